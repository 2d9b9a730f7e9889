"""Mission plan: a versioned TOML file (``version = 1``) validated all at once.

A plan names the fleet, the mission origin, the vehicles and their MAVLink connections, the
formation, the seeking parameters, the safety envelope (geofence, speed limit, separation) and
the zenoh configuration. :func:`load_plan` reads a file, :func:`parse_plan` a decoded TOML
mapping; both raise :class:`PlanError` listing EVERY invalid key with its dotted path and why.

The file format is documented in ``docs/mission.md`` and illustrated by
``mission/examples/sitl_plan.toml``.

The data model is in :mod:`mission.core.plan_types` and the section parsers in
:mod:`mission.core.plan_sections`; this module reads the file and checks the document as a
whole (the model is imported from :mod:`mission.core.plan_types`).
"""
from __future__ import annotations
import tomllib
from pathlib import Path

from mission.core.plan_checks import check_prior_box, check_start_in_fence, Checker, show_value
from mission.core.plan_field import parse_field
from wire.fleet_name import fleet_name_problem
from mission.core.plan_sections import (
    RETURN_BEHAVIOURS,
    parse_control,
    parse_faults,
    parse_forward,
    parse_formation,
    parse_geofence,
    parse_geofence_file,
    parse_origin,
    parse_preflight,
    parse_require_signing,
    parse_security,
    parse_seeking,
    parse_vehicles,
)
from mission.core.plan_security import PlanSecurityError, check_security, refusals
from mission.core.plan_types import PLAN_VERSION, Plan, PlanError
from wire.loopback import IsLoopback, host_is_loopback
from mission.core.zenoh_security import parse_zenoh

__all__ = ["load_plan", "parse_plan"]


def load_plan(path: str | Path, *, is_loopback: IsLoopback = host_is_loopback) -> Plan:
    """Read and validate a plan file.

    Parameters
    ----------
    path : str or pathlib.Path
        TOML file.
    is_loopback : callable
        The security check's loopback rule (see :func:`parse_plan`).

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
    return parse_plan(doc, source=str(path), base_dir=path.parent, is_loopback=is_loopback)


def parse_plan(doc: dict, *, source: str | None = None, base_dir: str | Path | None = None,
               is_loopback: IsLoopback = host_is_loopback) -> Plan:
    """Validate a decoded TOML document and build a :class:`Plan`.

    Parameters
    ----------
    doc : dict
        The decoded TOML.
    source : str, optional
        Where it came from (for error messages).
    base_dir : path, optional
        Relative TLS and fence file paths are resolved against it.
    is_loopback : callable
        ``host -> bool`` for the security check (:func:`mission.core.plan_security.check_security`,
        run once every key is valid; default :func:`wire.loopback.host_is_loopback`).

    Raises
    ------
    PlanError
        Listing every invalid key with its path and why.
    PlanSecurityError
        (a PlanError) The security check refuses the plan: one line per refusal.
    """
    c = Checker()
    if not isinstance(doc, dict):
        raise PlanError([("(document)", "expected a TOML table")], source)
    c.unknown(doc, ("version", "fleet", "origin", "vehicles", "formation", "seeking", "geofence",
                    "zenoh", "security", "max_speed_m_s", "min_separation_m", "takeoff_alt_m", "return",
                    "stagger_s", "setpoint_rate_hz", "heartbeat_timeout_s", "min_battery_pct",
                    "faults", "preflight", "field", "control", "forward"), "")
    version = doc.get("version")
    if version is None:
        c.bad("version", f"required (this program reads version = {PLAN_VERSION})")
    elif isinstance(version, bool) or version != PLAN_VERSION:
        c.bad("version", f"unsupported version {show_value(version)}; this program reads version = {PLAN_VERSION}")
    fleet = c.string(doc, "fleet", "", required=True)
    if fleet is not None and fleet_name_problem(fleet):
        c.bad("fleet", f"{fleet_name_problem(fleet)}, got {show_value(fleet)}")
    base = Path(base_dir) if base_dir is not None else None
    fence_file, fence_file_given = parse_geofence_file(c, doc, base)
    origin = parse_origin(c, doc, fence_file, fence_file_given)
    vehicles = parse_vehicles(c, doc)
    formation = parse_formation(c, doc)
    seeking = parse_seeking(c, doc)
    top = _top_level(c, doc)
    geofence = parse_geofence(c, doc, origin, fence_file)
    faults = parse_faults(c, doc)
    preflight = parse_preflight(c, doc)
    zen = parse_zenoh(c, doc, Path(base_dir) if base_dir is not None else None)
    security = parse_security(c, doc, Path(base_dir) if base_dir is not None else None)
    field = parse_field(c, doc)
    control, forward = parse_control(c, doc), parse_forward(c, doc)
    _check_across_sections(c, doc, formation, seeking, geofence, top)
    if c.problems:
        raise PlanError(c.problems, source)
    plan = Plan(fleet=fleet, origin=origin, vehicles=tuple(vehicles), formation=formation,
                seeking=seeking, geofence=geofence, zenoh=zen, security=security,
                require_signing=parse_require_signing(doc), version=PLAN_VERSION, faults=faults,
                preflight=preflight, field=field, control=control, forward=forward, **top)
    refused = refusals(check_security(plan, is_loopback=is_loopback))
    if refused:
        raise PlanSecurityError(refused, source)
    return plan


def _top_level(c: Checker, doc: dict) -> dict:
    """The plan's top-level numbers and the return behaviour, by :class:`Plan` field name."""
    return dict(
        max_speed_m_s=c.number(doc, "max_speed_m_s", "", 3.0, low=0, low_open=True, high=30),
        min_separation_m=c.number(doc, "min_separation_m", "", 1.5, low=0, low_open=True),
        takeoff_alt_m=c.number(doc, "takeoff_alt_m", "", 10.0, low=1.0, high=500),
        return_behaviour=c.string(doc, "return", "", "land", choices=RETURN_BEHAVIOURS),
        stagger_s=c.number(doc, "stagger_s", "", 1.0, low=0, high=60),
        setpoint_rate_hz=c.number(doc, "setpoint_rate_hz", "", 10.0, low=2.0, high=100),
        heartbeat_timeout_s=c.number(doc, "heartbeat_timeout_s", "", 10.0, low=0.5, low_open=False),
        min_battery_pct=c.number(doc, "min_battery_pct", "", 30.0, low=0, high=100),
    )


