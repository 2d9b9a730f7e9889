"""The mission plan's data model: one frozen dataclass per section, the plan and its error.

What :func:`mission.core.plan.parse_plan` builds once every key is valid (the file format is
described in :mod:`mission.core.plan`); its names are imported from here.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from mission.core.plan_field import FieldPlan
from mission.core.signing_config import SigningConfig
from mission.core.zenoh_config import ZenohPlan

__all__ = [
    "PLAN_VERSION", "SAMPLINGS", "PLUME_MODES", "PlanError", "VehiclePlan", "FaultsPlan",
    "PreflightPlan", "ControlPlan", "ForwardPlan", "FormationPlan", "SeekingPlan", "GeofencePlan",
    "Plan", "replace_plan",
]

PLAN_VERSION = 1
#: values of ``[seeking] sampling`` (:class:`SeekingPlan`)
SAMPLINGS = ("stop_and_go", "moving")
#: variants of the ``plume`` seeker (``[seeking] plume_mode``)
PLUME_MODES = ("steady", "intermittent")


class PlanError(ValueError):
    """An invalid plan; ``problems`` lists ``(key_path, why)`` for every invalid key.

    Parameters
    ----------
    problems : list of (str, str)
        Dotted key path (e.g. ``vehicles[2].sysid``) and a reason.
    source : str, optional
        File name, for the message.
    """

    def __init__(self, problems: list[tuple[str, str]], source: str | None = None):
        self.problems = list(problems)
        where = f" in {source}" if source else ""
        lines = [f"  {key}: {why}" for key, why in self.problems]
        super().__init__(f"invalid plan{where} ({len(self.problems)} problem"
                         f"{'s' if len(self.problems) != 1 else ''}):\n" + "\n".join(lines))


@dataclass(frozen=True)
class VehiclePlan:
    """One vehicle: a name, its MAVLink system id and connection string."""

    id: str
    sysid: int
    connection: str


@dataclass(frozen=True)
class FormationPlan:
    """Formation type (``cvt`` or ``symmetric``), radius ``D`` in metres, CVT seed."""

    type: str = "cvt"
    radius_m: float = 4.0
    seed: int = 0


@dataclass(frozen=True)
class SeekingPlan:
    """Source-seeking parameters.

    Attributes
    ----------
    eps : float
        Gain of the step ``eps * grad`` (paper: 1).
    gamma_m : float
        Largest centre move per iteration (paper: 0.1).
    estimator : str
        ``cvt`` (Theorem 2 on the actual positions), ``symmetric`` (eq. 3) or ``robust``.
    seeker : str
        ``gradient`` (the paper's ``eps * grad`` capped by ``gamma_m``), ``newton``, ``model``,
        ``plume`` or ``ste`` (``estimator.seekers``; their steps are capped by ``gamma_m`` too: give
        it 10-20 m). This class's defaults are the paper's (``gradient``, ``gamma_m = 0.1``, stop
        and go); a plan file that names no seeker gets :func:`best_seeker` of its field, with
        ``gamma_m = 20`` and sampling while moving (``mission.core.plan_sections.parse_seeking``).
    sampling : str
        ``stop_and_go`` (fly to the new centre, settle, read, estimate) or ``moving`` (the
        seeker gets every reading taken since the last estimate, along the path, and the next
        estimate is made while the formation flies: :mod:`mission.flight.phases.seek_moving`; for the
        ``newton`` and ``model`` seekers only).
    replan_fraction : float
        With ``moving`` sampling: the next estimate is made once the formation has covered this
        fraction of its move (or is within ``arrival_tol_m`` of its slots' centroid).
    sensor_lag_s : float
        The sensor's response time constant (its datasheet's; 0: instantaneous). With ``moving``
        sampling each reading goes to the seeker at the position its vehicle had this long before
        (a lagged sensor moving reads the field where it was).
    wind_from_deg : float or None
        Wind direction for the ``plume`` seeker (where it comes FROM, degrees clockwise from north:
        an anemometer or the vehicles' wind estimate); None: the seeker estimates the plume's axis.
    plume_mode : str
        The ``plume`` seeker's variant: ``steady`` (surge up the axis, cast, two passes, hold) or
        ``intermittent`` (puffs: follow the upwind edge of the cloud of detections,
        ``estimator.seek_hits``); for ``ste`` the likelihood: ``steady`` (the mean field) or
        ``intermittent`` (hits and misses).
    wind_std_deg : float
        ``ste``: the prior's standard deviation about ``wind_from_deg`` (given only with it).
    sensor_noise_std, sensor_detection_floor : float
        ``ste``: the sensor's noise standard deviation (> 0, signal units) and detection floor
        (readings below it report 0), from its datasheet.
    ground_alt_m : float
        ``ste``: the ground's up coordinate (mission ENU, m): the dispersion model's reflecting
        ground, and no release below it.
    stability : str
        ``ste``: the Pasquill-Gifford stability class (``A``-``F``) of the dispersion model.
    region_m : float
        ``ste``: converged when the posterior's 95 % region (its radius about the posterior mean) is
        at most this (and the posterior has not collapsed recently nor misfits the readings).
    prior_box : str
        ``ste``: ``fence`` bounds the prior over the release by the geofence's box (the polygon's
        east/north bounding box, up from the lower of ``ground_alt_m`` and the fence's floor to its
        ceiling: a release outside the fence cannot be reached; the default); ``none``: the
        seeker's own prior about the first centre alone (docs/seekers.md, "Round 6").
    min_signal_fraction : float
        Convergence needs a signal in at least this fraction of the window's iterations
        (``estimator.seeking``, criterion 3; 0 turns it off): the ``plume`` seeker's "holding
        with a detection", else ``estimator.seek_signal.ArrivalSignal`` on the readings.
    rate_hz : float
        Highest estimation rate (iterations per second of mission clock).
    max_iterations : int
        The mission stops seeking after this many iterations (not converged).
    convergence_tol_m, convergence_window : float, int
        Converged when the centre's spread over the last ``window`` iterations is below tol.
    region_hold : int
        With a seeker that reports a 95 % region (``model``), also converged when that region has
        been ``<= convergence_tol_m`` with the formation on the estimate for this many iterations
        (:mod:`estimator.seek_confirm`); 0 turns that rule off (the window test alone).
    start_enu_m : tuple of float or None
        Formation centre where seeking starts (mission ENU); ``None``: above the origin at
        ``altitude_m``.
    altitude_m : float
        Up coordinate of the start point when ``start_enu_m`` is not given.
    arrival_tol_m : float
        A vehicle is "at its slot" within this distance.
    reading_window_s : float
        Readings used for an estimation instant are at most this far from it.
    max_reading_age_s : float
        Readings older than this (by the mission clock) are rejected as late.
    max_position_error_m : float
        Readings taken farther than this from the vehicle's telemetry position are rejected.
    """

    eps: float = 1.0
    gamma_m: float = 0.1
    estimator: str = "cvt"
    seeker: str = "gradient"
    sampling: str = "stop_and_go"
    replan_fraction: float = 0.5
    sensor_lag_s: float = 0.0
    wind_from_deg: float | None = None
    plume_mode: str = "steady"
    wind_std_deg: float = 10.0
    sensor_noise_std: float = 0.01
    sensor_detection_floor: float = 0.0
    ground_alt_m: float = 0.0
    stability: str = "C"
    region_m: float = 1.0
    prior_box: str = "fence"
    min_signal_fraction: float = 1.0
    rate_hz: float = 2.0
    max_iterations: int = 300
    convergence_tol_m: float = 0.5
    convergence_window: int = 12
    region_hold: int = 3
    start_enu_m: tuple[float, float, float] | None = None
    altitude_m: float = 10.0
    arrival_tol_m: float = 0.5
    reading_window_s: float = 0.5
    max_reading_age_s: float = 5.0
    max_position_error_m: float = 10.0

    def start_point(self) -> np.ndarray:
        """Start of the formation centre, ENU metres."""
        if self.start_enu_m is not None:
            return np.asarray(self.start_enu_m, dtype=float)
        return np.array([0.0, 0.0, self.altitude_m])


@dataclass(frozen=True)
class GeofencePlan:
    """Geofence: polygon vertices (east_m, north_m) in the mission frame and altitude band (up_m).

    Attributes
    ----------
    source : str
        Where a polygon read from a file (``[geofence] file``) came from, in words (the file and
        the fence in it: ``fence.kml: KML Polygon 'Search area'``); empty when the plan gives it.
    source_latlon_deg : tuple of (float, float)
        That file's vertices ``(lat_deg, lon_deg)``, as written in it (``polygon_en_m`` is their
        conversion about the origin).
    origin_from_file : bool
        The plan has no ``[origin]``: the mission origin is the file's home.
    """

    polygon_en_m: tuple[tuple[float, float], ...] = ()
    min_alt_m: float = 2.0
    max_alt_m: float = 120.0
    source: str = ""
    source_latlon_deg: tuple[tuple[float, float], ...] = ()
    origin_from_file: bool = False


@dataclass(frozen=True)
class FaultsPlan:
    """Vehicle-loss handling (``[faults]``): see ``docs/faults.md``.

    Attributes
    ----------
    readmit : bool
        A lost vehicle whose link comes back is kept out and commanded to land / RTL per
        ``return`` (False, the default); True: re-admitted into the formation if it comes back
        during the seek, armed and airborne (``mission.flight.faults.rejoin``).
    link_timeout_s : float
        A vehicle silent for this long (mission clock) is lost (default 1.0; detection within
        ``link_timeout_s`` + 0.1 s).
    faulty_sensor : {"retire", "keep", "off"}
        Whatever the estimator and the seeker, the robust estimator's fault detection
        (:mod:`mission.flight.sensor_check`) leaves the readings of the sensors it excludes (stuck,
        biased, a spike) out of the seeker's input; a sensor it names for one of the reasons of
        :class:`estimator.retire.SensorRetirement` (stuck; noisy at 3x the median) for
        ``retire_after`` consecutive iterations is retired, its vehicle parked at the
        formation centre and the others re-formed (``retire``, the default,
        :mod:`mission.flight.faults.retire`); ``keep``: detection only, the vehicle keeps its slot;
        ``off``: no detection (the plan's estimator alone, every reading to the seeker).
    retire_after : int
        Consecutive iterations a sensor must be named before it is retired (default 20).
    retire_min_noise_ratio : float
        A ``noisy`` sensor counts only while its estimated noise std is at least this many times
        the median's (``min_noise_ratio`` of the rule; default 3.0, >= 1).
    """

    readmit: bool = False
    link_timeout_s: float = 1.0
    faulty_sensor: str = "retire"
    retire_after: int = 20
    retire_min_noise_ratio: float = 3.0


@dataclass(frozen=True)
class PreflightPlan:
    """Preflight (``[preflight]``): the autopilots' own readiness and their failsafe parameters.

    Attributes
    ----------
    autopilot_ready_timeout_s : float
        How long (mission clock) preflight waits for every autopilot's own pre-arm state to be
        ready (SYS_STATUS health, EKF / estimator position), and arming is retried while the
        autopilot refuses (``PreArm: Need Position Estimate``); default 120 (ArduCopter SITL
        needs about 40 s after boot at speed-up 1).
    require_gcs_failsafe : bool
        True: a vehicle whose failsafe parameters would let it hover forever when the ground
        station dies (ArduPilot ``FS_GCS_ENABLE = 0``; PX4 ``NAV_DLL_ACT = 0`` with an offboard
        loss action that only holds) is not ready (``fly`` refuses); False (default): a warning.
    require_readings : bool
        True (default): a vehicle whose sensor sent no accepted reading within
        ``readings_timeout_s`` is not ready to seek (``dry-run`` says so, ``fly`` arms nothing);
        False: a warning only (a sensor that starts publishing once airborne).
    readings_timeout_s : float
        How long (mission clock) preflight waits for a reading from every vehicle (default 10).
    """

    autopilot_ready_timeout_s: float = 120.0
    require_gcs_failsafe: bool = False
    require_readings: bool = True
    readings_timeout_s: float = 10.0


@dataclass(frozen=True)
class ControlPlan:
    """Operator commands over zenoh (``[control]``, see ``docs/operator.md``).

    Attributes
    ----------
    remote : bool
        The coordinator answers ``swarmseek ctl`` on ``swarmseek/<fleet>/mission/control`` (default
        True; who may is the zenoh access control's ``commander_*`` subjects); False: only the
        terminal's keys command the mission.
    """

    remote: bool = True


@dataclass(frozen=True)
class ForwardPlan:
    """MAVLink forwarding to ground-control clients (``[forward]``, see ``docs/operator.md``).

    Attributes
    ----------
    out : tuple of str
        ``udp:HOST:PORT`` addresses every vehicle frame is copied to (``--out`` adds more).
    allow_commands : bool
        Frames from those clients are relayed to the vehicles (default False: read-only; they are
        counted as dropped).
    """

    out: tuple[str, ...] = ()
    allow_commands: bool = False


@dataclass(frozen=True)
class Plan:
    """A validated mission plan (see the module docstring)."""

    fleet: str
    origin: tuple[float, float, float]
    vehicles: tuple[VehiclePlan, ...]
    formation: FormationPlan = FormationPlan()
    seeking: SeekingPlan = SeekingPlan()
    geofence: GeofencePlan = GeofencePlan()
    zenoh: ZenohPlan = ZenohPlan()
    security: SigningConfig | None = None
    #: ``[security] require_signing``: a vehicle link that is not loopback must be signed (else the
    #: plan is refused, :mod:`mission.core.plan_security`)
    require_signing: bool = False
    max_speed_m_s: float = 3.0
    min_separation_m: float = 1.5
    takeoff_alt_m: float = 10.0
    return_behaviour: str = "land"
    stagger_s: float = 1.0
    setpoint_rate_hz: float = 10.0
    heartbeat_timeout_s: float = 10.0
    min_battery_pct: float = 30.0
    version: int = PLAN_VERSION
    faults: FaultsPlan = FaultsPlan()
    preflight: PreflightPlan = PreflightPlan()
    field: FieldPlan | None = None  # the simulated world's field ([field]); not used to fly
    control: ControlPlan = ControlPlan()
    forward: ForwardPlan = ForwardPlan()


def replace_plan(plan: Plan, **sections) -> Plan:
    """Return a copy of ``plan`` with top-level fields replaced (e.g. ``seeking=...``)."""
    return replace(plan, **sections)
