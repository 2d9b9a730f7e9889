"""A ready-to-fly plan file for a running SITL fleet (the format of ``docs/mission.md``).

The plan is the sample plan's mission (``mission/examples/sitl_plan.toml``: CVT formation of
radius 2 m, ``eps = 50``, ``gamma_m = 1``, fence +-60 m, 3..40 m) with the fleet's vehicles
(system ids, connections), its origin (the first vehicle's home) and a zenoh endpoint on which
the coordinator listens and the sensors connect. ``overrides`` replaces any key, section by
section. The file written is read back with :func:`mission.core.plan.load_plan`, so a plan that
would not load is never left behind.
"""
from __future__ import annotations

import copy
import os
from pathlib import Path

from estimator.seekers import MOVING_SEEKERS
from mission.core.plan import load_plan

__all__ = ["plan_document", "scale_for_speedup", "seeker_settings", "write_plan", "to_toml"]

_BASE = {
    "version": 1, "fleet": "sitl", "max_speed_m_s": 3.0, "min_separation_m": 1.5, "takeoff_alt_m": 10.0,
    "return": "land", "stagger_s": 2.0, "setpoint_rate_hz": 10.0, "min_battery_pct": 30.0,
    "formation": {"type": "cvt", "radius_m": 2.0, "seed": 0},
    "seeking": {"eps": 50.0, "gamma_m": 1.0, "estimator": "cvt", "rate_hz": 1.0, "max_iterations": 300,
                "convergence_tol_m": 0.5, "convergence_window": 10, "start_enu_m": [0.0, 20.0, 15.0],
                "arrival_tol_m": 0.7, "reading_window_s": 0.6, "max_reading_age_s": 5.0,
                "max_position_error_m": 10.0},
    "faults": {"readmit": False, "link_timeout_s": 1.0},
    "geofence": {"polygon_enu_m": [[-60.0, -60.0], [60.0, -60.0], [60.0, 60.0], [-60.0, 60.0]],
                 "min_alt_m": 3.0, "max_alt_m": 40.0},
}


def seeker_settings(seeker: str) -> dict:
    """The ``[seeking]`` keys for ``seeker``: the paper's ``gradient`` keeps the sample plan's
    ``gamma_m = 1`` (with its ``eps``) and samples stop and go; the other seekers get
    ``gamma_m = 20`` m, as ``swarmseek run`` (their step is bounded by their own trust region or
    passes, not by ``eps``), and ``newton``/``model`` sample while moving (measured on real PX4
    and ArduCopter, docs/sitl.md), as ``ste`` does (it folds in every reading where it was taken;
    its other keys keep their defaults: a steady plume, the wind estimated, docs/mission.md)."""
    return {"seeker": seeker, "gamma_m": 1.0 if seeker == "gradient" else 20.0,
            "sampling": "moving" if seeker in MOVING_SEEKERS else "stop_and_go"}


def scale_for_speedup(doc: dict, speedup: float) -> dict:
    """Scale a plan's wall-clock quantities for a SITL running ``speedup`` times real time.

    The ground station measures everything in wall time; the vehicles live in simulated time.
    At speed-up ``S`` a vehicle flying ``v`` m/s (simulated) covers ``S v`` m per wall second,
    so the setpoint speed limit, the seeking rate and the setpoint rate are multiplied by ``S``
    and the takeoff stagger and reading window divided by ``S``: the mission the vehicles fly
    (speeds, iterations per simulated second, readings per iteration) is the real-time one.
    """
    if speedup == 1.0:
        return doc
    doc["max_speed_m_s"] = round(doc["max_speed_m_s"] * speedup, 6)
    doc["stagger_s"] = round(doc["stagger_s"] / speedup, 6)
    doc["setpoint_rate_hz"] = round(min(doc["setpoint_rate_hz"] * speedup, 50.0), 6)
    seeking = doc["seeking"]
    seeking["rate_hz"] = round(seeking["rate_hz"] * speedup, 6)
    seeking["reading_window_s"] = round(seeking["reading_window_s"] / speedup, 6)
    return doc


def plan_document(vehicles, origin, *, flavour: str, fleet: str = "sitl",
                  zenoh_endpoint: str = "tcp/127.0.0.1:7447", overrides: dict | None = None,
                  speedup: float = 1.0) -> dict:
    """The plan as a TOML-ready mapping.

    Parameters
    ----------
    vehicles : sequence
        Objects with ``sysid`` and ``connection`` (e.g. :class:`~mission.sim.sitl_fleet.SitlVehicle`).
    origin : tuple of float
        ``(lat_deg, lon_deg, alt_m)`` of the mission frame.
    flavour : str
        Used in the vehicle names (``px41``, ``ard1``...).
    fleet : str
        The zenoh fleet name (``swarmseek sensor --fleet``).
    zenoh_endpoint : str
        The coordinator listens here; sensors connect to it.
    overrides : dict, optional
        Keys replacing the defaults; a dict value updates that section (applied before the
        speed-up scaling: give real-time values).
    speedup : float
        The SITL's speed-up (see :func:`scale_for_speedup`).
    """
    doc = copy.deepcopy(_BASE)
    doc["fleet"] = fleet
    for key, value in (overrides or {}).items():
        if isinstance(value, dict) and isinstance(doc.get(key), dict):
            doc[key].update(value)
        else:
            doc[key] = value
    scale_for_speedup(doc, speedup)
    doc["origin"] = {"lat_deg": float(origin[0]), "lon_deg": float(origin[1]), "alt_m": float(origin[2])}
    prefix = "px4-" if flavour == "px4" else "copter"
    doc["vehicles"] = [{"id": f"{prefix}{v.sysid}", "sysid": int(v.sysid), "connection": v.connection}
                       for v in vehicles]
    doc["zenoh"] = {"mode": "peer", "listen": [zenoh_endpoint]}
    return doc


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def to_toml(doc: dict) -> str:
    """TOML text of a plan mapping: scalars, tables, arrays of tables (one level deep)."""
    lines = [f"{k} = {_value(v)}" for k, v in doc.items() if not isinstance(v, dict)
             and not (isinstance(v, list) and v and isinstance(v[0], dict))]
    for key, value in doc.items():
        if isinstance(value, dict):
            lines += ["", f"[{key}]"] + [f"{k} = {_value(v)}" for k, v in value.items()]
        elif isinstance(value, list) and value and isinstance(value[0], dict):
            for item in value:
                lines += ["", f"[[{key}]]"] + [f"{k} = {_value(v)}" for k, v in item.items()]
    return "\n".join(lines) + "\n"


def write_plan(path: str | os.PathLike, vehicles, origin, *, flavour: str, **options) -> Path:
    """Write :func:`plan_document` to ``path`` as TOML, check that it loads, return the path.

    Raises
    ------
    mission.core.plan.PlanError
        The plan does not validate (e.g. an override out of range); the file is removed.
    """
    out = Path(path)
    text = "# swarmseek plan for a SITL fleet started by `swarmseek sitl` (docs/sitl.md)\n"
    text += to_toml(plan_document(vehicles, origin, flavour=flavour, **options))
    out.write_text(text)
    try:
        load_plan(out)
    except Exception:
        out.unlink(missing_ok=True)
        raise
    return out
