"""Flight-logic state of one mock autopilot, and the queries every flight module shares.

:class:`FlightState` is the mutable state of :mod:`sitl_mock.ap_flight` (reset at boot);
:class:`Setpoint` is a GCS setpoint resolved into the vehicle's LOCAL_NED frame (made by
:mod:`sitl_mock.ap_setpoints`). :func:`is_ardupilot` and :func:`airborne` are the queries the
flight, setpoint and failsafe logic all ask of an autopilot (``ap``). This module imports no
other part of the autopilot, so every flight module can depend on it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["FlightState", "Setpoint", "is_ardupilot", "airborne"]


@dataclass
class Setpoint:
    """A GCS setpoint resolved into the vehicle's LOCAL_NED frame."""

    frame: int
    type_mask: int
    ned: np.ndarray | None
    vel: np.ndarray | None
    yaw: float | None
    yaw_rate: float
    t_s: float


@dataclass
class FlightState:
    """Mutable flight-logic state of one autopilot (reset at boot)."""

    setpoint: Setpoint | None = None
    last_setpoint_s: float = -math.inf
    velocity_stopped: bool = False
    takeoff_alt_m: float | None = None
    rtl_phase: str = ""
    rtl_alt_m: float = 0.0
    mission_idx: int = 0
    mission_gen: int = -1
    mission_started: bool = False
    mission_wait_until_s: float | None = None
    idle_since_s: float | None = None
    has_flown: bool = False
    battery_level_done: int = 0
    #: mission clock since which the pack voltage is below BATT_LOW_VOLT / BATT_CRT_VOLT (None: above)
    volt_low_since_s: float | None = None
    volt_crt_since_s: float | None = None
    gcs_failsafe_done: bool = False
    #: PX4 said "Connection to ground station lost" (and has not yet said it was regained)
    gcs_lost_said: bool = False
    fence_breached: bool = False
    #: PX4's failsafe action delayed by COM_FAIL_ACT_T, held meanwhile: ``(action, due_s, reason)`` (None: none)
    pending_failsafe: tuple | None = None
    mission_target_ned: np.ndarray | None = None
    mission_alt_m: float = 0.0
    prearm_report_s: float | None = None
    #: PX4 offboard loss with COM_OBL_RC_ACT 0 and no RC: shown as POSCTL, descending at
    #: MPC_LAND_SPEED to the ground; the mode shown again once disarmed (the one it left, OFFBOARD)
    descent_without_pilot: bool = False
    mode_before_failsafe: str | None = None


def is_ardupilot(ap) -> bool:
    """True for the ArduPilot personality."""
    return ap.personality.name == "ardupilot"


def airborne(ap) -> bool:
    """True when armed and off the ground."""
    return ap.mc.armed and not ap.mc.landed
