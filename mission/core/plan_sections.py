"""Parsers of the plan's sections (``[origin]``, ``[[vehicles]]``, ``[formation]``, ``[seeking]``,
``[geofence]``, ``[faults]``, ``[security]``, ``[preflight]``).

Each takes the :class:`~mission.core.plan_checks.Checker` that collects problems and the decoded
TOML document, records every invalid key of its section and returns the section's value (None
when it is invalid). :func:`mission.core.plan.parse_plan` calls them and adds the checks that span
sections.
"""
from __future__ import annotations

from pathlib import Path

from estimator.seekers import MOVING_SEEKERS, SEEKERS as _SEEKERS, best_seeker
from estimator.ste_model import BRIGGS_RURAL
from formation.geodesy import geodetic_to_enu
from mission.core.fence_file import FenceFile, FenceFileError, fence_in_mission_frame, read_fence_file
from mission.core.plan_checks import Checker, check_connection, join_key, polygon_area, show_value
from mission.core.plan_types import (PLUME_MODES, SAMPLINGS, ControlPlan, FaultsPlan, ForwardPlan, FormationPlan, GeofencePlan,
                                     PreflightPlan, SeekingPlan, VehiclePlan)
from mission.core.signing_config import SigningConfig, signing_config_from_table
from wire.signing import SigningError

__all__ = [
    "LINK_TIMEOUT_MAX_S",
    "RETURN_BEHAVIOURS",
    "parse_faults",
    "parse_origin",
    "parse_geofence_file",
    "parse_vehicles",
    "parse_formation",
    "parse_seeking",
    "parse_geofence",
    "parse_security",
    "parse_require_signing",
    "parse_preflight",
    "parse_control",
    "parse_forward",
    "parse_forward_out",
]

_FORMATIONS = ("cvt", "symmetric")
_ESTIMATORS = ("cvt", "symmetric", "robust")
#: values of the top-level ``return`` key
RETURN_BEHAVIOURS = ("land", "rtl")
#: the longest ``[faults] link_timeout_s`` a plan may give (seconds of silence before a vehicle is lost)
LINK_TIMEOUT_MAX_S = 1.4
_FAULTY_SENSOR = ("retire", "keep", "off")
_STABILITY = tuple(BRIGGS_RURAL)  # the Pasquill-Gifford classes of the dispersion model


def parse_faults(c: Checker, doc: dict) -> FaultsPlan:
    """``[faults]``: vehicle-loss and faulty-sensor handling (defaults when absent)."""
    t = c.table(doc, "faults")
    c.unknown(t, ("readmit", "link_timeout_s", "faulty_sensor", "retire_after", "retire_min_noise_ratio"),
              "faults")
    readmit = t.get("readmit", False)
    if not isinstance(readmit, bool):
        c.bad("faults.readmit", f"must be true or false, got {show_value(readmit)}")
        readmit = False
    timeout = c.number(t, "link_timeout_s", "faults", 1.0, low=0.2, high=LINK_TIMEOUT_MAX_S)
    d = FaultsPlan()
    faulty = c.string(t, "faulty_sensor", "faults", d.faulty_sensor, choices=_FAULTY_SENSOR)
    after = c.number(t, "retire_after", "faults", d.retire_after, low=1, high=10000, integer=True)
    ratio = c.number(t, "retire_min_noise_ratio", "faults", d.retire_min_noise_ratio, low=1.0, high=100.0)
    return FaultsPlan(readmit=readmit, link_timeout_s=1.0 if timeout is None else timeout,
                      faulty_sensor=faulty, retire_after=after, retire_min_noise_ratio=ratio)


def parse_geofence_file(c: Checker, doc: dict, base_dir: Path | None) -> tuple[FenceFile | None, bool]:
    """``[geofence] file``: ``(the fence file read, whether the key is given)``; the file is None
    when absent or refused (the reason recorded under ``geofence.file``). A relative path is
    relative to the plan file (``base_dir``)."""
    t = doc.get("geofence")
    if not isinstance(t, dict) or "file" not in t:
        return None, False
    name = c.string(t, "file", "geofence")
    if name is None:
        return None, True
    path = Path(name).expanduser()
    if not path.is_absolute() and base_dir is not None:
        path = Path(base_dir) / path
    try:
        return read_fence_file(path), True
    except FenceFileError as exc:
        c.bad("geofence.file", str(exc))
        return None, True


