"""Mission plan: a versioned TOML file (``version = 1``) validated all at once.

A plan names the fleet, the mission origin, the vehicles and their MAVLink connections, the
formation, the seeking parameters, the safety envelope (geofence, speed limit, separation) and
the zenoh configuration. :func:`load_plan` reads a file, :func:`parse_plan` a decoded TOML
mapping; both raise :class:`PlanError` listing EVERY invalid key with its dotted path and why.

The file format is documented in ``docs/mission.md`` and illustrated by
``mission/examples/sitl_plan.toml``.
"""
from __future__ import annotations

import tomllib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from formation.geodesy import geodetic_to_enu
from mission.core.plan_checks import Checker, check_connection, polygon_area, show_value
from mission.core.signing_config import SigningConfig, signing_config_from_table
from mission.core.signing_keys import SigningError
from mission.core.zenoh_security import ZenohPlan, parse_zenoh

__all__ = [
    "PLAN_VERSION",
    "PlanError",
    "VehiclePlan",
    "FaultsPlan",
    "FormationPlan",
    "SeekingPlan",
    "GeofencePlan",
    "ZenohPlan",
    "Plan",
    "load_plan",
    "parse_plan",
    "replace_plan",
]

PLAN_VERSION = 1
_FORMATIONS = ("cvt", "symmetric")
_ESTIMATORS = ("cvt", "symmetric", "robust")
_RETURNS = ("land", "rtl")
_FAULTY_SENSOR = ("retire", "keep")


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
    rate_hz : float
        Highest estimation rate (iterations per second of mission clock).
    max_iterations : int
        The mission stops seeking after this many iterations (not converged).
    convergence_tol_m, convergence_window : float, int
        Converged when the centre's spread over the last ``window`` iterations is below tol.
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
    rate_hz: float = 2.0
    max_iterations: int = 300
    convergence_tol_m: float = 0.5
    convergence_window: int = 12
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
    """Geofence: polygon vertices (east_m, north_m) in the mission frame and altitude band (up_m)."""

    polygon_en_m: tuple[tuple[float, float], ...] = ()
    min_alt_m: float = 2.0
    max_alt_m: float = 120.0


@dataclass(frozen=True)
class FaultsPlan:
    """Vehicle-loss handling (``[faults]``): see ``docs/faults.md``.

    Attributes
    ----------
    readmit : bool
        A lost vehicle whose link comes back is kept out and commanded to land / RTL per
        ``return`` (False, the default); True: re-admitted into the formation if it comes back
        during the seek, armed and airborne (``mission.flight.rejoin``).
    link_timeout_s : float
        A vehicle silent for this long (mission clock) is lost (default 1.0; detection within
        ``link_timeout_s`` + 0.1 s).
    faulty_sensor : {"retire", "keep"}
        With the ``robust`` estimator: a sensor it names for one of the reasons of
        :class:`estimator.retire.SensorRetirement` (stuck; noisy at 3x the median) for
        ``retire_after`` consecutive iterations is retired, its vehicle parked at the
        formation centre and the others re-formed (``retire``, the default,
        :mod:`mission.flight.retire`); ``keep``: the vehicle keeps its slot, its sensor down-weighted.
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


def replace_plan(plan: Plan, **sections) -> Plan:
    """Return a copy of ``plan`` with top-level fields replaced (e.g. ``seeking=...``)."""
    return replace(plan, **sections)


def load_plan(path: str | Path) -> Plan:
    """Read and validate a plan file.

    Parameters
    ----------
    path : str or pathlib.Path
        TOML file.

    Returns
    -------
    Plan

    Raises
    ------
    PlanError
        The file cannot be read or parsed, or any key is invalid (all listed at once).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise PlanError([("(file)", f"cannot read: {exc.strerror or exc}")], str(path)) from None
    except UnicodeDecodeError as exc:
        raise PlanError([("(file)", f"not UTF-8 text: {exc}")], str(path)) from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise PlanError([("(file)", f"not valid TOML: {exc}")], str(path)) from None
    return parse_plan(doc, source=str(path), base_dir=path.parent)


