"""The end result of a mission (:class:`MissionResult`, what ``--json`` prints)."""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

from mission.telemetry.mission_log import dataclass_json

__all__ = ["MissionResult", "mission_result", "readiness_result", "geodetic_point", "estimate_fields", "region_text",
           "mission_exit_status", "EXIT_OK", "EXIT_NOT_REACHED", "EXIT_USAGE", "EXIT_VEHICLE_LOST", "EXIT_AIRBORNE",
           "SIGNAL_EXIT", "LOG_FAILURE"]

#: the mission reached its goal (``converged``; a dry run: every vehicle ``ready``), every vehicle it
#: armed landed and disarmed, none lost
EXIT_OK = 0
#: the mission did not reach its goal (not converged, stopped at the fence, aborted, not ready),
#: every vehicle accounted for (none lost, none left airborne or armed)
EXIT_NOT_REACHED = 1
#: invalid options or plan (argparse's status; nothing was contacted)
EXIT_USAGE = 2
#: a vehicle was lost during the mission (link, handed to its autopilot's own failsafe, failed to
#: arm or fly) and not re-admitted, whether or not the mission converged: look at ``lost``
EXIT_VEHICLE_LOST = 4
#: a vehicle was left airborne with no landing behaviour, or still armed at the end: go and look
EXIT_AIRBORNE = 5
#: the name :mod:`mission.flight.operator_stop` records when the mission log could not be written
LOG_FAILURE = "LOG_WRITE_FAILED"
#: the exit status of a mission stopped by a signal (the first one) or by a log that could not be written
SIGNAL_EXIT = {"SIGHUP": 129, "SIGINT": 130, "SIGPIPE": 141, "SIGTERM": 143, LOG_FAILURE: 74}


def mission_exit_status(outcome: str, *, lost=(), airborne_left=(), still_armed=(), interrupted_by=()) -> int:
    """The exit status of a mission that ended with ``outcome`` (``run``, ``fly``, ``resume``).

    In order of precedence: :data:`EXIT_AIRBORNE` (5) when a vehicle was left airborne or armed
    (whatever else happened); the first stop's signal status (:data:`SIGNAL_EXIT`: 129, 130, 141,
    143, or 74 for a mission log that could not be written); :data:`EXIT_VEHICLE_LOST` (4) when a
    vehicle is still lost at the end; :data:`EXIT_OK` (0) for ``converged`` (a dry run's ``ready``;
    ``resume``'s ``recovered``: the stopped mission's vehicles brought home); else
    :data:`EXIT_NOT_REACHED` (1).

    Parameters
    ----------
    outcome : str
        :attr:`MissionResult.outcome`.
    lost, airborne_left, still_armed : sequence
        The vehicles lost (not re-admitted, not found disarmed on the ground by ``resume``: ``on_ground``),
        left airborne, still armed at the end.
    interrupted_by : sequence of str
        The signals that stopped the mission, in order.

    Returns
    -------
    int
    """
    if airborne_left or still_armed:
        return EXIT_AIRBORNE
    if interrupted_by:
        return SIGNAL_EXIT.get(interrupted_by[0], 130)
    if lost:
        return EXIT_VEHICLE_LOST
    return EXIT_OK if outcome in ("converged", "ready", "recovered") else EXIT_NOT_REACHED


def region_text(region95_m: float | None) -> str:
    """``95 % region 0.42 m`` (radius), or ``no 95 % region`` when the estimate has none."""
    return "no 95 % region" if region95_m is None else f"95 % region {float(region95_m):.2f} m"


def estimate_fields(estimate) -> dict:
    """The mission log's and the summary's keys of a source estimate's uncertainty.

    Parameters
    ----------
    estimate : estimator.estimate.SourceEstimate or None

    Returns
    -------
    dict
        ``estimate_region95_m`` (radius, m, or None), ``estimate_basis`` (what that region is, or
        None without an estimate) and, when the estimate has a plan-view posterior, ``estimate_map``
        (:meth:`estimator.estimate.PlanPosterior.to_json`).
    """
    if estimate is None:
        return {"estimate_region95_m": None, "estimate_basis": None}
    out = {"estimate_region95_m": estimate.region95_m, "estimate_basis": estimate.basis}
    if estimate.plan_map is not None:
        out["estimate_map"] = estimate.plan_map.to_json()
    return out