def parse_origin(c: Checker, doc: dict, fence_file: FenceFile | None = None, file_given: bool = False):
    """``[origin]`` (required, unless the ``[geofence] file`` gives a home: then that home):
    ``(lat_deg, lon_deg, alt_m)``, or None if invalid."""
    if "origin" not in doc and file_given:
        if fence_file is None:
            return None  # the file was refused: that is the problem to fix first
        if fence_file.home is None:
            why = fence_file.home_problem or f"{fence_file.path} gives no home position"
            c.bad("origin", f"required table missing, and the geofence file cannot stand in: {why}")
            return None
        lat, lon, alt = fence_file.home
        if not -500 <= alt <= 9000:
            c.bad("origin", f"the geofence file's home altitude {alt} m is outside -500..9000 m")
            return None
        return (lat, lon, alt)
    t = c.table(doc, "origin", required=True)
    c.unknown(t, ("lat_deg", "lon_deg", "alt_m"), "origin")
    lat = c.number(t, "lat_deg", "origin", low=-90, high=90, required=True)
    lon = c.number(t, "lon_deg", "origin", low=-180, high=180, required=True)
    alt = c.number(t, "alt_m", "origin", 0.0, low=-500, high=9000)
    if None in (lat, lon, alt):
        return None
    return (lat, lon, alt)


def parse_vehicles(c: Checker, doc: dict) -> list[VehiclePlan]:
    """``[[vehicles]]``: id, sysid and connection of each; duplicates are problems."""
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


def parse_formation(c: Checker, doc: dict) -> FormationPlan | None:
    """``[formation]``: type, radius and seed, or None if invalid."""
    t = c.table(doc, "formation")
    c.unknown(t, ("type", "radius_m", "seed"), "formation")
    kind = c.string(t, "type", "formation", "cvt", choices=_FORMATIONS)
    radius = c.number(t, "radius_m", "formation", 4.0, low=0, low_open=True, high=500)
    seed = c.number(t, "seed", "formation", 0, low=0, integer=True)
    if None in (kind, radius, seed):
        return None
    return FormationPlan(type=kind, radius_m=radius, seed=seed)


def parse_seeking(c: Checker, doc: dict) -> SeekingPlan | None:
    """``[seeking]``: the source-seeking parameters, or None if invalid."""
    t = c.table(doc, "seeking")
    p = "seeking"
    c.unknown(t, tuple(SeekingPlan.__dataclass_fields__), p)
    d = SeekingPlan()
    seeker = c.string(t, "seeker", p, best_seeker(_field_type(doc)), choices=_SEEKERS)
    vals = dict(
        eps=c.number(t, "eps", p, d.eps, low=0, low_open=True),
        gamma_m=c.number(t, "gamma_m", p, d.gamma_m if seeker == "gradient" else NON_GRADIENT_GAMMA_M,
                         low=0, low_open=True, high=100),
        estimator=c.string(t, "estimator", p, d.estimator, choices=_ESTIMATORS),
        seeker=seeker,
        sampling=c.string(t, "sampling", p, "moving" if seeker in MOVING_SEEKERS else "stop_and_go",
                          choices=SAMPLINGS),
        plume_mode=c.string(t, "plume_mode", p, _default_plume_mode(doc, d), choices=PLUME_MODES),
        replan_fraction=c.number(t, "replan_fraction", p, d.replan_fraction, low=0, low_open=True, high=1),
        sensor_lag_s=c.number(t, "sensor_lag_s", p, d.sensor_lag_s, low=0, high=60),
        rate_hz=c.number(t, "rate_hz", p, d.rate_hz, low=0, low_open=True, high=50),
        max_iterations=c.number(t, "max_iterations", p, d.max_iterations, low=1, integer=True),
        convergence_tol_m=c.number(t, "convergence_tol_m", p, d.convergence_tol_m, low=0, low_open=True),
        convergence_window=c.number(t, "convergence_window", p, d.convergence_window, low=8, integer=True),
        region_hold=c.number(t, "region_hold", p, d.region_hold, low=0, high=1000, integer=True),
        altitude_m=c.number(t, "altitude_m", p, d.altitude_m),
        arrival_tol_m=c.number(t, "arrival_tol_m", p, d.arrival_tol_m, low=0, low_open=True),
        reading_window_s=c.number(t, "reading_window_s", p, d.reading_window_s, low=0, low_open=True),
        max_reading_age_s=c.number(t, "max_reading_age_s", p, d.max_reading_age_s, low=0, low_open=True),
        max_position_error_m=c.number(t, "max_position_error_m", p, d.max_position_error_m,
                                      low=0, low_open=True),
        min_signal_fraction=c.number(t, "min_signal_fraction", p, d.min_signal_fraction, low=0, high=1),
        **_ste_keys(c, t, d),
    )
    start = c.point(t, "start_enu_m", p, 3)
    if vals["region_hold"] == 1:
        c.bad(f"{p}.region_hold", "must be 0 (the region rule off) or at least 2 iterations: one tight region "
              "is not a confirmation")
        vals["region_hold"] = None
    if vals["sampling"] == "moving" and vals["seeker"] not in MOVING_SEEKERS:
        c.bad(f"{p}.sampling", 'sampling = "moving" needs seeker = "model", "newton" or "ste": the paper\'s '
              "gradient seeker estimates from the formation's shape at rest (Theorem 2) and the plume seeker's "
              "passes compare readings taken at rest, so they sample stop and go")
        vals["sampling"] = None
    wind = c.number(t, "wind_from_deg", p, None, low=0, high=360)  # None: not given (or invalid, reported)
    _check_keys_apply(c, t, vals["seeker"], vals["sampling"])
    if "wind_std_deg" in t and "wind_from_deg" not in t and "seeking.wind_std_deg" not in {k for k, _ in c.problems}:
        c.bad(f"{p}.wind_std_deg", "is the spread of the wind prior about wind_from_deg: give wind_from_deg too "
              "(without it the ste seeker estimates the wind's direction from a uniform prior)")
    if None in vals.values():
        return None
    return SeekingPlan(start_enu_m=start, wind_from_deg=wind, **vals)


