"""The end result of a mission (:class:`MissionResult`, what ``--json`` prints)."""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

from mission.telemetry.mission_log import to_jsonable

__all__ = ["MissionResult"]

@dataclass
class MissionResult:
    """End of a mission (what ``--json`` prints).

    Attributes
    ----------
    outcome : str
        ``converged``, ``max_iterations``, ``stopped_at_fence``, ``aborted``, ``ready`` or
        ``not_ready`` (dry run).
    message : str
    estimate_enu : list or None
        Estimated source position (mean of the last ``convergence_window`` centres).
    spread_m : float or None
        RMS spread of those centres.
    iterations : int
    mission_time_s, seek_time_s : float
        Mission clock seconds, whole mission and seek phase.
    distance_flown_m : float
        Path length of the formation centre during the seek.
    vehicle_distance_m : dict
        Path length flown by each vehicle (telemetry), by sysid.
    readings : dict
        Accepted readings and rejections per reason.
    readiness : list
        Preflight result per vehicle.
    lost : list
        Vehicles lost during the mission: ``sysid``, ``reason`` (``link`` / ``left``),
        ``detail``, ``phase``, ``latency_s`` (see :mod:`mission.flight.loss`).
    """

    outcome: str
    message: str = ""
    estimate_enu: list | None = None
    spread_m: float | None = None
    iterations: int = 0
    mission_time_s: float = 0.0
    seek_time_s: float = 0.0
    distance_flown_m: float = 0.0
    vehicle_distance_m: dict = field(default_factory=dict)
    readings: dict = field(default_factory=dict)
    readiness: list = field(default_factory=list)
    true_source_enu: list | None = None
    error_m: float | None = None
    log_path: str | None = None
    reengaged: dict = field(default_factory=dict)
    max_loop_lag_s: float | None = None
    lost: list = field(default_factory=list)
    readmitted: list = field(default_factory=list)  # sysid, lost_s, came_back_s, readmitted_s
    retired: list = field(default_factory=list)  # retired sensors: mission.flight.retire.RetiredSensor

    @property
    def ok(self) -> bool:
        """The mission reached its goal (converged), or the dry run found every vehicle ready."""
        return self.outcome in ("converged", "ready")

    def to_json(self) -> dict:
        """JSON-friendly dict."""
        return to_jsonable(asdict(self))
