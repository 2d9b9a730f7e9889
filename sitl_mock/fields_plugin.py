"""Your own field: a Python plug-in ``"pkg.module:factory"`` given the plan's ``[field]`` table.

The factory is called with the ``[field]`` table (a ``dict``) and returns an object with the
interface :class:`FieldPlugin` (``docs/fields.md``, "Your own field"). :func:`load_plugin` imports
it (``importlib``: the module must be importable from ``sys.path`` or the current directory,
which is searched last: run from the directory holding it or set ``PYTHONPATH``), checks what
the factory returned and wraps it in a :class:`PluginField`, which gives the simulated world the
interface of the built-in fields. :func:`probe_field` evaluates a field at a few points and times
before a command arms or connects anything. Every problem is a :class:`FieldPluginError`: one line naming the plug-in.
"""
from __future__ import annotations

import importlib
import os
import re
import sys
from typing import Protocol, runtime_checkable

import numpy as np

__all__ = ["FieldPlugin", "FieldPluginError", "PluginField", "load_plugin", "probe_field", "probe_points_enu",
           "PROBE_TIMES_S", "check_spec"]

#: seconds after a command's start at which :func:`probe_field` reads the field
PROBE_TIMES_S = (0.0, 0.5, 10.0, 60.0, 600.0, 3600.0)
#: step of the central differences of :meth:`PluginField.gradient` when the plug-in has none, m
GRADIENT_STEP_M = 1e-3
_SPEC = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*(\.[A-Za-z_]\w*)*$")


class FieldPluginError(ValueError):
    """A plug-in (or a gridded-data file) that cannot serve as a field; the message is one line
    that names it."""


@runtime_checkable
class FieldPlugin(Protocol):
    """What a field plug-in's factory returns.

    Coordinates are the mission frame: ENU metres (x east, y north, z up) about the plan's
    origin; times are the simulated world's clock in seconds (Unix epoch: a lock-step
    ``swarmseek run`` starts at 2026-01-01 00:00:00 UTC, 1767225600 s; ``swarmseek simulate``
    at 0).

    Optional members: ``time_dependent`` (bool, default False: the offline simulation then calls
    ``value`` with ``t_s = 0``), ``gradient(points_enu_m, t_s) -> (M, 3)`` (default: central
    differences of ``value``, 1 mm apart), ``downwind_en`` (the unit (east, north) vector the wind
    blows toward: ``swarmseek run`` then starts the formation downwind of the source).
    """

    def value(self, points_enu_m: np.ndarray, t_s: float) -> np.ndarray:
        """Concentration at ``points_enu_m`` (float array of shape (M, 3), M >= 1) at time
        ``t_s`` (a Python float): an array of shape (M,), finite and >= 0."""
        ...

    def source_enu(self) -> np.ndarray:
        """The point a seeker should find (the release), ENU m, shape (3,), finite."""
        ...


def check_spec(spec: str) -> str | None:
    """Why ``spec`` is not of the form ``"pkg.module:factory"``, or None."""
    if not isinstance(spec, str) or not _SPEC.match(spec):
        return f"expected a plug-in as 'pkg.module:factory' (dotted module, a colon, a name), got {spec!r}"
    return None


