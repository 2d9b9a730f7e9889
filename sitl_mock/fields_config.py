"""Fields by name and parameters: the one constructor that ``mock``, ``sensor``, ``run``, the
plan's ``[field]`` section and the offline simulation share.

Names (:data:`FIELD_NAMES`): ``sigma1`` and ``sigma2`` (the paper's Gaussians), ``plume`` (steady
Gaussian plume, :class:`~sitl_mock.fields_plume.GaussianPlume`), ``intermittent`` (puff plume,
:class:`~sitl_mock.fields_filament.FilamentPlume`). Every one can have several sources
(``extra_sources``, weighted by ``strengths``): the field is then the sum of one field per
source (:class:`~sitl_mock.fields_gaussian.SumField`; one background for the sum).

A ``[field]`` table may instead name your own field: ``python = "pkg.module:factory"``
(:mod:`sitl_mock.fields_plugin`) or ``type = "grid"`` with ``npz = PATH``
(:mod:`sitl_mock.fields_grid`); :func:`field_from_table` builds those too.
"""
from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np

from sitl_mock.fields_filament import FilamentPlume
from sitl_mock.fields_gaussian import S1, S2, GaussianField, SumField
from sitl_mock.fields_grid import load_grid
from sitl_mock.fields_plugin import load_plugin
from sitl_mock.fields_plume import GaussianPlume

__all__ = ["FIELD_NAMES", "FIELD_PARAMS", "PLUME_PARAMS", "FILAMENT_PARAMS", "SENSOR_PARAMS",
           "make_field", "field_from_table", "read_field_table"]

FIELD_NAMES = ("sigma1", "sigma2", "plume", "intermittent")
PLUME_PARAMS = ("wind_from_deg", "wind_speed_m_s", "stability", "source_radius_m", "emission_rate",
                "ground_reflection", "background", "ground_alt_m")
FILAMENT_PARAMS = ("seed", "release_rate_hz", "puff_fraction", "meander_fraction", "meander_time_s",
                   "max_range_m")
#: keyword parameters each field accepts (besides the sources)
FIELD_PARAMS = {"sigma1": (), "sigma2": (), "plume": PLUME_PARAMS,
                "intermittent": PLUME_PARAMS + FILAMENT_PARAMS}
#: keys of a ``[field]`` table that configure the sensors, not the field
SENSOR_PARAMS = ("sensor_time_constant_s", "sensor_detection_floor")
_PAPER = {"sigma1": (100.0, S1), "sigma2": (1.0, S2)}


def _one(name: str, source, weight: float, index: int, params: dict):
    if name in _PAPER:
        amp, S = _PAPER[name]
        return GaussianField(amp * weight, S, np.asarray(source, dtype=float))
    kw = dict(params)
    if name == "intermittent":
        kw["seed"] = int(kw.get("seed", 0)) + index  # independent puffs per source
        cls = FilamentPlume
    else:
        cls = GaussianPlume
    if weight != 1.0:
        q = cls(source, **kw)
        q = q.steady.emission_rate if name == "intermittent" else q.emission_rate
        kw["emission_rate"] = q * weight
    return cls(source, **kw)


def make_field(name: str, source=(0.0, 0.0, 0.0), *, extra_sources=(), strengths=None, **params):
    """The field ``name`` with its (first) source at ``source`` (ENU m).

    Parameters
    ----------
    name : str
        One of :data:`FIELD_NAMES`.
    source : array_like, shape (3,)
        Source (plumes: release point), ENU m.
    extra_sources : sequence of array_like (3,)
        Further sources of the same kind (a multi-source field).
    strengths : sequence of float, optional
        One positive weight per source (first, then the extras; default all 1): scales the
        paper's amplitude or the plume's emission rate.
    **params
        The field's parameters (:data:`FIELD_PARAMS`).

    Raises
    ------
    ValueError
        Unknown name or parameter, or a value out of range.
    """
    if name not in FIELD_NAMES:
        raise ValueError(f"unknown field {name!r}; known fields: {', '.join(FIELD_NAMES)}")
    bad = sorted(set(params) - set(FIELD_PARAMS[name]))
    if bad:
        allowed = ", ".join(FIELD_PARAMS[name]) or "none"
        raise ValueError(f"field {name!r} has no parameter {', '.join(bad)} (allowed: {allowed})")
    sources = [np.asarray(source, dtype=float)] + [np.asarray(s, dtype=float) for s in extra_sources]
    for s in sources:
        if s.shape != (3,) or not np.all(np.isfinite(s)):
            raise ValueError(f"a source must be 3 finite numbers (E, N, U m), got {s.tolist()!r}")
    weights = [1.0] * len(sources) if strengths is None else [float(w) for w in strengths]
    if len(weights) != len(sources) or not all(np.isfinite(w) and w > 0 for w in weights):
        raise ValueError(f"strengths must be {len(sources)} positive numbers (one per source), got {strengths!r}")
    if len(sources) == 1:
        return _one(name, sources[0], weights[0], 0, params)
    background = float(params.get("background", 1e-4)) if name in ("plume", "intermittent") else 0.0
    part_params = dict(params, background=0.0) if name in ("plume", "intermittent") else params
    parts = [_one(name, s, w, i, part_params) for i, (s, w) in enumerate(zip(sources, weights))]
    return SumField(parts, background=background)


