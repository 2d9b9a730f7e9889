"""Audit a flown mission from its ``.tlog`` files: did any setpoint break the fence, the speed
limit or the separation?

:func:`audit_mission` reads ``LOG_DIR/mission.jsonl`` (its ``plan`` record: geofence in the
mission ENU frame, ``max_speed_m_s``, ``min_separation_m``, ``origin``) and every
``LOG_DIR/tlogs/*.tlog`` (pymavlink reads them). It is independent of the code that produced
the setpoints: it decodes what the ground station actually **sent** and places it in the mission
frame with :mod:`formation.geodesy` only.

* Setpoints: ``SET_POSITION_TARGET_LOCAL_NED`` and ``SET_POSITION_TARGET_GLOBAL_INT`` sent by
  the ground station (source system ``gcs_sysid``, 255). A frame whose ``type_mask`` ignores
  all three position components (velocity/acceleration only) is skipped and counted; one that
  ignores only some, or uses a frame the audit cannot place (``LOCAL_OFFSET_NED``,
  ``BODY_NED``, terrain altitude), is a ``frame`` violation (it cannot be proved safe).
  Take-off and landing commands (``COMMAND_LONG`` NAV_TAKEOFF, NAV_LAND, DO_SET_MODE) are not
  setpoints.
* LOCAL_NED to mission ENU: the vehicle's LOCAL_NED origin is its last ``HOME_POSITION``
  received *before* the setpoint (home geodetic moved back by the home's local ``x, y, z``), as
  the ground station does (``docs/interfaces.md``). A LOCAL_NED setpoint with no home before it
  is a ``no_home`` violation. ``GLOBAL_INT`` (AMSL) and ``GLOBAL_RELATIVE_ALT_INT`` (above that
  home) are placed directly.
* Checks: inside the fence polygon and altitude band within ``fence_tol_m`` (1 cm: HOME_POSITION
  carries 1e-7 deg, about 1.1 cm, and mm altitude); the speed between consecutive setpoints of a
  vehicle (distance / tlog time difference, see below): each step at most
  ``max_speed_m_s * (dt + stamp_jitter_s)``; the separation between every
  pair of commanded vehicles, both "latest vs latest" at every setpoint instant (read
  ``stamp_jitter_s`` after it: the datagrams of one streamer burst count as sent together) and along the
  straight paths between consecutive setpoints (piecewise-linear commanded trajectories,
  closest approach in closed form), at least ``min_separation_m - separation_tol_m``.
* A vehicle is *commanded* from its first setpoint until ``stale_after_s`` after its last one
  (PX4 leaves offboard after about a second without setpoints), or until its own HEARTBEAT (in
  its tlog) says it no longer flies setpoints (disarmed, or out of OFFBOARD / GUIDED: a
  failsafe, RTL, LAND), whichever comes first; a longer gap ends a track and a later setpoint
  starts a new one (no path is drawn across a gap).

**Completeness.** A clean report vouches for the whole mission only if the audit saw it whole;
it is *incomplete* (``AuditReport.incomplete``: the reasons; ``swarmseek audit`` exit status 3)
when no setpoint was checked (e.g. the wrong ``gcs_sysid``), when a planned vehicle's tlog is
missing or empty, or when the log's plan and the tlogs disagree: setpoints sent to a system id
not in the plan, several missions' plan records in one ``mission.jsonl`` (a resume's own plan
record, ``resumed: true``, is not another mission), or plan records with different vehicles.

**Clock.** The tlog stamps are written by :class:`mission.link.tlog.TlogSet` with the mission clock's
``time()`` (``links.py`` passes ``clock.time``): on the simulated timeline when the mission
embeds the mock fleet (a :class:`sitl_mock.clock.SimClock` at 10x: stamps advance 10 s per wall
second), wall time against real vehicles. Speeds are therefore metres per mission-clock second,
the clock the speed limit is enforced on.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from mission.safety.audit_read import (
    AuditError,
    AuditViolation,
    find_tlogs,
    load_plan_limits,
    read_vehicle_setpoints,
    read_vehicle_setpoints_fast,
)
from mission.safety.audit_pairs import apply_track_pair, check_pairs_fast, track_pair
from mission.safety.geometry import boundary_distance, point_in_polygon

__all__ = ["AuditReport", "audit_mission"]

_MAX_LISTED = 200                       # violations listed per kind (all are counted)


@dataclass
class AuditReport:
    """Result of :func:`audit_mission`.

    Attributes
    ----------
    log_dir : str
    tlogs : list of str
        The audited tlogs: those of the plan's vehicles.
    ignored_tlogs : list of str
        Tlogs of system ids that are not planned vehicles (listed, not audited or counted).
    setpoints_checked : int
        Position setpoints checked against the fence and band.
    setpoints_skipped : int
        Velocity-only setpoints (no position to check).
    per_vehicle : dict
        sysid -> ``{"setpoints", "skipped", "homes", "max_step_speed_m_s", "max_window_speed_m_s",
        "tracks"}`` (tracks: runs of setpoints without a gap longer than ``stale_after_s``).
    speed_steps_checked : int
        Consecutive-setpoint pairs checked for speed.
    separation_instants_checked : int
        (instant, pair) checks of latest-vs-latest setpoints.
    separation_segments_checked : int
        (path segment, pair) checks of the closest approach.
    max_speed_seen_m_s : float
        Largest speed over any window of at least ``speed_window_s``.
    max_step_speed_m_s : float
        Largest raw speed between two consecutive setpoints (for information: sampling).
    min_separation_seen_m : float
        Smallest distance between two commanded vehicles (paths included).
    min_fence_margin_m : float
        Smallest distance inside the fence prism (negative = outside).
    limits : dict
        ``max_speed_m_s``, ``min_separation_m``, fence band, and every tolerance used.
    violations : list of AuditViolation
        Up to 200 listed per kind.
    violation_counts : dict
        kind -> count (all of them).
    incomplete : list of str
        Why the audit cannot vouch for the whole mission (empty: it can); see the module's
        "Completeness".
    """

    log_dir: str
    tlogs: list
    ignored_tlogs: list = field(default_factory=list)
    setpoints_checked: int = 0
    setpoints_skipped: int = 0
    per_vehicle: dict = field(default_factory=dict)
    speed_steps_checked: int = 0
    separation_instants_checked: int = 0
    separation_segments_checked: int = 0
    max_speed_seen_m_s: float = 0.0
    max_step_speed_m_s: float = 0.0
    min_separation_seen_m: float = math.inf
    min_fence_margin_m: float = math.inf
    limits: dict = field(default_factory=dict)
    violations: list = field(default_factory=list)
    violation_counts: dict = field(default_factory=dict)
    incomplete: list = field(default_factory=list)

    @property
    def clean(self) -> bool:
        """True when no checked setpoint broke a rule."""
        return not any(self.violation_counts.values())

    @property
    def ok(self) -> bool:
        """True when nothing was violated and the audit saw the whole mission."""
        return self.clean and not self.incomplete

    @property
    def exit_status(self) -> int:
        """``swarmseek audit``'s status: 0 ok, 1 violations, 3 incomplete (and no violation)."""
        return 1 if not self.clean else 3 if self.incomplete else 0

    def add(self, violation: AuditViolation) -> None:
        """Count a violation (and list it, up to 200 per kind)."""
        n = self.violation_counts.get(violation.kind, 0)
        self.violation_counts[violation.kind] = n + 1
        if n < _MAX_LISTED:
            self.violations.append(violation)

    def to_dict(self) -> dict:
        """JSON-ready dictionary (non-finite numbers as None, strict JSON)."""
        d = asdict(self)
        d["ok"] = self.ok
        d["exit_status"] = self.exit_status
        d["violations"] = [dict(asdict(v), sysids=list(v.sysids)) for v in self.violations]
        return _finite(d)

    def format_text(self) -> str:
        """The report as lines of text."""
        lim = self.limits
        sep = "n/a" if not math.isfinite(self.min_separation_seen_m) else f"{self.min_separation_seen_m:.3f} m"
        lines = [
            f"audit of {self.log_dir}: {len(self.tlogs)} tlog(s), {len(self.per_vehicle)} vehicle(s)",
            f"  setpoints checked: {self.setpoints_checked} (velocity-only skipped: {self.setpoints_skipped})",
            f"  fence: {lim.get('polygon_vertices')} vertices, altitude {lim.get('min_alt_m')}..{lim.get('max_alt_m')} m;"
            f" smallest margin inside {self.min_fence_margin_m:.3f} m (tolerance {lim.get('fence_tol_m')} m)",
            f"  speed: {self.speed_steps_checked} steps, each <= {lim.get('max_speed_m_s')} m/s * (dt + "
            f"{lim.get('stamp_jitter_s')} s); max single step {self.max_step_speed_m_s:.3f} m/s, max over >= "
            f"{lim.get('speed_window_s')} s windows {self.max_speed_seen_m_s:.3f} m/s",
            f"  separation: {self.separation_instants_checked} pair-instants, {self.separation_segments_checked} "
            f"pair-path segments; min {sep} (limit {lim.get('min_separation_m')} - {lim.get('separation_tol_m')} m)",
        ]
        if self.ignored_tlogs:
            names = ", ".join(Path(p).name for p in self.ignored_tlogs)
            lines.insert(1, f"  ignored {len(self.ignored_tlogs)} tlog(s) of system ids not in the plan: {names}")
        lines.extend(f"  INCOMPLETE: {why}" for why in self.incomplete)
        if self.ok:
            lines.append("  OK: no violation")
        elif self.clean:
            lines.append("  NOT OK: the audit is incomplete (above); what was checked broke no rule")
        else:
            counts = ", ".join(f"{k} {v}" for k, v in sorted(self.violation_counts.items()) if v)
            lines.append(f"  VIOLATIONS: {counts}")
            for v in self.violations:
                who = "-".join(str(s) for s in v.sysids)
                lines.append(f"    t={v.t_s:.3f} {v.kind} vehicle(s) {who}: {v.detail}")
        return "\n".join(lines)