def geodetic_point(origin, enu) -> dict | None:
    """A mission-frame point in WGS-84 geodetic coordinates, for the operator.

    Parameters
    ----------
    origin : tuple of float
        The plan's origin ``(lat_deg, lon_deg, alt_m)`` (altitude AMSL, as MAVLink's).
    enu : array_like, shape (3,), or None
        East, north, up metres about ``origin``.

    Returns
    -------
    dict or None
        ``{"lat_deg", "lon_deg", "alt_m"}`` (``alt_m`` AMSL, as the origin's; latitude and
        longitude to 1e-8 degree, about 1 mm), None when ``enu`` or ``origin`` is None.
    """
    if enu is None or origin is None:
        return None
    from formation.geodesy import enu_to_geodetic

    lat_deg, lon_deg, alt_m = (float(x) for x in enu_to_geodetic([float(v) for v in enu], origin))
    return {"lat_deg": round(lat_deg, 8), "lon_deg": round(lon_deg, 8), "alt_m": round(alt_m, 3)}


@dataclass
class MissionResult:
    """End of a mission (what ``--json`` prints).

    Attributes
    ----------
    outcome : str
        ``converged``, ``max_iterations``, ``stopped_at_fence``, ``aborted``, ``interrupted``
        (Ctrl-C, SIGTERM), ``recovered`` (``resume`` of a mission that had ended: the vehicles
        still flying brought home), ``ready`` or ``not_ready`` (dry run).
    message : str
    estimate_enu : list or None
        Estimated source position: the seeker's own estimate (``model``: the fitted maximum;
        ``ste``: the posterior mean), else the mean of the last ``convergence_window`` centres
        (:func:`estimator.estimate.reported_estimate`).
    estimate_region95_m : float or None
        Radius of the sphere about ``estimate_enu`` holding 95 % of the probability, as
        ``estimate_basis`` defines it; None: the estimate has no region (``estimate_basis`` says why).
    estimate_basis : str or None
        What that region is (``docs/seekers.md``), None without an estimate.
    estimate_geodetic : dict or None
        The same in WGS-84: ``lat_deg``, ``lon_deg``, ``alt_m`` (AMSL, like the plan's origin).
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
        ``detail``, ``phase``, ``latency_s``, ``came_back_s``, ``on_ground`` (``resume`` found it
        disarmed on the ground: accounted for, not counted by the exit status) (see
        :mod:`mission.flight.faults.loss`).
    link_rejections : dict
        MAVLink frames the ground station's links refused, by kind (non-zero only:
        ``unsigned``, ``bad_signature``, ``replayed``, ``bad_crc``, ``malformed``...; see
        :mod:`mission.telemetry.link_report`).
    unknown_sysids : list
        System ids heard on the links that are no vehicle of the plan (ignored).
    true_source_geodetic : dict or None
        ``swarmseek run`` only: the true source in WGS-84 (as ``estimate_geodetic``).
    vehicle_rejections : dict
        ``swarmseek run`` only: frames the embedded mock vehicles refused, by sysid then kind
        (non-zero only; :func:`mission.sim.fleet_report.vehicle_rejections`).
    separation_interventions : int
        Vehicle-setpoints the safety envelope held back to keep ``min_separation_m`` (0: none
        needed; per vehicle in the mission log's ``separation enforcement`` events).
    airborne_left : list
        Vehicles still airborne with no landing behaviour at the end (the ``airborne_left``
        record of :mod:`mission.flight.faults.landing_guard`; empty when every vehicle is down or landing).
    still_armed : list
        Vehicles still armed at the end though landed or landing (after the wait for their disarm,
        :meth:`mission.flight.faults.landing_guard.LandingGuard.await_disarm`); the mission is then not ``ok`` (exit 1).
    interrupted_by : list
        The signals (``SIGINT``, ``SIGTERM``) that interrupted the mission, in order
        (:mod:`mission.flight.operator_stop`).
    mission_checks : list
        The mission-wide preflight checks (``name``, ``ok``, ``detail``: zenoh, readings, start
        and paths inside the fence; :mod:`mission.flight.readiness_mission`).
    """

    outcome: str
    message: str = ""
    estimate_enu: list | None = None
    estimate_geodetic: dict | None = None
    spread_m: float | None = None
    estimate_region95_m: float | None = None
    estimate_basis: str | None = None
    iterations: int = 0
    mission_time_s: float = 0.0
    seek_time_s: float = 0.0
    distance_flown_m: float = 0.0
    vehicle_distance_m: dict = field(default_factory=dict)
    readings: dict = field(default_factory=dict)
    readiness: list = field(default_factory=list)
    true_source_enu: list | None = None
    true_source_geodetic: dict | None = None
    error_m: float | None = None
    log_path: str | None = None
    reengaged: dict = field(default_factory=dict)
    max_loop_lag_s: float | None = None
    lost: list = field(default_factory=list)
    readmitted: list = field(default_factory=list)  # sysid, lost_s, came_back_s, readmitted_s
    retired: list = field(default_factory=list)  # retired sensors: mission.flight.faults.retire.RetiredSensor
    link_rejections: dict = field(default_factory=dict)
    unknown_sysids: list = field(default_factory=list)
    vehicle_rejections: dict = field(default_factory=dict)
    separation_interventions: int = 0
    airborne_left: list = field(default_factory=list)
    still_armed: list = field(default_factory=list)
    interrupted_by: list = field(default_factory=list)
    mission_checks: list = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """The mission reached its goal (converged) with every vehicle disarmed, none lost and none left
        airborne, or the dry run found every vehicle ready: exit status :data:`EXIT_OK`."""
        return self.exit_status == EXIT_OK

    @property
    def exit_status(self) -> int:
        """The command's exit status for this result (:func:`mission_exit_status`)."""
        return mission_exit_status(self.outcome, lost=[x for x in self.lost if not x.get("on_ground")],
                                   airborne_left=self.airborne_left,
                                   still_armed=self.still_armed, interrupted_by=self.interrupted_by)

    def to_json(self) -> dict:
        """JSON-friendly dict (through :func:`~mission.telemetry.mission_log.dataclass_json`: no secret),
        with ``exit_status``, the status the command exits with."""
        return dataclass_json(self) | {"exit_status": self.exit_status}