def parse_plan(doc: dict, *, source: str | None = None, base_dir: str | Path | None = None) -> Plan:
    """Validate a decoded TOML document and build a :class:`Plan`.

    Parameters
    ----------
    doc : dict
        The decoded TOML.
    source : str, optional
        Where it came from (for error messages).
    base_dir : path, optional
        Relative TLS file paths are resolved against it.

    Raises
    ------
    PlanError
        Listing every invalid key with its path and why.
    """
    c = Checker()
    if not isinstance(doc, dict):
        raise PlanError([("(document)", "expected a TOML table")], source)
    c.unknown(doc, ("version", "fleet", "origin", "vehicles", "formation", "seeking", "geofence",
                    "zenoh", "security", "max_speed_m_s", "min_separation_m", "takeoff_alt_m", "return",
                    "stagger_s", "setpoint_rate_hz", "heartbeat_timeout_s", "min_battery_pct",
                    "faults"), "")
    version = doc.get("version")
    if version is None:
        c.bad("version", f"required (this program reads version = {PLAN_VERSION})")
    elif isinstance(version, bool) or version != PLAN_VERSION:
        c.bad("version", f"unsupported version {show_value(version)}; this program reads version = {PLAN_VERSION}")
    fleet = c.string(doc, "fleet", "", required=True)
    if fleet is not None and any(ch in fleet for ch in "/*$?# "):
        c.bad("fleet", f"must not contain '/', '*', '$', '?', '#' or spaces (a zenoh key chunk), got {fleet!r}")
    origin = _parse_origin(c, doc)
    vehicles = _parse_vehicles(c, doc)
    formation = _parse_formation(c, doc)
    seeking = _parse_seeking(c, doc)
    top = dict(
        max_speed_m_s=c.number(doc, "max_speed_m_s", "", 3.0, low=0, low_open=True, high=30),
        min_separation_m=c.number(doc, "min_separation_m", "", 1.5, low=0, low_open=True),
        takeoff_alt_m=c.number(doc, "takeoff_alt_m", "", 10.0, low=1.0, high=500),
        return_behaviour=c.string(doc, "return", "", "land", choices=_RETURNS),
        stagger_s=c.number(doc, "stagger_s", "", 1.0, low=0, high=60),
        setpoint_rate_hz=c.number(doc, "setpoint_rate_hz", "", 10.0, low=2.0, high=100),
        heartbeat_timeout_s=c.number(doc, "heartbeat_timeout_s", "", 10.0, low=0.5, low_open=False),
        min_battery_pct=c.number(doc, "min_battery_pct", "", 30.0, low=0, high=100),
    )
    geofence = _parse_geofence(c, doc, origin)
    faults = _parse_faults(c, doc)
    zen = parse_zenoh(c, doc, Path(base_dir) if base_dir is not None else None)
    security = _parse_security(c, doc, Path(base_dir) if base_dir is not None else None)
    if formation is not None and vehicles:
        n = len(vehicles)
        if n < 4:
            c.bad("vehicles", f"a formation needs at least 4 vehicles, got {n}")
        elif formation.type == "symmetric" and n % 2:
            c.bad("formation.type", f"the symmetric formation needs an even number of vehicles, got {n}")
    if formation is not None and top["min_separation_m"] is not None and formation.radius_m is not None:
        if formation.radius_m < top["min_separation_m"]:
            c.bad("formation.radius_m", f"radius {formation.radius_m} m is smaller than "
                  f"min_separation_m {top['min_separation_m']} m")
    if geofence is not None and seeking is not None and formation is not None:
        start = seeking.start_point()
        if not geofence.min_alt_m + formation.radius_m <= start[2] <= geofence.max_alt_m - formation.radius_m:
            c.bad("seeking.start_enu_m", f"start altitude {start[2]:.1f} m must leave the formation "
                  f"radius inside the altitude band [{geofence.min_alt_m}, {geofence.max_alt_m}] m")
        if top["takeoff_alt_m"] is not None and not (
                geofence.min_alt_m <= top["takeoff_alt_m"] <= geofence.max_alt_m):
            c.bad("takeoff_alt_m", f"{top['takeoff_alt_m']} m is outside the geofence altitude band")
    if c.problems:
        raise PlanError(c.problems, source)
    return Plan(fleet=fleet, origin=origin, vehicles=tuple(vehicles), formation=formation,
                seeking=seeking, geofence=geofence, zenoh=zen, security=security, version=PLAN_VERSION, faults=faults,
                **top)