def _field_type(doc: dict) -> str | None:
    """The plan's ``[field] type`` as written (checked by ``parse_field``), or None."""
    field = doc.get("field")
    kind = field.get("type") if isinstance(field, dict) else None
    return kind if isinstance(kind, str) else None


def _default_plume_mode(doc: dict, d: SeekingPlan) -> str:
    """``intermittent`` on the intermittent plume (hits and misses), else the dataclass default."""
    return "intermittent" if _field_type(doc) == "intermittent" else d.plume_mode


def _ste_keys(c: Checker, t: dict, d: SeekingPlan) -> dict:
    """The ``ste`` seeker's ``[seeking]`` keys (:class:`~mission.core.plan_types.SeekingPlan`), checked."""
    p = "seeking"
    return dict(
        wind_std_deg=c.number(t, "wind_std_deg", p, d.wind_std_deg, low=0, high=180),
        sensor_noise_std=c.number(t, "sensor_noise_std", p, d.sensor_noise_std, low=0, low_open=True),
        sensor_detection_floor=c.number(t, "sensor_detection_floor", p, d.sensor_detection_floor, low=0),
        ground_alt_m=c.number(t, "ground_alt_m", p, d.ground_alt_m, low=-500, high=9000),
        stability=c.string(t, "stability", p, d.stability, choices=_STABILITY),
        region_m=c.number(t, "region_m", p, d.region_m, low=0, low_open=True, high=100),
        prior_box=c.string(t, "prior_box", p, d.prior_box, choices=("fence", "none")),
    )


#: ``gamma_m`` when the plan gives none, for every seeker but the paper's ``gradient`` (whose default
#: is the paper's 0.1 m): their steps are bounded by their own trust region or passes (as ``swarmseek run``)
NON_GRADIENT_GAMMA_M = 20.0

_STE = 'seeker = "ste"'
_PLUME_OR_STE = 'seeker = "plume" or "ste"'
#: [seeking] keys of one seeker or sampling mode: (key, what it needs, does it apply?(seeker, sampling))
_SEEKING_KEYS_OF = (
    ("plume_mode", _PLUME_OR_STE, lambda seeker, sampling: seeker in ("plume", "ste")),
    ("wind_from_deg", _PLUME_OR_STE, lambda seeker, sampling: seeker in ("plume", "ste")),
    ("wind_std_deg", _STE, lambda seeker, sampling: seeker == "ste"),
    ("sensor_noise_std", _STE, lambda seeker, sampling: seeker == "ste"),
    ("sensor_detection_floor", _STE, lambda seeker, sampling: seeker == "ste"),
    ("ground_alt_m", _STE, lambda seeker, sampling: seeker == "ste"),
    ("stability", _STE, lambda seeker, sampling: seeker == "ste"),
    ("region_m", _STE, lambda seeker, sampling: seeker == "ste"),
    ("prior_box", _STE, lambda seeker, sampling: seeker == "ste"),
    ("replan_fraction", 'sampling = "moving"', lambda seeker, sampling: sampling == "moving"),
    ("sensor_lag_s", 'sampling = "moving"', lambda seeker, sampling: sampling == "moving"),
)


