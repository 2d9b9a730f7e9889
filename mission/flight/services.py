"""The narrow services a phase is handed instead of the coordinator.

A phase of :mod:`mission.flight` is an object constructed with exactly what it uses: the
:class:`~mission.flight.state.MissionState`, the plan sections it reads, the mission clock, the
safety gate (:class:`mission.safety.gate.SafetyGate`), the :class:`Fleet` of connected vehicles,
the mission log and the few coordinator services below, each a :class:`typing.Protocol` that says
what the phase may call. Only :mod:`mission.flight.coordinator` (which builds the phases) holds the
coordinator; it satisfies these protocols structurally.
"""
from __future__ import annotations

from typing import Any, Callable, Protocol

import numpy as np

__all__ = ["Clock", "Events", "Fleet", "Motion", "PhaseEvents", "SeekFormation", "Waiter"]


class Clock(Protocol):
    """The mission clock (wall, scaled or lock-step: ``docs/architecture.md``)."""

    def time(self) -> float:
        """Seconds of mission clock."""

    async def sleep(self, dt_s: float) -> None:
        """Wait ``dt_s`` seconds of mission clock."""


class Events(Protocol):
    """Tell the operator: an ``event`` record in the mission log, a line on the display."""

    def event(self, message: str, level: str = "info", **fields: Any) -> None:
        """Log and show an event."""


class PhaseEvents(Events, Protocol):
    """:class:`Events`, and entering a phase (a ``phase`` record, the state publication)."""

    def set_phase(self, name: str, **fields: Any) -> None:
        """Enter a phase: log it, show it."""


class Waiter(Protocol):
    """Wait on the mission clock for a condition; an operator's stop ends the wait."""

    async def wait_until(self, predicate: Callable[[], bool], timeout_s: float, what: str,
                         poll_s: float = 0.1) -> None:
        """Poll ``predicate()`` until true; MissionError after ``timeout_s``."""


class Motion(Protocol):
    """The moves a phase may use (goals flown on the gate): :class:`mission.flight.motion.GateMotion`.

    Lost vehicles are skipped by every one of them; ``sysids``: system ids, positions in mission ENU m.
    """

    async def move_and_wait(self, goals: dict[int, np.ndarray], tol_m: float, timeout_s: float | None = None,
                            what: str = "vehicles to reach their goals") -> None:
        """Set the goals on the gate and wait until every vehicle is within ``tol_m`` of its own."""

    async def fly_timed(self, sysids: list[int], times_s, waypoints_enu) -> None:
        """Feed a synchronous plan's interpolated positions to the gate as goals."""

    async def transfer_to(self, sysids: list[int], new_offsets: dict, centre_enu, what: str,
                          lost_here: list[int]) -> None:
        """A separation-keeping transfer to ``centre_enu + new_offsets``; the slots adopted."""

    async def keep_out(self, sysid: int, v, why: str) -> None:
        """Keep a returning lost vehicle out of the formation and command it to land (or RTL)."""

    def parked(self) -> list[int]:
        """Vehicles whose sensor was retired, still under the mission's setpoints (sorted)."""


class Fleet:
    """The vehicles connected to this ground station, by system id, and their plan ids.

    Parameters
    ----------
    ids : dict[int, str]
        The plan's vehicle id of each system id.
    """

    def __init__(self, ids: dict[int, str]) -> None:
        self.ids = dict(ids)
        self.vehicles: dict[int, Any] = {}

    def add(self, vehicle) -> None:
        """A connected vehicle (a :class:`mission.vehicle.vehicle_link.VehicleLink`)."""
        self.vehicles[vehicle.sysid] = vehicle

    def telemetry_position(self, sysid: int) -> np.ndarray | None:
        """The vehicle's telemetry position (mission ENU m), or None (unknown vehicle, no telemetry yet)."""
        v = self.vehicles.get(sysid)
        if v is None:
            return None
        try:
            return v.position_enu_m()
        except Exception:  # noqa: BLE001 - no telemetry yet
            return None


class SeekFormation(Protocol):
    """What the seek asks of the formation's keepers: losses (:mod:`mission.flight.faults.loss`),
    re-admission (:mod:`mission.flight.faults.rejoin`), sensor retirement (:mod:`mission.flight.faults.retire`)
    and the moves (:mod:`mission.flight.motion`): :class:`mission.flight.faults.responses.FaultResponses`."""

    async def reform(self, centre_enu, sysids: list[int]) -> list[int]:
        """Re-form without the lost vehicles; the members left."""

    def pending_readmissions(self) -> list[int]:
        """Lost vehicles heard again, waiting for re-admission."""

    async def keep_out_retired(self, returning: list[int]) -> list[int]:
        """Keep returning vehicles with a retired sensor out; the others of ``returning``."""

    async def readmit(self, centre_enu, sysids: list[int], returning: list[int]) -> list[int]:
        """Re-admit ``returning`` into the formation; the members."""

    def clear_goals(self, centre_enu, sysids: list[int]) -> bool:
        """Rotate the slots clear of lost vehicles still flying (True: rotated)."""

    async def fly_rotation(self, centre_enu, sysids: list[int], before: dict) -> None:
        """Fly a rotation of the slots as a planned transfer."""

    def formation_goals(self, centre_enu, sysids: list[int]) -> dict:
        """Each member's goal about ``centre_enu``, parked vehicles at the centre."""

    def make_watch(self, check, sysids: list[int]):
        """The faulty-sensor retirement watch (None: off)."""

    async def retire_sensor(self, centre_enu, sysids: list[int], info) -> list[int]:
        """Retire a sensor: park its vehicle, re-form the others; the members."""

    async def move_and_wait(self, goals: dict, tol_m: float, timeout_s: float | None = None,
                            what: str = "vehicles to reach their goals") -> None:
        """Set the gate's goals and wait for the vehicles there."""

    def parked(self) -> list[int]:
        """Vehicles parked at the centre (retired sensors)."""