def _finite(obj):
    """Copy of a JSON-like structure with NaN and infinities replaced by None."""
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


# ---------------------------------------------------------------------------------- checks
def _tracks(t_s, stale_after_s):
    """Index ranges ``[(i0, i1), ...]`` of contiguous commanding (gaps > stale_after_s split)."""
    if len(t_s) == 0:
        return []
    cuts = np.flatnonzero(np.diff(t_s) > stale_after_s) + 1
    bounds = np.concatenate([[0], cuts, [len(t_s)]])
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]


def _check_fence(report, sp, plan, tol_m):
    poly = plan["polygon_en_m"]
    p = sp.enu_m
    crossing = point_in_polygon(p[:, :2], poly, 0.0)
    below = plan["min_alt_m"] - p[:, 2]
    above = p[:, 2] - plan["max_alt_m"]
    margin_v = np.minimum(-below, -above)
    margin_h = _horizontal_margins(p[:, :2], poly, crossing, float(margin_v.min()))
    inside = crossing | (np.abs(margin_h) <= tol_m) if tol_m > 0 else crossing   # = point_in_polygon(..., tol_m)
    margin = np.minimum(margin_h, margin_v)
    report.min_fence_margin_m = min(report.min_fence_margin_m, float(margin.min()))
    for i in np.flatnonzero(~inside):
        report.add(AuditViolation("fence", float(sp.t_s[i]), (sp.sysid,), float(-margin_h[i]), 0.0,
                                  f"setpoint ({p[i, 0]:.2f}, {p[i, 1]:.2f}, {p[i, 2]:.2f}) m is "
                                  f"{-margin_h[i]:.3f} m outside the fence polygon"))
    for i in np.flatnonzero((below > tol_m) | (above > tol_m)):
        low = below[i] > tol_m
        report.add(AuditViolation("altitude", float(sp.t_s[i]), (sp.sysid,), float(p[i, 2]),
                                  plan["min_alt_m"] if low else plan["max_alt_m"],
                                  f"setpoint altitude {p[i, 2]:.3f} m is {'below' if low else 'above'} the band "
                                  f"{plan['min_alt_m']:g}..{plan['max_alt_m']:g} m"))