def mission_result(state, outcome: str, message: str, *, now_s: float, readings: dict,
                   log_path: str | None = None, separation_interventions: int = 0,
                   origin=None) -> MissionResult:
    """The :class:`MissionResult` of a mission whose state is ``state`` (:class:`~mission.flight.state.MissionState`).

    Parameters
    ----------
    state : MissionState
    outcome, message : str
    now_s : float
        Mission clock now.
    readings : dict
        The reading store's counts (and last errors).
    log_path : str, optional
    separation_interventions : int
        The ramp's count (:attr:`mission.safety.gate.SafetyGate.separation_interventions`).
    origin : tuple of float, optional
        The plan's geodetic origin: gives ``estimate_geodetic``.
    """
    t_end = state.t_seek_end_s or now_s
    est = state.estimate_enu
    return MissionResult(
        outcome=outcome, message=message,
        estimate_enu=None if est is None else [float(x) for x in est],
        estimate_geodetic=geodetic_point(origin, est),
        spread_m=state.spread_m, estimate_region95_m=state.estimate_region95_m,
        estimate_basis=state.estimate_basis, iterations=state.iteration,
        mission_time_s=now_s - state.t_start_s,
        seek_time_s=0.0 if state.t_seek_start_s is None else t_end - state.t_seek_start_s,
        distance_flown_m=state.distance_flown_m,
        vehicle_distance_m={int(k): round(v, 2) for k, v in state.vehicle_distance_m.items()},
        readings=readings,
        readiness=[asdict(r) | {"ready": r.ready} for r in state.readiness.values()],
        log_path=log_path, reengaged=dict(state.reengaged), max_loop_lag_s=round(state.max_loop_lag_s, 4),
        lost=[{"sysid": x.sysid, "reason": x.reason, "detail": x.detail, "phase": x.phase,
               "latency_s": round(x.latency_s, 3), "came_back_s": x.came_back_s, "on_ground": x.on_ground}
              for x in state.lost.values()], readmitted=list(state.readmitted),
        retired=[dict(asdict(x), ratio=round(x.ratio, 3)) for x in state.retired.values()],
        separation_interventions=int(separation_interventions))


def readiness_result(state, plan_vehicles, readings: dict, mission_time_s: float,
                     mission_checks=()) -> MissionResult:
    """The dry run's result: ``ready`` when every vehicle of the plan passed its preflight and
    every mission-wide check (:mod:`mission.flight.readiness_mission`) passed, else ``not_ready``."""
    ready = list(state.readiness.values())
    failed = [c for c in mission_checks if not c["ok"]]
    all_ready = len(ready) == len(plan_vehicles) and all(r.ready for r in ready) and not failed
    missing = [vp for vp in plan_vehicles if vp.sysid not in state.readiness]
    readiness = [asdict(r) | {"ready": r.ready} for r in ready] + [
        {"sysid": vp.sysid, "id": vp.id, "connection": vp.connection, "ready": False,
         "checks": {"connected": False}, "problems": ["not connected"]} for vp in missing]
    n_bad = sum(not r["ready"] for r in readiness)
    why = ([f"{n_bad} vehicle(s) not ready"] if n_bad else []) + [f"{c['name']} failed" for c in failed]
    return MissionResult(outcome="ready" if all_ready else "not_ready",
                         message="every vehicle and the mission are ready to seek" if all_ready else "; ".join(why),
                         readiness=readiness, readings=readings, mission_time_s=mission_time_s,
                         mission_checks=[dict(c) for c in mission_checks])
