"""An intermittent plume: puffs released at the source, advected by a meandering wind, dispersing.

In the style of the filament model of Farrell, Murlis, Long, Li & Cardé (2002), "Filament-based
atmospheric dispersion model to achieve short time-scale structure of odor plumes",
*Environmental Fluid Mechanics* 2, 143-169: the source releases puffs at ``release_rate_hz``;
each puff is carried downwind at the wind speed, displaced crosswind and vertically by a
**meander** common to all puffs (large eddies swinging the whole plume, so the plume snakes and
a fixed sensor sees it come and go) plus its own **relative dispersion**, and grows. A reading
is the sum of the puffs' Gaussian kernels at the sensor, plus the background: patchy in time
(long stretches at the background, then bursts), a function of position AND time, fully
deterministic for a seed (no state: any ``(points, t_s)`` can be asked in any order).

Construction (what makes the time-average exactly the steady plume's shape): a puff released
at ``t_k`` has, at time ``t`` (age ``a = t - t_k``, downwind distance ``x = U a``), its centre
at ``(x, Y, H + Z)`` in the wind frame and a Gaussian kernel of standard deviations
``(s0, kappa s_y(x), kappa s_z(x))`` (``kappa`` the ``puff_fraction``; along the wind the
puffs keep the source radius ``s0``), carrying ``Q / release_rate_hz``. The displacement is
``Y = sqrt(f (1 - kappa^2)) s_y m_y + sqrt((1 - f) (1 - kappa^2)) s_y xi_y`` (``f`` the
``meander_fraction``, same for ``Z`` with ``s_z``), where ``xi`` is the puff's own N(0, 1) draw
and ``m`` the meander: the integral over ``[t_k, t]`` of a wind-direction process (N(0, 1)
values every ``meander_time_s``, linearly interpolated), divided by its standard deviation, so
``m`` is exactly N(0, 1) for every puff and time, and puffs released close together share it.
Hence ``Y ~ N(0, (1 - kappa^2) s_y^2)``, the puff-averaged concentration is
``N(y; 0, s_y) N(z; H, s_z)`` (the image puff at ``-(H + Z)`` gives the ground reflection) and,
puffs being closer along the wind than ``s0``, their sum is the steady plume of
:class:`sitl_mock.fields_plume.GaussianPlume` smoothed along the wind by a Gaussian of standard
deviation ``s0`` (the ensemble mean). The smoothing changes the centreline by about
``s0^2 C'' / (2 C)`` relative (``C ~ x^-p``: ``p (p + 1) s0^2 / (2 x^2)``, 2-3 % at 10 m with
``s0 = 1`` m, under 1 % beyond 20 m) and rounds the upwind edge (at the release the mean is
about half the steady value).
Readings taken more than ``max_range_m / U + 2 meander_time_s`` apart share no puff and no
meander value: they are independent draws.
"""
from __future__ import annotations

import numpy as np

from sitl_mock.fields_plume import GaussianPlume, _positive

__all__ = ["FilamentPlume"]

_GOLDEN = 0x9E3779B97F4A7C15
_MIX1 = 0xBF58476D1CE4E5B9
_MIX2 = 0x94D049BB133111EB
_CHUNK_POINTS = 8192
#: puffs farther than this many source radii along the wind from a point are left out (< 2e-8)
_CUTOFF = 6.0


def _mix(z: np.ndarray) -> np.ndarray:
    """splitmix64 finaliser on a uint64 array (wraps modulo 2^64)."""
    z = z ^ (z >> np.uint64(30))
    z = z * np.uint64(_MIX1)
    z = z ^ (z >> np.uint64(27))
    z = z * np.uint64(_MIX2)
    return z ^ (z >> np.uint64(31))


def hashed_normals(seed: int, stream: int, index) -> np.ndarray:
    """N(0, 1) numbers that depend only on ``(seed, stream, index)`` (counter-based, vectorised).

    ``index`` is an integer array (int64); the result has its shape.
    """
    key = _mix(np.array([(int(seed) * 16 + int(stream)) % (1 << 64)], dtype=np.uint64))
    idx = np.asarray(index, dtype=np.int64).view(np.uint64)
    h = _mix(_mix(idx * np.uint64(_GOLDEN) + key) ^ key)
    u = ((h >> np.uint64(11)).astype(np.float64) + 0.5) * 2.0 ** -53
    from scipy.special import ndtri  # here, not at the top: scipy.special costs a third of a CPU second
    # at every start of a mock fleet, which needs it only for this plume
    return ndtri(u)