def _horizontal_margins(xy, poly, crossing, cap_m: float) -> np.ndarray:
    """Signed distance of each point to the fence polygon's boundary (negative outside; ``crossing``:
    inside by the crossing rule), computed exactly (:func:`boundary_distance`) for the points outside
    and for those whose distance to the nearest edge's *line* (never more than the distance to the
    edge) is at most ``cap_m``, the smallest vertical margin; inf for the others, whose distance
    exceeds ``cap_m`` and so can be neither a violation nor the smallest margin."""
    a = np.asarray(poly, dtype=float)
    d = np.roll(a, -1, axis=0) - a
    length = np.hypot(d[:, 0], d[:, 1])
    rel = xy[:, None, :] - a
    cross = np.abs(rel[..., 0] * d[:, 1] - rel[..., 1] * d[:, 0])
    line = np.where(length > 0, cross / np.where(length > 0, length, 1.0), np.hypot(rel[..., 0], rel[..., 1]))
    near = ~crossing | (line.min(axis=1) <= cap_m + _LINE_SLACK_M)
    margin = np.full(len(xy), np.inf)
    margin[near] = boundary_distance(xy[near], poly)
    return np.where(crossing, margin, -margin)


#: rounding slack of the line-distance pre-filter (it only widens the set computed exactly)
_LINE_SLACK_M = 1e-3