def _parse_faults(c: Checker, doc: dict) -> FaultsPlan:
    t = c.table(doc, "faults")
    c.unknown(t, ("readmit", "link_timeout_s", "faulty_sensor", "retire_after", "retire_min_noise_ratio"),
              "faults")
    readmit = t.get("readmit", False)
    if not isinstance(readmit, bool):
        c.bad("faults.readmit", f"must be true or false, got {show_value(readmit)}")
        readmit = False
    timeout = c.number(t, "link_timeout_s", "faults", 1.0, low=0.2, high=1.4)
    d = FaultsPlan()
    faulty = c.string(t, "faulty_sensor", "faults", d.faulty_sensor, choices=_FAULTY_SENSOR)
    after = c.number(t, "retire_after", "faults", d.retire_after, low=1, high=10000, integer=True)
    ratio = c.number(t, "retire_min_noise_ratio", "faults", d.retire_min_noise_ratio, low=1.0, high=100.0)
    return FaultsPlan(readmit=readmit, link_timeout_s=1.0 if timeout is None else timeout,
                      faulty_sensor=faulty, retire_after=after, retire_min_noise_ratio=ratio)


def _parse_origin(c: Checker, doc: dict):
    t = c.table(doc, "origin", required=True)
    c.unknown(t, ("lat_deg", "lon_deg", "alt_m"), "origin")
    lat = c.number(t, "lat_deg", "origin", low=-90, high=90, required=True)
    lon = c.number(t, "lon_deg", "origin", low=-180, high=180, required=True)
    alt = c.number(t, "alt_m", "origin", 0.0, low=-500, high=9000)
    if None in (lat, lon, alt):
        return None
    return (lat, lon, alt)


def _parse_vehicles(c: Checker, doc: dict) -> list[VehiclePlan]:
    raw = doc.get("vehicles")
    if raw is None:
        c.bad("vehicles", "required: at least 4 [[vehicles]] entries")
        return []
    if not isinstance(raw, list) or not all(isinstance(v, dict) for v in raw):
        c.bad("vehicles", "expected an array of tables ([[vehicles]])")
        return []
    out: list[VehiclePlan] = []
    seen_ids: dict[str, int] = {}
    seen_sysids: dict[int, int] = {}
    for i, v in enumerate(raw):
        prefix = f"vehicles[{i}]"
        c.unknown(v, ("id", "sysid", "connection"), prefix)
        sysid = c.number(v, "sysid", prefix, low=1, high=254, required=True, integer=True)
        vid = c.string(v, "id", prefix, f"v{sysid}" if sysid is not None else None)
        conn = c.string(v, "connection", prefix, required=True)
        if conn is not None:
            why = check_connection(conn)
            if why:
                c.bad(f"{prefix}.connection", why)
                conn = None
        if vid is not None and vid in seen_ids:
            c.bad(f"{prefix}.id", f"duplicate id {vid!r} (also vehicles[{seen_ids[vid]}])")
        if sysid is not None and sysid in seen_sysids:
            c.bad(f"{prefix}.sysid", f"duplicate sysid {sysid} (also vehicles[{seen_sysids[sysid]}])")
        if None in (sysid, vid, conn):
            continue
        seen_ids.setdefault(vid, i)
        seen_sysids.setdefault(sysid, i)
        out.append(VehiclePlan(id=vid, sysid=sysid, connection=conn))
    return out


def _parse_formation(c: Checker, doc: dict) -> FormationPlan | None:
    t = c.table(doc, "formation")
    c.unknown(t, ("type", "radius_m", "seed"), "formation")
    kind = c.string(t, "type", "formation", "cvt", choices=_FORMATIONS)
    radius = c.number(t, "radius_m", "formation", 4.0, low=0, low_open=True, high=500)
    seed = c.number(t, "seed", "formation", 0, low=0, integer=True)
    if None in (kind, radius, seed):
        return None
    return FormationPlan(type=kind, radius_m=radius, seed=seed)


