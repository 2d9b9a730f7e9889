"""Errors and result records of the safety envelope (:mod:`mission.safety.envelope`)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["SafetyError", "EmptyFenceError", "SafetyViolation", "CentreClamp", "Violation", "SetpointReport",
           "ClampedSetpoints"]


class SafetyError(ValueError):
    """An invalid safety configuration (fence, band, limits)."""


class EmptyFenceError(SafetyError):
    """A fence shrunk by a margin (e.g. the formation radius) leaves no room at all."""


class SafetyViolation(RuntimeError):
    """A setpoint would break the envelope even after clamping; never send it."""


@dataclass(frozen=True)
class CentreClamp:
    """Result of :meth:`SafetyEnvelope.clamp_centre`.

    Attributes
    ----------
    centre_enu : numpy.ndarray, shape (3,)
        The centre to use (inside the fence shrunk by the formation radius).
    at_boundary : bool
        True if the requested centre was outside and was stopped at the boundary.
    requested_enu : numpy.ndarray, shape (3,)
        The centre that was asked for.
    message : str
        Human-readable explanation ("" when not clamped).
    """

    centre_enu: np.ndarray
    at_boundary: bool
    requested_enu: np.ndarray
    message: str = ""

    @property
    def shortfall_m(self) -> float:
        """Distance between the requested and the allowed centre."""
        return float(np.linalg.norm(self.requested_enu - self.centre_enu))


@dataclass(frozen=True)
class Violation:
    """One broken rule: ``kind`` in ``fence``, ``fence_path``, ``altitude``, ``speed``,
    ``separation`` (end points) or ``separation_path``; ``vehicles`` are 0-based indices."""

    kind: str
    vehicles: tuple[int, ...]
    value: float
    limit: float
    message: str


@dataclass(frozen=True)
class SetpointReport:
    """Every violation found by :meth:`SafetyEnvelope.check_setpoints`."""

    violations: tuple[Violation, ...] = ()
    min_separation_m: float = float("inf")
    max_speed_m_s: float = 0.0

    @property
    def ok(self) -> bool:
        """True when nothing is violated."""
        return not self.violations

    def kinds(self) -> set[str]:
        """The set of violated rule kinds."""
        return {v.kind for v in self.violations}

    def __str__(self):
        if self.ok:
            return "setpoints safe"
        return "; ".join(v.message for v in self.violations)


@dataclass(frozen=True)
class ClampedSetpoints:
    """Result of :meth:`SafetyEnvelope.clamp_setpoints`.

    Attributes
    ----------
    positions_enu : numpy.ndarray, shape (N, 3)
        Safe setpoints: inside the fence and band, speed-limited where the previous position
        was inside the fence, separated (see ``separation_held``).
    fence_clamped, speed_limited : numpy.ndarray of bool, shape (N,)
        Which vehicles' setpoints were moved by the fence/band or shortened by the speed limit.
    report : SetpointReport
        The check of the returned setpoints (ok unless the previous batch was already too close
        or a vehicle outside the fence could not be held).
    separation_held : numpy.ndarray of bool, shape (N,)
        Vehicles held at their previous setpoints to keep the separation (one intervention each).
    separation_note : str
        Which pairs would have come too close, and who was held, by index ("" when none).
    separation_conflicts : tuple of (int, int, float)
        Those pairs ``(i, j, closest approach m)`` as asked for, closest first.
    separation_aside : numpy.ndarray of bool, shape (N,)
        Vehicles moved aside for separation (a shorter or sideways step than asked for, not
        held; one intervention each).
    """

    positions_enu: np.ndarray
    fence_clamped: np.ndarray
    speed_limited: np.ndarray
    report: SetpointReport = field(default_factory=SetpointReport)
    separation_held: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    separation_note: str = ""
    separation_conflicts: tuple = ()
    separation_aside: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    @property
    def separation_interventions(self) -> int:
        """Vehicles held or moved aside for separation in this batch."""
        return int(np.count_nonzero(self.separation_held)) + int(np.count_nonzero(self.separation_aside))