def _check_keys_apply(c: Checker, t: dict, seeker: str | None, sampling: str | None) -> None:
    """A ``[seeking]`` key written for another seeker or sampling mode is refused, never ignored
    (docs/seekers.md, "Options that do not apply"); a key already reported invalid is not
    reported twice."""
    if seeker is None or sampling is None:
        return
    reported = {key for key, _ in c.problems}
    for key, needs, applies in _SEEKING_KEYS_OF:
        path = join_key("seeking", key)
        if key in t and path not in reported and not applies(seeker, sampling):
            c.bad(path, f"applies only with {needs}; this plan has seeker = {seeker!r}, sampling = {sampling!r}"
                        " (remove the key)")


def parse_geofence(c: Checker, doc: dict, origin, fence_file: FenceFile | None = None) -> GeofencePlan | None:
    """``[geofence]`` (required): polygon (mission ENU, lat/lon or a fence file, converted about
    ``origin``) and altitude band, or None if invalid."""
    t = c.table(doc, "geofence")
    p = "geofence"
    c.unknown(t, ("polygon_enu_m", "polygon_latlon_deg", "file", "min_alt_m", "max_alt_m"), p)
    lo = c.number(t, "min_alt_m", p, 2.0)
    hi = c.number(t, "max_alt_m", p, 120.0)
    if lo is not None and hi is not None and lo >= hi:
        c.bad(f"{p}.max_alt_m", f"must be greater than min_alt_m ({lo}), got {hi}")
        hi = None
    given = [k for k in ("polygon_enu_m", "polygon_latlon_deg", "file") if k in t]
    if len(given) > 1:
        c.bad(p, f"give one of polygon_enu_m, polygon_latlon_deg or file, not {' and '.join(given)}")
        return None
    if "file" in t:
        return _geofence_from_file(c, fence_file, origin, lo, hi, "origin" not in doc)
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
        c.bad(p, "required: a polygon_enu_m or polygon_latlon_deg of at least 3 vertices, or a fence file")
        return None
    if lo is None or hi is None:
        return None
    return GeofencePlan(polygon_en_m=tuple(polygon), min_alt_m=lo, max_alt_m=hi)


def _geofence_from_file(c: Checker, fence_file: FenceFile | None, origin, lo, hi,
                        origin_from_file: bool) -> GeofencePlan | None:
    """The ``[geofence]`` of a fence file: its polygon converted about ``origin``, the plan's band."""
    if fence_file is None or origin is None:
        return None  # refused (reported by parse_geofence_file) or no origin (reported by parse_origin)
    try:
        polygon = fence_in_mission_frame(fence_file, origin)
    except FenceFileError as exc:
        c.bad("geofence.file", str(exc))
        return None
    if abs(polygon_area(polygon)) < 1e-6:
        c.bad("geofence.file", f"{fence_file.path}: the polygon has zero area")
        return None
    if lo is None or hi is None:
        return None
    return GeofencePlan(polygon_en_m=polygon, min_alt_m=lo, max_alt_m=hi,
                        source=f"{fence_file.path}: {fence_file.what}",
                        source_latlon_deg=fence_file.polygon_latlon_deg, origin_from_file=origin_from_file)


def parse_security(c: Checker, doc: dict, base_dir: Path | None) -> SigningConfig | None:
    """``[security]``: MAVLink 2 signing (see :func:`mission.core.signing_config.signing_config_from_table`)."""
    t = c.table(doc, "security")
    try:
        return signing_config_from_table(t, base_dir)
    except SigningError as exc:
        for key, why in exc.problems:
            c.bad(key, why)
        return None


def parse_require_signing(doc: dict) -> bool:
    """``[security] require_signing`` (default false; a wrong type is reported by
    :func:`parse_security`)."""
    t = doc.get("security")
    value = t.get("require_signing", False) if isinstance(t, dict) else False
    return value if isinstance(value, bool) else False


