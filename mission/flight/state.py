"""The mission's state types: phases, errors, preflight results and lost vehicles.

The lowest module of :mod:`mission.flight`: every other flight module may import it, it imports
none of them.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["PHASES", "MissionError", "VehicleLoss", "VehicleReadiness"]

PHASES = ("idle", "connect", "preflight", "takeoff", "assemble", "seek", "finish", "return", "done",
          "aborted")


class MissionError(RuntimeError):
    """The mission cannot go on (a phase failed); the message says which and why."""


@dataclass
class VehicleReadiness:
    """Preflight result of one vehicle: every check and why it failed."""

    sysid: int
    id: str
    connection: str
    checks: dict = field(default_factory=dict)
    problems: list = field(default_factory=list)
    flavour: str | None = None

    @property
    def ready(self) -> bool:
        """All checks passed."""
        return bool(self.checks) and all(self.checks.values()) and not self.problems


@dataclass
class VehicleLoss:
    """One lost vehicle.

    Attributes
    ----------
    sysid : int
    reason : str
        ``link`` (silent) or ``left`` (failsafe / unrequested mode, or disarmed in the air).
    detail : str
        Human-readable cause (mode seen, silence length).
    detected_s : float
        Mission clock at detection.
    since_s : float
        Mission clock of the last frame heard (``link``) or of the first sight of the new
        mode (``left``); ``detected_s - since_s`` is the detection latency seen by the coordinator.
    phase : str
        Coordinator phase at detection.
    came_back_s : float or None
        Mission clock when its frames were heard again (link losses).
    last_setpoint_enu : numpy.ndarray or None
        Its last setpoint when it was lost (a silent vehicle may still fly there).
    readmit_pending : bool
        Heard again and waiting for re-admission at the next seek iteration.
    """

    sysid: int
    reason: str
    detail: str
    detected_s: float
    since_s: float
    phase: str = ""
    came_back_s: float | None = None
    last_setpoint_enu: np.ndarray | None = None
    readmit_pending: bool = False

    @property
    def latency_s(self) -> float:
        """Seconds from the last sign of the vehicle (or of its mode change) to the detection."""
        return float(self.detected_s - self.since_s)
