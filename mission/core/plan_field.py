"""The plan's ``[field]`` section: the simulated world's field and sensor response.

The ground station never reads it to fly: it describes the world that ``swarmseek mock``,
``swarmseek sensor`` and ``swarmseek run`` simulate (``--field-config plan.toml``), so one plan
file carries a SITL dry-run's field. Keys (``docs/fields.md``)::

    [field]
    type = "plume"                  # sigma1 | sigma2 | plume | intermittent
    source_enu_m = [0.0, 0.0, 15.0] # source (plumes: release point), mission ENU m
    extra_sources_enu_m = [[30.0, 20.0, 15.0]]   # optional: multi-source
    strengths = [1.0, 0.5]          # optional: one per source
    wind_from_deg = 270.0           # plumes (see FIELD_KEYS)
    sensor_time_constant_s = 0.5    # every field: sensor lag
    sensor_detection_floor = 0.001  # every field: readings below report 0

Your own field (``docs/fields.md``, "Your own field")::

    [field]
    python = "my_field:make"        # a plug-in: further keys are its own, passed as given
    # or
    type = "grid"
    npz = "frames.npz"              # gridded frames over time, relative to the plan's directory

Only their form is checked here (the ground station imports no plug-in); the commands that
simulate the world import and probe them before anything starts.

This module checks types and ranges with the plan's :class:`~mission.core.plan_checks.Checker`
(every problem with its key path); ``sitl_mock.fields_config.field_from_table`` builds the field from
:meth:`FieldPlan.to_table`.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

from mission.core.plan_checks import Checker, show_value

__all__ = ["FIELD_TYPES", "FIELD_KEYS", "FieldPlan", "parse_field"]

FIELD_TYPES = ("sigma1", "sigma2", "plume", "intermittent", "grid")
#: ``python = "pkg.module:factory"`` (the same form ``sitl_mock.fields_plugin.check_spec`` accepts)
_PLUGIN_SPEC = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*(\.[A-Za-z_]\w*)*$")
_SENSOR_KEYS = ("sensor_time_constant_s", "sensor_detection_floor")
_PLUMES = ("plume", "intermittent")
_STABILITY = ("A", "B", "C", "D", "E", "F")
#: key -> (field types it applies to, low, low_open, high, integer); None types: every field
FIELD_KEYS = {
    "wind_from_deg": (_PLUMES, -360.0, False, 360.0, False),
    "wind_speed_m_s": (_PLUMES, 0.0, True, 50.0, False),
    "source_radius_m": (_PLUMES, 0.0, True, 100.0, False),
    "emission_rate": (_PLUMES, 0.0, True, None, False),
    "background": (_PLUMES, 0.0, False, None, False),
    "ground_alt_m": (_PLUMES, -500.0, False, 9000.0, False),
    "seed": (("intermittent",), 0, False, None, True),
    "release_rate_hz": (("intermittent",), 0.0, True, 1000.0, False),
    "puff_fraction": (("intermittent",), 0.0, True, 0.99, False),
    "meander_fraction": (("intermittent",), 0.0, False, 1.0, False),
    "meander_time_s": (("intermittent",), 0.0, True, 3600.0, False),
    "max_range_m": (("intermittent",), 0.0, True, 10000.0, False),
    "sensor_time_constant_s": (None, 0.0, False, 3600.0, False),
    "sensor_detection_floor": (None, 0.0, False, None, False),
}
_OTHER_KEYS = ("type", "source_enu_m", "extra_sources_enu_m", "strengths", "stability", "ground_reflection")


@dataclass(frozen=True)
class FieldPlan:
    """A valid ``[field]`` section: the field's type, sources and parameters (as given)."""

    type: str
    source_enu_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    extra_sources_enu_m: tuple[tuple[float, float, float], ...] = ()
    strengths: tuple[float, ...] | None = None
    params: tuple[tuple[str, object], ...] = ()

    def to_table(self) -> dict:
        """The section as a ``[field]`` table for ``sitl_mock.fields_config.field_from_table``."""
        if self.type in ("python", "grid"):  # as given: a plug-in's own keys, or the grid's npz
            return dict(self.params) if self.type == "python" else {"type": "grid", **dict(self.params)}
        t = {"type": self.type, "source_enu_m": list(self.source_enu_m), **dict(self.params)}
        if self.extra_sources_enu_m:
            t["extra_sources_enu_m"] = [list(s) for s in self.extra_sources_enu_m]
        if self.strengths is not None:
            t["strengths"] = list(self.strengths)
        return t


