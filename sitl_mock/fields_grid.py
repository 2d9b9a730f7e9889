"""Gridded concentration data over time: frames on a regular 2D or 3D grid in a NumPy ``.npz``.

Keys of the file (``docs/fields.md``, "Gridded data"):

* ``frames``: shape ``(T, nx, ny)`` or ``(T, nx, ny, nz)``, finite, >= 0; frame ``k`` is at time
  ``t0_s + k * frame_period_s``; node ``(i, j[, l])`` at ``origin_enu_m + (i, j[, l]) * spacing_m``
  (a 2D grid is a map over east and north that does not depend on the altitude);
* ``origin_enu_m``, ``spacing_m``: one number per grid axis (2 or 3), ENU m about the plan's
  origin, spacings > 0;
* ``frame_period_s``: seconds between frames (> 0);
* optional ``t0_s`` (default 0: the world's clock, Unix seconds), ``loop`` (default false: before
  the first frame the first, after the last the last; true: the frames repeat every
  ``T * frame_period_s``, the last blending into the first), ``source_enu_m`` (default: the
  node of the largest time-mean value; a 2D grid's at U = 0).

Interpolated with :class:`scipy.interpolate.RegularGridInterpolator` over (frame, x, y[, z]):
multilinear, i.e. linear in space and linear between frames; exactly the data at the nodes.
Outside the grid the value is 0.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from sitl_mock.fields_plugin import FieldPluginError

__all__ = ["GridField", "load_grid", "from_table", "REQUIRED_KEYS", "OPTIONAL_KEYS"]

REQUIRED_KEYS = ("frames", "origin_enu_m", "spacing_m", "frame_period_s")
OPTIONAL_KEYS = ("t0_s", "loop", "source_enu_m")
#: gradient step (central differences), as a fraction of the smallest spacing
_GRAD_FRACTION = 1e-3


def _vector(data, key: str, d: int, label: str, positive: bool = False) -> np.ndarray:
    v = np.asarray(data[key], dtype=float)
    if v.shape != (d,) or not np.all(np.isfinite(v)) or (positive and not np.all(v > 0)):
        want = f"{d} finite{' positive' if positive else ''} numbers (one per grid axis)"
        raise FieldPluginError(f"{label}: {key} must be {want}, got {np.array2string(v, separator=', ')}")
    return v


def _scalar(data, key: str, label: str, positive: bool) -> float:
    v = np.asarray(data[key], dtype=float)
    if v.shape not in ((), (1,)) or not np.isfinite(v).all() or (positive and not float(v.reshape(-1)[0]) > 0):
        raise FieldPluginError(f"{label}: {key} must be one finite{' positive' if positive else ''} number, "
                               f"got {np.array2string(v, separator=', ')}")
    return float(v.reshape(-1)[0])


def _frames(data, label: str) -> np.ndarray:
    try:
        frames = np.asarray(data["frames"], dtype=float)
    except (TypeError, ValueError) as exc:
        raise FieldPluginError(f"{label}: frames is not numeric ({exc})") from None
    if frames.ndim not in (3, 4) or frames.shape[0] < 1 or min(frames.shape[1:]) < 2:
        raise FieldPluginError(f"{label}: frames must have shape (T, nx, ny) or (T, nx, ny, nz) with T >= 1 and "
                               f"at least 2 nodes per axis, got {frames.shape}")
    if not np.all(np.isfinite(frames)):
        k = int(np.flatnonzero(~np.isfinite(frames).reshape(len(frames), -1).all(axis=1))[0])
        raise FieldPluginError(f"{label}: frames hold non-finite values (first in frame {k})")
    if np.any(frames < 0):
        raise FieldPluginError(f"{label}: frames hold negative values (min {frames.min():.6g}); "
                               "a concentration is >= 0")
    return frames


class GridField:
    """Frames on a regular grid, interpolated linearly in space and time (module docstring).

    Parameters
    ----------
    frames : array_like, shape (T, nx, ny) or (T, nx, ny, nz)
        Concentrations, finite and >= 0.
    origin_enu_m, spacing_m : array_like, shape (d,)
        First node and node spacing per axis, ENU m (d = 2 or 3).
    frame_period_s : float
        Seconds between frames (> 0).
    t0_s : float
        Time of frame 0 (the world's clock, s).
    loop : bool
        Repeat the frames every ``T * frame_period_s``.
    source_enu_m : array_like (3,), optional
        The point a seeker should find (default: the node of the largest time-mean).
    label : str
        Names the data in messages and ``repr`` (e.g. ``"grid field data.npz"``).
    """

    def __init__(self, frames, origin_enu_m, spacing_m, frame_period_s: float, t0_s: float = 0.0,
                 loop: bool = False, source_enu_m=None, label: str = "grid field"):
        from scipy.interpolate import RegularGridInterpolator

        data = {"frames": frames, "origin_enu_m": origin_enu_m, "spacing_m": spacing_m,
                "frame_period_s": frame_period_s, "t0_s": t0_s}
        self.label = label
        self.frames = _frames(data, label)
        self.dims = self.frames.ndim - 1
        self.origin_enu_m = _vector(data, "origin_enu_m", self.dims, label)
        self.spacing_m = _vector(data, "spacing_m", self.dims, label, positive=True)
        self.frame_period_s = _scalar(data, "frame_period_s", label, positive=True)
        self.t0_s = _scalar(data, "t0_s", label, positive=False)
        self.loop = bool(loop)
        n_frames = len(self.frames)
        self.time_dependent = n_frames > 1
        stack = np.concatenate([self.frames, self.frames[:1]]) if self.loop and n_frames > 1 else self.frames
        if len(stack) == 1:  # one frame: a static field; the frame axis needs two nodes
            stack = np.concatenate([stack, stack])
        self.axes = tuple(o + s * np.arange(n) for o, s, n in zip(self.origin_enu_m, self.spacing_m,
                                                                   self.frames.shape[1:]))
        self._interp = RegularGridInterpolator((np.arange(len(stack), dtype=float),) + self.axes, stack,
                                               method="linear", bounds_error=False, fill_value=0.0)
        self._source = self._default_source() if source_enu_m is None else _vector(
            {"source_enu_m": source_enu_m}, "source_enu_m", 3, label)

    def __repr__(self) -> str:
        return (f"GridField({self.label.removeprefix('grid field ')}, frames={self.frames.shape}, "
                f"spacing_m={self.spacing_m.tolist()}, frame_period_s={self.frame_period_s:g}, loop={self.loop})")

    def _default_source(self) -> np.ndarray:
        idx = np.unravel_index(int(np.argmax(self.frames.mean(axis=0))), self.frames.shape[1:])
        node = [ax[i] for ax, i in zip(self.axes, idx)]
        return np.array(node + [0.0] * (3 - self.dims), dtype=float)

    def _frame_coordinate(self, t_s) -> np.ndarray:
        n = len(self.frames)
        s = (np.asarray(t_s, dtype=float) - self.t0_s) / self.frame_period_s
        if n == 1:
            return np.zeros_like(s)
        return np.mod(s, n) if self.loop else np.clip(s, 0.0, n - 1.0)

    def value(self, points, t_s=0.0) -> np.ndarray:
        """Concentration at ``points`` (..., 3) and time ``t_s`` (scalar or broadcastable to
        ``points.shape[:-1]``), shape (...)."""
        pts = np.asarray(points, dtype=float)
        lead = pts.shape[:-1]
        s = np.broadcast_to(self._frame_coordinate(t_s), lead)
        query = np.concatenate([s[..., None], pts[..., :self.dims]], axis=-1).reshape(-1, 1 + self.dims)
        return self._interp(query).reshape(lead)

    def gradient(self, points, t_s=0.0) -> np.ndarray:
        """Central differences of :meth:`value` (step 1e-3 of the smallest spacing), shape (..., 3)."""
        pts = np.asarray(points, dtype=float)
        h = _GRAD_FRACTION * float(self.spacing_m.min())
        grad = np.zeros(pts.shape)
        for i in range(self.dims):
            step = np.zeros(3)
            step[i] = h
            grad[..., i] = (self.value(pts + step, t_s) - self.value(pts - step, t_s)) / (2.0 * h)
        return grad

    def source_enu(self) -> np.ndarray:
        """``source_enu_m`` of the file, else the node of the largest time-mean value."""
        return self._source.copy()


def load_grid(path) -> GridField:
    """The :class:`GridField` of the ``.npz`` at ``path``.

    Raises
    ------
    FieldPluginError
        The file cannot be read, misses a key, or a key has a wrong shape or value.
    """
    path = Path(path)
    label = f"grid field {path}"
    try:
        with np.load(path, allow_pickle=False) as npz:
            data = {k: npz[k] for k in npz.files}
    except (OSError, ValueError, EOFError) as exc:  # missing, unreadable, not an npz, pickled objects
        raise FieldPluginError(f"{label}: cannot read it as a NumPy .npz ({_one_line(exc)})") from None
    missing = [k for k in REQUIRED_KEYS if k not in data]
    if missing:
        raise FieldPluginError(f"{label}: missing key{'s' if len(missing) > 1 else ''} {', '.join(missing)} "
                               f"(needs {', '.join(REQUIRED_KEYS)})")
    unknown = sorted(set(data) - set(REQUIRED_KEYS) - set(OPTIONAL_KEYS))
    if unknown:
        raise FieldPluginError(f"{label}: unknown key{'s' if len(unknown) > 1 else ''} {', '.join(unknown)} "
                               f"(known: {', '.join(REQUIRED_KEYS + OPTIONAL_KEYS)})")
    loop = data.get("loop", False)
    if np.asarray(loop).shape not in ((), (1,)) or np.asarray(loop).dtype.kind not in "bi":
        raise FieldPluginError(f"{label}: loop must be one boolean, got {np.asarray(loop)!r}")
    return GridField(data["frames"], data["origin_enu_m"], data["spacing_m"], data["frame_period_s"],
                     t0_s=data.get("t0_s", 0.0), loop=bool(np.asarray(loop).reshape(-1)[0]),
                     source_enu_m=data.get("source_enu_m"), label=label)


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def from_table(table: dict) -> GridField:
    """A field plug-in factory: the grid of the table's ``npz`` path (``[field] python =
    "sitl_mock.fields_grid:from_table"``; the same as ``type = "grid"``)."""
    npz = table.get("npz")
    if not isinstance(npz, str) or not npz:
        raise FieldPluginError(f"grid field: [field] npz must be the path of a .npz file, got {npz!r}")
    return load_grid(npz)