def _describe(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _import_factory(spec: str, label: str):
    module_name, attr = spec.split(":")
    cwd = os.getcwd()
    if cwd not in sys.path and "" not in sys.path:  # the `swarmseek` script's sys.path lacks it; searched last
        sys.path.append(cwd)
    try:
        obj = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name and (exc.name == module_name or module_name.startswith(exc.name + ".")):
            raise FieldPluginError(f"{label}: cannot import module {module_name!r} (no module named {exc.name!r}; "
                                   "run from the directory holding it or put it on PYTHONPATH)") from None
        raise FieldPluginError(f"{label}: importing {module_name!r} failed: {_describe(exc)}") from None
    except Exception as exc:  # noqa: BLE001 - any error of the user's module is reported, never a traceback
        raise FieldPluginError(f"{label}: importing {module_name!r} failed: {_describe(exc)}") from None
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise FieldPluginError(f"{label}: module {module_name!r} has no attribute {attr!r}")
        obj = getattr(obj, part)
    if not callable(obj):
        raise FieldPluginError(f"{label}: {attr!r} is not callable (a factory taking the [field] table)")
    return obj


def _finite_source(model, label: str) -> np.ndarray:
    try:
        src = np.asarray(model.source_enu(), dtype=float)
    except Exception as exc:  # noqa: BLE001 - the user's code
        raise FieldPluginError(f"{label}: source_enu() raised {_describe(exc)}") from None
    if src.shape != (3,) or not np.all(np.isfinite(src)):
        raise FieldPluginError(f"{label}: source_enu() must return 3 finite numbers (E, N, U m), "
                               f"got {np.array2string(src, precision=4, separator=', ')}")
    return src


def load_plugin(spec: str, table: dict | None = None) -> PluginField:
    """Import ``spec`` (``"pkg.module:factory"``), call the factory with ``table`` and wrap what
    it returns.

    Raises
    ------
    FieldPluginError
        A malformed spec, an import error, a missing attribute, a factory that raises, or a
        returned object without ``value`` / ``source_enu`` (or whose ``source_enu()`` is not 3
        finite numbers).
    """
    label = f"field plug-in {spec}" if isinstance(spec, str) else "field plug-in"
    problem = check_spec(spec)
    if problem:
        raise FieldPluginError(f"{label}: {problem}")
    factory = _import_factory(spec, label)
    try:
        model = factory(dict(table or {}))
    except Exception as exc:  # noqa: BLE001 - the user's code
        raise FieldPluginError(f"{label}: the factory raised {_describe(exc)}") from None
    missing = [m for m in ("value", "source_enu") if not callable(getattr(model, m, None))]
    if missing:
        raise FieldPluginError(f"{label}: the factory returned a {type(model).__name__} without "
                               f"{' and '.join(m + '()' for m in missing)} (docs/fields.md, \"Your own field\")")
    return PluginField(model, label, _finite_source(model, label))


class PluginField:
    """A plug-in seen as a built-in field: ``value(points, t_s)`` for points ``(..., 3)`` and
    ``t_s`` a scalar or an array broadcastable to ``points.shape[:-1]`` (the plug-in is called
    once per distinct time with points ``(M, 3)``), ``gradient``, ``source_enu``,
    ``time_dependent``, ``downwind_en``.

    Parameters
    ----------
    model : FieldPlugin
        What the factory returned.
    label : str
        ``"field plug-in pkg.module:factory"`` (error messages, ``repr``).
    source_enu_m : array_like, shape (3,)
        ``model.source_enu()``, checked.
    """

    def __init__(self, model, label: str, source_enu_m):
        self.model = model
        self.label = label
        self._source = np.asarray(source_enu_m, dtype=float).copy()
        self.time_dependent = bool(getattr(model, "time_dependent", False))
        wind = getattr(model, "downwind_en", None)
        self.downwind_en = None if wind is None else np.asarray(wind, dtype=float)

    def __repr__(self) -> str:
        return f"PluginField({self.label.removeprefix('field plug-in ')}, model={type(self.model).__name__})"

    def _call(self, flat: np.ndarray, t_s: float) -> np.ndarray:
        out = np.asarray(self.model.value(flat, t_s), dtype=float)
        if out.shape != (len(flat),):
            raise FieldPluginError(f"{self.label}: value() of {len(flat)} points returned shape {out.shape}, "
                                   f"expected ({len(flat)},)")
        return out

    def value(self, points, t_s=0.0) -> np.ndarray:
        """The plug-in's value at ``points`` (..., 3), shape (...)."""
        pts = np.asarray(points, dtype=float)
        flat = np.ascontiguousarray(pts.reshape(-1, 3))
        t = np.asarray(t_s, dtype=float)
        if t.ndim == 0:
            return self._call(flat, float(t)).reshape(pts.shape[:-1])
        times = np.broadcast_to(t, pts.shape[:-1]).reshape(-1)
        out = np.empty(len(flat))
        for tu in np.unique(times):
            sel = times == tu
            out[sel] = self._call(flat[sel], float(tu))
        return out.reshape(pts.shape[:-1])

    def gradient(self, points, t_s=0.0) -> np.ndarray:
        """The plug-in's ``gradient`` if it has one, else central differences of :meth:`value`."""
        pts = np.asarray(points, dtype=float)
        if callable(getattr(self.model, "gradient", None)) and np.ndim(t_s) == 0:
            flat = pts.reshape(-1, 3)
            return np.asarray(self.model.gradient(flat, float(t_s)), dtype=float).reshape(pts.shape)
        grad = np.empty(pts.shape)
        for i in range(3):
            step = np.zeros(3)
            step[i] = GRADIENT_STEP_M
            grad[..., i] = (self.value(pts + step, t_s) - self.value(pts - step, t_s)) / (2.0 * GRADIENT_STEP_M)
        return grad

    def source_enu(self) -> np.ndarray:
        """The plug-in's ``source_enu()`` (checked when loaded)."""
        return self._source.copy()


def probe_points_enu(polygon_en_m, min_alt_m: float, max_alt_m: float, extra=()) -> np.ndarray:
    """Probe points: the fence's corners at its floor and ceiling, its centre, and ``extra``
    points (the start, the source), shape (P, 3)."""
    poly = np.asarray(polygon_en_m, dtype=float).reshape(-1, 2)
    corners = [(e, n, alt) for e, n in poly for alt in (min_alt_m, max_alt_m)]
    centre = (*poly.mean(axis=0), 0.5 * (min_alt_m + max_alt_m))
    return np.array(corners + [centre] + [tuple(np.asarray(p, dtype=float)) for p in extra], dtype=float)


def _where(point, t_s: float) -> str:
    return f"({', '.join(f'{x:g}' for x in point)}) m, t = {t_s:.12g} s"


def probe_field(field, points_enu_m, t0_s: float = 0.0, times_s=PROBE_TIMES_S, label: str | None = None) -> None:
    """Evaluate ``field`` at ``points_enu_m`` (P, 3) at ``t0_s + times_s``; raise on a value of the
    wrong shape, not finite or negative, or an exception of the field.

    A :class:`PluginField` is probed through its plug-in's own ``value`` (points (P, 3), a float
    time), so a wrong shape is reported, not reshaped.

    Raises
    ------
    FieldPluginError
        One line naming the field (``label``, or the plug-in's).
    """
    label = label or getattr(field, "label", None) or f"field {type(field).__name__}"
    raw = field.model if isinstance(field, PluginField) else field
    pts = np.ascontiguousarray(np.asarray(points_enu_m, dtype=float).reshape(-1, 3))
    for dt in times_s:
        t = float(t0_s) + float(dt)
        try:
            out = np.asarray(raw.value(pts.copy(), t), dtype=float)
        except Exception as exc:  # noqa: BLE001 - the user's code
            raise FieldPluginError(f"{label}: value() raised {_describe(exc)} at t = {t:.12g} s") from None
        if out.shape != (len(pts),):
            raise FieldPluginError(f"{label}: value() of {len(pts)} points returned shape {out.shape}, "
                                   f"expected ({len(pts)},)")
        bad = np.flatnonzero(~np.isfinite(out))
        if bad.size:
            raise FieldPluginError(f"{label}: value() is {out[bad[0]]} at {_where(pts[bad[0]], t)}")
        neg = np.flatnonzero(out < 0.0)
        if neg.size:
            raise FieldPluginError(f"{label}: value() is negative ({out[neg[0]]:.6g}) at {_where(pts[neg[0]], t)}; "
                                   "a concentration is >= 0")