def _check_across_sections(c: Checker, doc: dict, formation, seeking, geofence, top: dict) -> None:
    """Checks that span sections: fleet size for the formation, radius against separation, the
    seeking start and the take-off altitude inside the geofence's altitude band.

    Each check runs only when the keys it reads were valid, so that one bad value is reported
    once, at its key, and not again as a consequence elsewhere (a bad ``[[vehicles]]`` entry is
    not also "a formation needs at least 4 vehicles"; an invalid ``min_separation_m`` is not
    compared, as its default, with the radius). The fleet size is the number of ``[[vehicles]]``
    entries written, valid or not.
    """
    failed = {key for key, _ in c.problems}

    def ok(*keys: str) -> bool:
        return not any(f == k or f.startswith((k + ".", k + "[")) for f in failed for k in keys)

    raw = doc.get("vehicles")
    if formation is not None and isinstance(raw, list) and raw and ok("formation.type"):
        n = len(raw)
        if n < 4:
            c.bad("vehicles", f"a formation needs at least 4 vehicles, got {n}")
        elif formation.type == "symmetric" and n % 2:
            c.bad("formation.type", f"the symmetric formation needs an even number of vehicles, got {n}")
    if (formation is not None and top["min_separation_m"] is not None and formation.radius_m is not None
            and ok("min_separation_m")):
        if formation.radius_m < top["min_separation_m"]:
            c.bad("formation.radius_m", f"radius {formation.radius_m} m is smaller than "
                  f"min_separation_m {top['min_separation_m']} m")
    if geofence is not None and seeking is not None and formation is not None and ok("seeking.start_enu_m"):
        start = seeking.start_point()
        if not geofence.min_alt_m + formation.radius_m <= start[2] <= geofence.max_alt_m - formation.radius_m:
            c.bad("seeking.start_enu_m", f"start altitude {start[2]:.1f} m must leave the formation "
                  f"radius inside the altitude band [{geofence.min_alt_m}, {geofence.max_alt_m}] m")
        check_start_in_fence(c, formation.radius_m, start, geofence.polygon_en_m)
    if geofence is not None and seeking is not None:
        check_prior_box(c, seeking.prior_box if seeking.seeker == "ste" else "none", seeking.ground_alt_m,
                        geofence.max_alt_m)
    if geofence is not None and top["takeoff_alt_m"] is not None and ok("takeoff_alt_m") and not (
            geofence.min_alt_m <= top["takeoff_alt_m"] <= geofence.max_alt_m):
        c.bad("takeoff_alt_m", f"{top['takeoff_alt_m']} m is outside the geofence altitude band")