def _check_speed(report, sp, tracks, max_speed_m_s, jitter_s, window_s):
    step_max = window_max = 0.0
    slack_m = max_speed_m_s * jitter_s
    for a, b in tracks:
        t, p = sp.t_s[a:b], sp.enu_m[a:b]
        if len(t) < 2:
            continue
        dt = np.diff(t)
        dist = np.linalg.norm(np.diff(p, axis=0), axis=1)
        report.speed_steps_checked += len(dt)
        speed = np.where(dt > 0, dist / np.where(dt > 0, dt, 1.0), np.where(dist > 0, np.inf, 0.0))
        step_max = max(step_max, float(speed.max()))
        for i in np.flatnonzero(dist > max_speed_m_s * dt + slack_m):
            report.add(AuditViolation("speed", float(t[i + 1]), (sp.sysid,), float(speed[i]), max_speed_m_s,
                                      f"moved {dist[i]:.3f} m in {dt[i]:.4f} s ({speed[i]:.2f} m/s; allowed "
                                      f"{max_speed_m_s * dt[i] + slack_m:.3f} m)"))
        j = np.searchsorted(t, t + window_s)
        ok = j < len(t)
        if np.any(ok):
            i = np.flatnonzero(ok)
            chord = np.linalg.norm(p[j[ok]] - p[i], axis=1) / (t[j[ok]] - t[i])
            window_max = max(window_max, float(chord.max()))
    return step_max, window_max


def _check_pair(report, a, b, tracks_a, tracks_b, min_sep_m, tol_m, stale_after_s, burst_s=0.0):
    """Separation of one pair (module docstring), every pair of tracks checked exactly
    (:func:`mission.safety.audit_pairs.track_pair`). ``burst_s``: "latest vs latest" is read ``burst_s``
    after each instant, so that the datagrams of one streamer burst count as sent together (the
    streamer sends a burst in one synchronous loop, microseconds apart: without this, the instant
    between two of its datagrams paired one vehicle's new setpoint with the other's previous one, a
    state no vehicle can be in, and a fast pair passing 1.5 m apart read as up to a step closer)."""
    for ra in tracks_a:
        for rb in tracks_b:
            result = track_pair(a, b, ra, rb, min_sep_m, tol_m, stale_after_s, burst_s)
            if result is not None:
                apply_track_pair(report, result)