def field_from_table(table: dict, where: str = "field"):
    """``(field, sensor_options)`` from a ``[field]`` table (the plan's, see ``docs/fields.md``).

    ``type`` names the field, ``source_enu_m`` its source (default 0, 0, 0),
    ``extra_sources_enu_m`` and ``strengths`` the multi-source, the other keys are the field's
    parameters and the sensor's (:data:`SENSOR_PARAMS`, returned as ``time_constant_s`` /
    ``detection_floor`` keywords of :meth:`sitl_mock.sensor.SignalSensor.set_response`).

    Raises
    ------
    ValueError
        The table is invalid (the message names the key).
    """
    if not isinstance(table, dict):
        raise ValueError(f"[{where}] must be a table")
    t = dict(table)
    if "python" in t or t.get("type") == "grid":
        return _custom_field(t, where)
    name = t.pop("type", None)
    if name is None:
        raise ValueError(f"{where}.type is required (one of {', '.join(FIELD_NAMES)})")
    source = t.pop("source_enu_m", (0.0, 0.0, 0.0))
    extra = t.pop("extra_sources_enu_m", ())
    strengths = t.pop("strengths", None)
    sensor = _sensor_options(t, where)
    try:
        return make_field(name, source, extra_sources=extra, strengths=strengths, **t), sensor
    except (TypeError, ValueError) as exc:
        raise ValueError(f"[{where}]: {exc}") from None


def _sensor_options(t: dict, where: str) -> dict:
    """Pop the sensor keys (:data:`SENSOR_PARAMS`) of ``t``, checked, as ``set_response`` keywords."""
    sensor = {k.removeprefix("sensor_"): t.pop(k) for k in SENSOR_PARAMS if k in t}
    for k, v in sensor.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (np.isfinite(v) and v >= 0):
            raise ValueError(f"[{where}]: sensor_{k} must be a finite number >= 0, got {v!r}")
    return sensor


def _custom_field(table: dict, where: str):
    """``(field, sensor_options)`` of a ``[field]`` table with ``python = "pkg.module:factory"``
    (the factory gets the whole table) or ``type = "grid"`` with ``npz = PATH``
    (:mod:`sitl_mock.fields_plugin`, :mod:`sitl_mock.fields_grid`; ``docs/fields.md``).

    Raises
    ------
    ValueError
        An invalid table; :class:`~sitl_mock.fields_plugin.FieldPluginError` (a ValueError) for a
        plug-in or a data file that cannot serve (one line naming it).
    """
    t = dict(table)
    sensor = _sensor_options(t, where)
    if "python" in t:
        if t.get("type") not in (None, "python"):
            raise ValueError(f"[{where}]: give either type or python, not both (type {t['type']!r}, "
                             f"python {t['python']!r})")
        return load_plugin(t["python"], dict(table)), sensor
    t.pop("type")
    npz = t.pop("npz", None)
    if not isinstance(npz, str) or not npz:
        raise ValueError(f"[{where}]: a grid field needs npz = \"PATH\" (a .npz of frames), got {npz!r}")
    if t:
        raise ValueError(f"[{where}]: {', '.join(sorted(t))} does not apply to a grid field "
                         "(keys: type, npz, sensor_time_constant_s, sensor_detection_floor)")
    return load_grid(npz), sensor


def read_field_table(path) -> dict:
    """The ``[field]`` table of a TOML file (e.g. a mission plan).

    Raises
    ------
    ValueError
        The file cannot be read, is not TOML or has no ``[field]`` table.
    """
    try:
        doc = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ValueError(f"{path} is not valid TOML: {exc}") from None
    if not isinstance(doc.get("field"), dict):
        raise ValueError(f"{path} has no [field] table")
    return doc["field"]