def _sources(c: Checker, t: dict, p: str):
    extra = []
    raw = t.get("extra_sources_enu_m", [])
    if not isinstance(raw, list):
        c.bad(f"{p}.extra_sources_enu_m", f"expected a list of [E, N, U] points, got {show_value(raw)}")
        raw = []
    for i, v in enumerate(raw):
        key = f"extra_sources_enu_m[{i}]"
        pt = c.point({key: v}, key, p, 3)
        if pt is not None:
            extra.append(pt)
    strengths = t.get("strengths")
    if strengths is not None:
        n = 1 + len(raw)
        if (not isinstance(strengths, list) or len(strengths) != n
                or not all(isinstance(w, (int, float)) and not isinstance(w, bool) and 0 < w < float("inf")
                           for w in strengths)):
            c.bad(f"{p}.strengths", f"expected {n} positive numbers (one per source), got {show_value(strengths)}")
            strengths = None
        else:
            strengths = tuple(float(w) for w in strengths)
    return tuple(extra), strengths


def _sensor_params(c: Checker, t: dict, p: str) -> dict:
    out = {}
    for key in _SENSOR_KEYS:
        if key in t:
            _types, low, low_open, high, integer = FIELD_KEYS[key]
            out[key] = c.number(t, key, p, low=low, low_open=low_open, high=high, integer=integer)
    return out


def _parse_custom(c: Checker, t: dict, p: str) -> FieldPlan | None:
    """``python = "pkg.module:factory"`` (any further keys are the plug-in's, passed as they are)
    or ``type = "grid"`` with ``npz = PATH``; only the form is checked here (the command that
    builds the world imports and probes it)."""
    before = len(c.problems)
    if "python" in t:
        spec = t["python"]
        if not isinstance(spec, str) or not _PLUGIN_SPEC.match(spec):
            c.bad(f"{p}.python", f"expected 'pkg.module:factory', got {show_value(spec)}")
        if t.get("type", "python") != "python":
            c.bad(f"{p}.type", f"give either type or python, not both (type {show_value(t['type'])})")
        _sensor_params(c, t, p)
        return None if len(c.problems) > before else FieldPlan(type="python", params=tuple(t.items()))
    c.unknown(t, ("type", "npz") + _SENSOR_KEYS, p)
    npz = t.get("npz")
    if not isinstance(npz, str) or not npz:
        c.bad(f"{p}.npz", f"a grid field needs npz = \"PATH\" (a .npz of frames), got {show_value(npz)}")
    params = {"npz": npz, **_sensor_params(c, t, p)}
    return None if len(c.problems) > before else FieldPlan(type="grid", params=tuple(params.items()))


def parse_field(c: Checker, doc: dict) -> FieldPlan | None:
    """``[field]`` (optional): a :class:`FieldPlan`, or None when absent or invalid."""
    if "field" not in doc:
        return None
    t = c.table(doc, "field")
    p = "field"
    if "python" in t or t.get("type") == "grid":
        return _parse_custom(c, t, p)
    c.unknown(t, _OTHER_KEYS + tuple(FIELD_KEYS), p)
    kind = c.string(t, "type", p, required=True, choices=FIELD_TYPES)
    before = len(c.problems)
    source = c.point(t, "source_enu_m", p, 3) or (0.0, 0.0, 0.0)
    extra, strengths = _sources(c, t, p)
    params = {}
    for key, (types, low, low_open, high, integer) in FIELD_KEYS.items():
        if key not in t:
            continue
        if kind is not None and types is not None and kind not in types:
            c.bad(f"{p}.{key}", f"does not apply to the {kind} field (only {', '.join(types)})")
            continue
        params[key] = c.number(t, key, p, low=low, low_open=low_open, high=high, integer=integer)
    for key, check in (("stability", lambda v: v in _STABILITY), ("ground_reflection", lambda v: isinstance(v, bool))):
        if key in t and kind is not None and kind not in _PLUMES:
            c.bad(f"{p}.{key}", f"does not apply to the {kind} field (only plume, intermittent)")
        elif key in t and not check(t[key]):
            want = f"one of {', '.join(_STABILITY)}" if key == "stability" else "true or false"
            c.bad(f"{p}.{key}", f"must be {want}, got {show_value(t[key])}")
        elif key in t:
            params[key] = t[key]
    if kind is None or len(c.problems) > before:
        return None
    return FieldPlan(type=kind, source_enu_m=source, extra_sources_enu_m=extra, strengths=strengths,
                     params=tuple(params.items()))