def _check_options(gcs_sysid, fence_tol_m, stamp_jitter_s, speed_window_s, separation_tol_m, stale_after_s):
    """AuditError for an option out of its range (the CLI shows the message)."""
    if isinstance(gcs_sysid, bool) or not isinstance(gcs_sysid, int) or not 1 <= gcs_sysid <= 255:
        raise AuditError(f"gcs_sysid must be a MAVLink system id 1..255, got {gcs_sysid!r}")
    for name, value, positive in (("fence_tol_m", fence_tol_m, False), ("stamp_jitter_s", stamp_jitter_s, False),
                                  ("separation_tol_m", separation_tol_m, False),
                                  ("speed_window_s", speed_window_s, True), ("stale_after_s", stale_after_s, True)):
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise AuditError(f"{name} must be a number, got {value!r}") from None
        if not math.isfinite(v) or v < 0 or (positive and v == 0):
            raise AuditError(f"{name} must be a finite number {'> 0' if positive else '>= 0'}, got {value!r}")


def _completeness(report, plan, by_sysid, ignored, gcs_sysid, read=read_vehicle_setpoints) -> None:
    """Add to ``report.incomplete`` every reason the audit cannot vouch for the whole mission
    (after the checks: ``report.setpoints_checked`` is final)."""
    if plan["missions"] > 1:
        report.incomplete.append(f"the mission log holds {plan['missions']} missions' plan records (two missions "
                                 "in one directory?): the tlogs cannot be matched to one plan")
    if len(plan["plan_sysid_sets"]) > 1:
        sets = "; ".join(", ".join(str(s) for s in group) for group in plan["plan_sysid_sets"])
        report.incomplete.append(f"the log's plan records name different vehicles ({sets})")
    for sysid in sorted(plan["sysids"] or ()):
        if sysid not in by_sysid:
            report.incomplete.append(f"vehicle {sysid} of the plan has no tlog")
        elif all(Path(p).stat().st_size == 0 for p in by_sysid[sysid]):
            report.incomplete.append(f"vehicle {sysid} of the plan has an empty tlog")
    for sysid, paths in sorted(ignored.items()):
        if sysid == gcs_sysid:  # the ground station's own id is never a vehicle
            continue
        sent = len(read(paths, sysid, plan["origin"], gcs_sysid).t_s)
        if sent:
            report.incomplete.append(f"{sent} setpoint(s) were sent to system id {sysid}, which is not in the plan")
    if report.setpoints_checked == 0:
        report.incomplete.append(f"no position setpoint sent by system id {gcs_sysid} was found: nothing was "
                                 "checked (the ground station's system id is 255 unless the plan says otherwise)")