class FilamentPlume:
    """Intermittent plume of puffs (see the module docstring); its mean is :attr:`steady`.

    Parameters
    ----------
    source : array_like, shape (3,)
        Release point, ENU m (as :class:`~sitl_mock.fields_plume.GaussianPlume`).
    seed : int
        Seed of the meander and of the puffs' own displacements.
    release_rate_hz : float or None
        Puffs per second; None: ``2 U / s0`` (two puffs per source radius along the wind).
    puff_fraction : float
        ``kappa`` in (0, 1): a puff's crosswind / vertical size as a fraction of the plume's.
    meander_fraction : float
        ``f`` in [0, 1]: share of the displacement variance due to the common meander.
    meander_time_s : float
        Spacing of the wind-direction values (correlation time of the meander).
    max_range_m : float
        Puffs are dropped this far downwind (age ``max_range_m / U``).
    **plume
        ``wind_from_deg``, ``wind_speed_m_s``, ``stability``, ``source_radius_m``,
        ``emission_rate``, ``ground_reflection``, ``background``, ``ground_alt_m``: as
        :class:`~sitl_mock.fields_plume.GaussianPlume`.

    Raises
    ------
    ValueError
        A parameter is out of range.
    """

    time_dependent = True

    def __init__(self, source=(0.0, 0.0, 0.0), *, seed: int = 0, release_rate_hz: float | None = None,
                 puff_fraction: float = 0.2, meander_fraction: float = 0.7, meander_time_s: float = 5.0,
                 max_range_m: float = 150.0, **plume):
        self.steady = GaussianPlume(source, **plume)
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
            raise ValueError(f"seed must be an integer, got {seed!r}")
        self.seed = int(seed)
        s = self.steady
        rate = 2.0 * s.wind_speed_m_s / s.source_radius_m if release_rate_hz is None else release_rate_hz
        self.release_rate_hz = _positive(rate, "release_rate_hz")
        self.puff_fraction = _positive(puff_fraction, "puff_fraction")
        if not self.puff_fraction < 1.0:
            raise ValueError(f"puff_fraction must be in (0, 1), got {puff_fraction!r}")
        self.meander_fraction = _positive(meander_fraction, "meander_fraction", allow_zero=True)
        if self.meander_fraction > 1.0:
            raise ValueError(f"meander_fraction must be in [0, 1], got {meander_fraction!r}")
        self.meander_time_s = _positive(meander_time_s, "meander_time_s")
        self.max_range_m = _positive(max_range_m, "max_range_m")
        self.n_puffs = int(np.ceil(self.max_range_m / s.wind_speed_m_s * self.release_rate_hz)) + 1
        self._cache = None  # (time, puffs) of the last single-time evaluation (a pure function's memo)
        if self.n_puffs > 200000:
            raise ValueError(f"{self.n_puffs} live puffs (max_range_m / wind_speed_m_s x release_rate_hz) "
                             "is too many; lower release_rate_hz or max_range_m")

    def __repr__(self) -> str:
        return (f"FilamentPlume({self.steady!r}, seed={self.seed}, release_rate_hz={self.release_rate_hz:g}, "
                f"puff_fraction={self.puff_fraction:g}, meander_fraction={self.meander_fraction:g}, "
                f"meander_time_s={self.meander_time_s:g}, max_range_m={self.max_range_m:g})")

    @property
    def background(self) -> float:
        return self.steady.background

    def _meander(self, t: np.ndarray, t_k: np.ndarray) -> np.ndarray:
        """``(m_y, m_z)``: the normalised integrals of the two meander processes from each
        puff's release ``t_k`` (T, M) to ``t`` (T,), shape (2, T, M).

        The integral of the interpolated process over ``[t_k, t]`` is ``sum_n theta_n w_n``
        with ``w_n = H_n(t) - H_n(t_k)`` (``H_n`` the integral of node ``n``'s hat function):
        computed from the running sum of the nodes' values, and its variance
        ``sum_n w_n^2`` from the full-weight nodes between the two and the four edge nodes.
        """
        step = self.meander_time_s
        span = int(np.ceil(self.n_puffs / self.release_rate_hz / step)) + 4
        j_t = np.floor(t / step)[:, None]             # (T, 1): cell of t
        j_k = np.floor(t_k / step)                    # (T, M): cell of each release
        n0 = j_t - span                               # first node of each time's window
        nodes = (n0 + np.arange(span + 3)[None, :]).astype(np.int64)  # (T, L)
        h = self._hat_integrals
        var = step * step * np.maximum(j_t - j_k - 2.0, 0.0)
        edges = (j_k, j_k + 1.0, np.broadcast_to(j_t, j_k.shape), np.broadcast_to(j_t + 1.0, j_k.shape))
        valid = (True, True, (j_t != j_k) & (j_t != j_k + 1.0), j_t != j_k)
        for n, ok in zip(edges, valid):
            w = h(n, t[:, None]) - h(n, t_k)
            var = var + np.where(ok, w * w, 0.0)
        phi_t = t[:, None] / step - j_t
        out = []
        for stream in (0, 1):
            theta = hashed_normals(self.seed, stream, nodes)                         # (T, L)
            cum = np.concatenate([np.zeros((len(t), 1)), np.cumsum(theta, axis=1)], axis=1)
            integral = self._antiderivative(theta, cum, t[:, None], j_t, n0) - \
                self._antiderivative(theta, cum, t_k, j_k, n0)
            i = (j_t - n0).astype(np.int64)
            now = (np.take_along_axis(theta, i, 1) * (1.0 - phi_t) + np.take_along_axis(theta, i + 1, 1) * phi_t) \
                / np.sqrt((1.0 - phi_t) ** 2 + phi_t ** 2)  # age 0: the limit a -> 0
            out.append(np.where(var > 0.0, integral / np.sqrt(np.where(var > 0.0, var, 1.0)), now))
        return np.stack(out)

    def _hat_integrals(self, n, s):
        """``H_n(s)``: integral up to ``s`` of node ``n``'s hat function (arrays, broadcast)."""
        step = self.meander_time_s
        u = np.clip(s / step - n, -1.0, 1.0)
        return step * np.where(u < 0.0, 0.5 * (u + 1.0) ** 2, 1.0 - 0.5 * (1.0 - u) ** 2)

    def _antiderivative(self, theta, cum, s, j, n0):
        """``sum_n theta_n H_n(s)`` over the window's nodes (``s`` in cell ``j``), shape of ``s``."""
        step = self.meander_time_s
        i = np.broadcast_to((j - n0).astype(np.int64), np.broadcast_shapes(np.shape(s), np.shape(j)))
        phi = s / step - j
        full = np.take_along_axis(cum, i, 1)  # nodes before cell j: whole hat integrals
        return step * (full + np.take_along_axis(theta, i, 1) * (1.0 - 0.5 * (1.0 - phi) ** 2)
                       + np.take_along_axis(theta, i + 1, 1) * 0.5 * phi ** 2)

    def puffs(self, t_s) -> dict:
        """The live puffs at time(s) ``t_s`` (scalar or shape (T,)) in the wind frame: centres
        ``x, y, z`` (z above the ground), kernel standard deviations ``sx, sy, sz`` (each of
        shape (M,) or (T, M)) and ``mass``."""
        s = self.steady
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        k = np.floor(t * self.release_rate_hz)[:, None] - np.arange(self.n_puffs)[None, :]
        t_k = k / self.release_rate_hz
        x = s.wind_speed_m_s * np.maximum(t[:, None] - t_k, 0.0)
        sy, sz = s.spreads(x)
        kap = self.puff_fraction
        rest = np.sqrt(1.0 - kap * kap)
        m_y, m_z = self._meander(t, t_k)
        ki = k.astype(np.int64)
        fm, fd = np.sqrt(self.meander_fraction), np.sqrt(1.0 - self.meander_fraction)
        y = rest * sy * (fm * m_y + fd * hashed_normals(self.seed, 2, ki))
        z = s.release_height_m + rest * sz * (fm * m_z + fd * hashed_normals(self.seed, 3, ki))
        out = dict(x=x, y=y, z=z, sx=np.full_like(x, s.source_radius_m), sy=kap * sy, sz=kap * sz)
        if np.ndim(t_s) == 0:
            out = {key: v[0] for key, v in out.items()}
        out["mass"] = s.emission_rate / self.release_rate_hz
        return out

    def _plume_at(self, points: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Sum of the puffs at ``points`` (P, 3), point ``i`` at time ``t[i]``, shape (P,)."""
        t_unique, inverse = np.unique(t, return_inverse=True)
        if len(t_unique) == 1 and self._cache is not None and self._cache[0] == t_unique[0]:
            pf = self._cache[1]  # the fleet's vehicles sample one after another at the same time
        else:
            pf = self.puffs(t_unique)
            if len(t_unique) == 1:
                self._cache = (float(t_unique[0]), pf)
        x, y, z = self.steady.wind_frame(points)
        # only the puffs within CUTOFF source radii along the wind count (s_x = s0 for all):
        # puff j sits at U (j + frac) / rate downwind, so they are a window of indices
        lam_u = self.release_rate_hz / self.steady.wind_speed_m_s
        frac = (t_unique * self.release_rate_hz - np.floor(t_unique * self.release_rate_hz))[inverse]
        half = int(np.ceil(_CUTOFF * self.steady.source_radius_m * lam_u)) + 1
        j = np.rint(x * lam_u - frac).astype(np.int64)[:, None] + np.arange(-half, half + 1)[None, :]
        live = (j >= 0) & (j < self.n_puffs)
        rows, cols = inverse[:, None] if len(t_unique) > 1 else 0, np.clip(j, 0, self.n_puffs - 1)
        px, py, pz, sy, sz = (pf[key].reshape(len(t_unique), -1)[rows, cols] for key in ("x", "y", "z", "sy", "sz"))
        s0 = self.steady.source_radius_m
        q = ((x[:, None] - px) / s0) ** 2 + ((y[:, None] - py) / sy) ** 2
        vert = np.exp(-0.5 * ((z[:, None] - pz) / sz) ** 2)
        if self.steady.ground_reflection:
            vert = vert + np.exp(-0.5 * ((z[:, None] + pz) / sz) ** 2)
        norm = pf["mass"] / ((2.0 * np.pi) ** 1.5 * s0 * sy * sz)
        return np.sum(np.where(live, norm * np.exp(-0.5 * q) * vert, 0.0), axis=1)

    def value(self, points, t_s=0.0):
        """Instantaneous concentration at ``points`` (..., 3) ENU m and time ``t_s`` (scalar or
        array broadcastable to ``points.shape[:-1]``), shape (...)."""
        p = np.asarray(points, dtype=float)
        if p.shape[-1:] != (3,):
            raise ValueError(f"points must have shape (..., 3), got {p.shape}")
        t = np.asarray(t_s, dtype=float)
        if not np.all(np.isfinite(t)):
            raise ValueError("t_s must be finite")
        flat = p.reshape(-1, 3)
        tf = np.broadcast_to(t, p.shape[:-1]).reshape(-1)
        out = np.empty(len(flat))
        for lo in range(0, len(flat), _CHUNK_POINTS):  # bounded memory: chunk x live puffs
            out[lo:lo + _CHUNK_POINTS] = self._plume_at(flat[lo:lo + _CHUNK_POINTS], tf[lo:lo + _CHUNK_POINTS])
        return out.reshape(p.shape[:-1]) + self.steady.background

    def mean_value(self, points, nodes: int = 241):
        """The exact ensemble (time) mean at ``points`` (..., 3), shape (...): the puffs'
        expected kernels integrated over their release times (trapezoid rule on ``nodes``
        points within 6 ``s0`` along the wind), plus the background. It is the steady plume
        smoothed along the wind by ``N(0, s0^2)`` and cut at ``max_range_m``."""
        s = self.steady
        x, y, z = (np.asarray(v)[..., None] for v in s.wind_frame(points))
        s0 = s.source_radius_m
        lo = np.clip(x - 6.0 * s0, 0.0, self.max_range_m)
        hi = np.clip(x + 6.0 * s0, 0.0, self.max_range_m)
        xi = lo + (hi - lo) * np.linspace(0.0, 1.0, nodes)  # puff positions, (..., nodes)
        sy, sz = s.spreads(xi)
        h = s.release_height_m
        vert = np.exp(-0.5 * ((z - h) / sz) ** 2)
        if s.ground_reflection:
            vert = vert + np.exp(-0.5 * ((z + h) / sz) ** 2)
        f = (np.exp(-0.5 * ((x - xi) / s0) ** 2) / (np.sqrt(2.0 * np.pi) * s0)
             * np.exp(-0.5 * (y / sy) ** 2) * vert / (2.0 * np.pi * sy * sz))
        integral = np.trapezoid(f, xi, axis=-1)
        return s.emission_rate / s.wind_speed_m_s * integral + s.background

    def gradient(self, points, t_s=0.0):
        """Gradient of the mean field (the instantaneous field has no useful gradient)."""
        return self.steady.gradient(points)

    def release_enu(self) -> np.ndarray:
        """The release point, ENU m."""
        return self.steady.release_enu()

    def source_enu(self) -> np.ndarray:
        """Same as :meth:`release_enu` (see :mod:`sitl_mock.fields_plume` for what it means)."""
        return self.steady.release_enu()

    def peak_enu(self, alt_m: float | None = None, max_range_m: float = 500.0) -> np.ndarray:
        """The mean field's centreline maximum at ``alt_m`` (:meth:`GaussianPlume.peak_enu`)."""
        return self.steady.peak_enu(alt_m, max_range_m)

    def newton_gain(self) -> float:
        """The mean plume's :meth:`GaussianPlume.newton_gain`."""
        return self.steady.newton_gain()