def parse_preflight(c: Checker, doc: dict) -> PreflightPlan:
    """``[preflight]``: autopilot readiness timeout and failsafe requirement, sensor readings
    required before arming (defaults when absent)."""
    t = c.table(doc, "preflight")
    c.unknown(t, ("autopilot_ready_timeout_s", "require_gcs_failsafe", "require_readings",
                  "readings_timeout_s"), "preflight")
    d = PreflightPlan()
    timeout = c.number(t, "autopilot_ready_timeout_s", "preflight", d.autopilot_ready_timeout_s,
                       low=1.0, high=3600.0)
    require = t.get("require_gcs_failsafe", d.require_gcs_failsafe)
    if not isinstance(require, bool):
        c.bad("preflight.require_gcs_failsafe", f"must be true or false, got {show_value(require)}")
        require = d.require_gcs_failsafe
    readings = t.get("require_readings", d.require_readings)
    if not isinstance(readings, bool):
        c.bad("preflight.require_readings", f"must be true or false, got {show_value(readings)}")
        readings = d.require_readings
    readings_timeout = c.number(t, "readings_timeout_s", "preflight", d.readings_timeout_s, low=0.5, high=600.0)
    return PreflightPlan(autopilot_ready_timeout_s=d.autopilot_ready_timeout_s if timeout is None else timeout,
                         require_gcs_failsafe=require, require_readings=readings,
                         readings_timeout_s=d.readings_timeout_s if readings_timeout is None else readings_timeout)


def parse_control(c: Checker, doc: dict) -> ControlPlan:
    """``[control]``: operator commands over zenoh (defaults when absent)."""
    t = c.table(doc, "control")
    c.unknown(t, ("remote",), "control")
    remote = t.get("remote", True)
    if not isinstance(remote, bool):
        c.bad("control.remote", f"must be true or false, got {show_value(remote)}")
        remote = True
    return ControlPlan(remote=remote)


def parse_forward_out(text: str) -> tuple[str, int]:
    """``(host, port)`` of a forward address ``udp:HOST:PORT`` (``udpout:`` accepted too).

    Raises
    ------
    ValueError
        Not of that form, or the port is not in 1..65535.
    """
    kind, sep, rest = str(text).partition(":")
    host, sep2, port = rest.rpartition(":")
    if kind not in ("udp", "udpout") or not sep or not sep2 or not host:
        raise ValueError(f"forward address {text!r} must look like udp:HOST:PORT (e.g. udp:127.0.0.1:14550)")
    if not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ValueError(f"forward address {text!r}: port must be 1..65535")
    problem = _forward_host_problem(host)
    if problem:
        raise ValueError(f"forward address {text!r}: {problem}")
    return host, int(port)


def _forward_host_problem(host: str) -> str | None:
    """Why ``host`` is neither a dotted IPv4 address nor a host name (None when it is one)."""
    import ipaddress

    if all(ch.isdigit() or ch == "." for ch in host):  # meant as an address: exactly a.b.c.d, each 0..255
        try:
            ipaddress.IPv4Address(host)
        except ValueError:
            return f"{host!r} is not an IPv4 address (four numbers 0..255, e.g. 192.168.1.10)"
        return None
    labels = host.rstrip(".").split(".")
    if len(host) > 253 or not all(0 < len(lab) <= 63 and lab.replace("-", "").replace("_", "").isalnum() and lab.isascii()
                                  and not lab.startswith("-") and not lab.endswith("-") for lab in labels):
        return f"{host!r} is not an IPv4 address or a host name (letters, digits, '-', '_' and '.')"
    return None


def parse_forward(c: Checker, doc: dict) -> ForwardPlan:
    """``[forward]``: MAVLink forwarding to ground-control clients (defaults when absent)."""
    t = c.table(doc, "forward")
    c.unknown(t, ("out", "allow_commands"), "forward")
    allow = t.get("allow_commands", False)
    if not isinstance(allow, bool):
        c.bad("forward.allow_commands", f"must be true or false, got {show_value(allow)}")
        allow = False
    outs = c.strings(t, "out", "forward")
    for j, out in enumerate(outs):
        try:
            parse_forward_out(out)
        except ValueError as exc:
            c.bad(f"forward.out[{j}]", str(exc))
    return ForwardPlan(out=tuple(outs), allow_commands=allow)