def audit_mission(log_dir, *, gcs_sysid: int = 255, fence_tol_m: float = 0.01, stamp_jitter_s: float = 0.01,
                  speed_window_s: float = 1.0, separation_tol_m: float = 0.01,
                  stale_after_s: float = 1.0, fast: bool = True) -> AuditReport:
    """Check every position setpoint sent in a flown mission against the plan's safety limits.

    Parameters
    ----------
    log_dir : path-like
        The mission's ``--log-dir``: ``mission.jsonl`` and ``tlogs/vehicle-<sysid>.tlog``.
    gcs_sysid : int
        System id of the ground station.
    fence_tol_m : float
        Slack on the fence and band (HOME_POSITION quantisation, 1 cm).
    stamp_jitter_s : float
        Slack on the time between two setpoints of a vehicle: a step may be up to
        ``max_speed_m_s * (dt + stamp_jitter_s)`` (the tlog stamps the write, not the instant
        the step was computed; a burst to N vehicles takes milliseconds). Also the width of one
        burst for "latest vs latest": setpoints stamped within it count as sent together.
    speed_window_s : float
        Window of the averaged speed figure (reported, not a violation).
    separation_tol_m : float
        Slack on the minimum separation (1 cm, frame quantisation of both vehicles).
    stale_after_s : float
        A vehicle is commanded until this long after its last setpoint.
    fast : bool
        Read the tlogs with numpy (:func:`~mission.safety.audit_read.read_vehicle_setpoints_fast`)
        and check exactly only the pairs a distance bound cannot clear
        (:func:`~mission.safety.audit_pairs.check_pairs_fast`); False: the plain reader and every
        pair checked exactly. The same report either way.

    Returns
    -------
    AuditReport

    Raises
    ------
    AuditError
        An option out of range, missing directory, no tlogs, no or unreadable plan, undecodable tlog.
    """
    _check_options(gcs_sysid, fence_tol_m, stamp_jitter_s, speed_window_s, separation_tol_m, stale_after_s)
    log_dir = Path(log_dir)
    if not log_dir.is_dir():
        raise AuditError(f"{log_dir}: " + ("not a directory (give the mission's --log-dir)" if log_dir.exists()
                                           else "no such directory"))
    by_sysid = find_tlogs(log_dir)
    if not by_sysid:
        raise AuditError(f"{log_dir}: no .tlog files (in tlogs/ or the directory itself; was --no-tlog used?)")
    plan = load_plan_limits(log_dir)
    ignored = {s: ps for s, ps in by_sysid.items() if plan["sysids"] is not None and s not in plan["sysids"]}
    by_sysid = {s: ps for s, ps in by_sysid.items() if s not in ignored}
    if not by_sysid:
        raise AuditError(f"{log_dir}: no .tlog of a planned vehicle (system ids {sorted(plan['sysids'])})")
    report = AuditReport(log_dir=str(log_dir), tlogs=[str(p) for ps in by_sysid.values() for p in ps],
                         ignored_tlogs=[str(p) for ps in ignored.values() for p in ps])
    report.limits = {
        "max_speed_m_s": plan["max_speed_m_s"], "min_separation_m": plan["min_separation_m"],
        "min_alt_m": plan["min_alt_m"], "max_alt_m": plan["max_alt_m"],
        "polygon_vertices": len(plan["polygon_en_m"]), "fence_tol_m": fence_tol_m,
        "stamp_jitter_s": stamp_jitter_s, "speed_slack_m": round(plan["max_speed_m_s"] * stamp_jitter_s, 4),
        "speed_window_s": speed_window_s, "separation_tol_m": separation_tol_m, "stale_after_s": stale_after_s,
        "clock": "tlog stamps: mission clock (simulated seconds when the mock fleet is embedded)",
    }
    read = read_vehicle_setpoints_fast if fast else read_vehicle_setpoints
    vehicles = []
    for sysid in sorted(by_sysid):
        sp = read(by_sysid[sysid], sysid, plan["origin"], gcs_sysid)
        for problem in sp.problems:
            report.add(problem)
        tracks = _tracks(sp.t_s, stale_after_s)
        report.setpoints_checked += len(sp.t_s)
        report.setpoints_skipped += sp.skipped
        step_max = window_max = 0.0
        if len(sp.t_s):
            _check_fence(report, sp, plan, fence_tol_m)
            step_max, window_max = _check_speed(report, sp, tracks, plan["max_speed_m_s"], stamp_jitter_s,
                                                speed_window_s)
        report.max_step_speed_m_s = max(report.max_step_speed_m_s, step_max)
        report.max_speed_seen_m_s = max(report.max_speed_seen_m_s, window_max)
        report.per_vehicle[sysid] = {"setpoints": int(len(sp.t_s)), "skipped": sp.skipped, "homes": sp.homes,
                                     "max_step_speed_m_s": round(step_max, 4),
                                     "max_window_speed_m_s": round(window_max, 4), "tracks": len(tracks)}
        vehicles.append((sp, tracks))
    if fast:
        check_pairs_fast(report, vehicles, plan["min_separation_m"], separation_tol_m, stale_after_s, stamp_jitter_s)
    else:
        for i in range(len(vehicles)):
            for j in range(i + 1, len(vehicles)):
                (a, ta), (b, tb) = vehicles[i], vehicles[j]
                _check_pair(report, a, b, ta, tb, plan["min_separation_m"], separation_tol_m, stale_after_s,
                            stamp_jitter_s)
    report.violations.sort(key=lambda v: (v.t_s, v.kind))
    _completeness(report, plan, by_sysid, ignored, gcs_sysid, read)
    return report