def _parse_seeking(c: Checker, doc: dict) -> SeekingPlan | None:
    t = c.table(doc, "seeking")
    p = "seeking"
    c.unknown(t, tuple(SeekingPlan.__dataclass_fields__), p)
    d = SeekingPlan()
    vals = dict(
        eps=c.number(t, "eps", p, d.eps, low=0, low_open=True),
        gamma_m=c.number(t, "gamma_m", p, d.gamma_m, low=0, low_open=True, high=100),
        estimator=c.string(t, "estimator", p, d.estimator, choices=_ESTIMATORS),
        rate_hz=c.number(t, "rate_hz", p, d.rate_hz, low=0, low_open=True, high=50),
        max_iterations=c.number(t, "max_iterations", p, d.max_iterations, low=1, integer=True),
        convergence_tol_m=c.number(t, "convergence_tol_m", p, d.convergence_tol_m, low=0, low_open=True),
        convergence_window=c.number(t, "convergence_window", p, d.convergence_window, low=8, integer=True),
        altitude_m=c.number(t, "altitude_m", p, d.altitude_m),
        arrival_tol_m=c.number(t, "arrival_tol_m", p, d.arrival_tol_m, low=0, low_open=True),
        reading_window_s=c.number(t, "reading_window_s", p, d.reading_window_s, low=0, low_open=True),
        max_reading_age_s=c.number(t, "max_reading_age_s", p, d.max_reading_age_s, low=0, low_open=True),
        max_position_error_m=c.number(t, "max_position_error_m", p, d.max_position_error_m,
                                      low=0, low_open=True),
    )
    start = c.point(t, "start_enu_m", p, 3)
    if None in vals.values():
        return None
    return SeekingPlan(start_enu_m=start, **vals)


def _parse_geofence(c: Checker, doc: dict, origin) -> GeofencePlan | None:
    t = c.table(doc, "geofence")
    p = "geofence"
    c.unknown(t, ("polygon_enu_m", "polygon_latlon_deg", "min_alt_m", "max_alt_m"), p)
    lo = c.number(t, "min_alt_m", p, 2.0)
    hi = c.number(t, "max_alt_m", p, 120.0)
    if lo is not None and hi is not None and lo >= hi:
        c.bad(f"{p}.max_alt_m", f"must be greater than min_alt_m ({lo}), got {hi}")
        hi = None
    if "polygon_enu_m" in t and "polygon_latlon_deg" in t:
        c.bad(p, "give polygon_enu_m or polygon_latlon_deg, not both")
        return None
    polygon: list[tuple[float, float]] = []
    for key in ("polygon_enu_m", "polygon_latlon_deg"):
        if key not in t:
            continue
        raw = t[key]
        path = f"{p}.{key}"
        if not isinstance(raw, list) or len(raw) < 3:
            c.bad(path, f"expected a list of at least 3 [x, y] vertices, got {show_value(raw)}")
            return None
        for j, vertex in enumerate(raw):
            pt = c.point({"v": vertex}, "v", f"{path}[{j}]", 2)
            if pt is None:
                continue
            if key == "polygon_latlon_deg":
                if not (-90 <= pt[0] <= 90 and -180 <= pt[1] <= 180):
                    c.bad(f"{path}[{j}]", f"latitude/longitude out of range: {pt}")
                    continue
                if origin is None:
                    continue
                e, n, _ = geodetic_to_enu(pt[0], pt[1], origin[2], origin)
                pt = (float(e), float(n))
            polygon.append(pt)
        if len(polygon) != len(raw):
            return None
        if abs(polygon_area(polygon)) < 1e-6:
            c.bad(path, "the polygon has zero area")
            return None
    if "polygon_enu_m" not in t and "polygon_latlon_deg" not in t:
        c.bad(p, "required: a polygon_enu_m or polygon_latlon_deg of at least 3 vertices")
        return None
    if lo is None or hi is None:
        return None
    return GeofencePlan(polygon_en_m=tuple(polygon), min_alt_m=lo, max_alt_m=hi)


def _parse_security(c: Checker, doc: dict, base_dir: Path | None) -> SigningConfig | None:
    """``[security]``: MAVLink 2 signing (see :func:`mission.link.signing.signing_config_from_table`)."""
    t = c.table(doc, "security")
    try:
        return signing_config_from_table(t, base_dir)
    except SigningError as exc:
        for key, why in exc.problems:
            c.bad(key, why)
        return None
