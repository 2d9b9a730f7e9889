"""A plume seeker: surge up the plume's axis while the signal is there, cast across it when lost.

In the spirit of odour-source localisation by insects and robots (surge upwind on a detection,
cast crosswind in a widening zig-zag when the plume is lost; e.g. Kennedy & Marsh 1974, Li,
Farrell & Cardé 2001, "Tracking of fluid-advected odor plumes", *IEEE Trans. Robotics and
Automation* 17(6)), adapted to a formation that can place its vehicles. Batched over ``K``
trials like :mod:`estimator.seekers` (``propose(centre, positions, values)`` -> next centres).

Per iteration:

1. **Detections** (:class:`~estimator.seek_signal.SignalFloor`): a reading above the noise floor
   estimated from the readings' own low quantiles. No detection for ``lost_iterations`` -> cast.
2. **Wind axis**: the downwind direction from ``wind_from_deg`` (meteorological, degrees
   clockwise from north, where the wind comes FROM) when given; otherwise estimated: the plume is
   elongated along the wind, so the horizontal direction of least curvature of the fitted
   log-quadratic (:func:`estimator.seek_quadratic.fit_quadratic`) is the axis, oriented up the
   fitted gradient, averaged over the iterations weighted by the fit's anisotropy.
3. **Axis point**: the plume's centreline across the wind, from the same fit restricted to the
   plane across the wind (the Newton point of ``log s`` in that plane, at most ``max_shift_m``;
   the detections' weighted centroid if the fit is not concave there).
4. **Surge** (signal present): the formation is placed so that its most upwind vehicle (the
   *nose*) is on the axis, ``surge_m`` further upwind than it was. A plume is narrower than the
   formation near the release (``docs/seekers.md``: why the gradient and model seekers stall
   16-17 m downwind), so the centre is not where the source is read; the nose is. When the nose,
   on the axis, has gone ``pass_m`` upwind of its best reading and reads below ``drop`` times
   that best, the source has been passed: the formation backs off ``back_m`` downwind of the
   best point and approaches again with steps of ``probe_m``; the second pass's best point (its
   along-wind position refined by a parabola through log-readings) is the estimate.
5. **Hold**: the centre goes to the estimate and stays; the signal lost for
   ``hold_lost_iterations``, the nose reading the plume, or a reading stronger than the held
   best -> search again. :attr:`arrival` (the convergence test's signal) is "holding, with a
   detection, the nose quiet and the strongest reading steady" (a patchy plume's never is).
6. **Cast** (signal lost): zig-zag across the wind about the last place with a detection,
   legs of ``cast_m`` growing by ``cast_growth`` each pair (at most ``cast_max_m``), alternately
   above and below, drifting ``cast_drift_m`` downwind per leg (a plume widens downwind).

The caller caps every move at ``gamma_m`` and applies the safety envelope.
"""
from __future__ import annotations

from collections import deque

import numpy as np

from estimator.seek_inputs import seeker_inputs
from estimator.seek_quadratic import fit_quadratic
from estimator.seek_signal import SignalFloor

__all__ = ["PlumeSeeker", "downwind_from_deg"]

_ACQUIRE, _COARSE, _FINE, _HOLD = 0, 1, 2, 3
_Z = np.array([0.0, 0.0, 1.0])


def downwind_from_deg(wind_from_deg: float) -> np.ndarray:
    """Unit ENU vector the wind blows toward, from the meteorological direction it comes from."""
    if isinstance(wind_from_deg, bool) or not np.isfinite(float(wind_from_deg)):
        raise ValueError(f"wind_from_deg must be a finite number of degrees, got {wind_from_deg!r}")
    rad = np.deg2rad(float(wind_from_deg))
    return np.array([-np.sin(rad), -np.cos(rad), 0.0])


def _positive(name: str, value, allow_zero: bool = False) -> float:
    v = float(value)
    if not np.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise ValueError(f"{name} must be a finite number {'>=' if allow_zero else '>'} 0, got {value!r}")
    return v


class PlumeSeeker:
    """Surge / cast plume seeker (module docstring has the algorithm).

    Parameters
    ----------
    wind_from_deg : float or None
        Wind direction (where it comes from, degrees clockwise from north); None: estimated.
    surge_m, probe_m : float
        Nose advance per iteration with a detection: first pass, second (fine) pass.
    pass_m, back_m, drop : float
        Source passed when the nose is ``pass_m`` upwind of its best and reads < ``drop`` x best;
        the fine pass starts ``back_m`` downwind of the first pass's best.
    cast_m, cast_growth, cast_max_m, cast_drift_m : float
        Casting legs (first half-width, growth per pair, largest, downwind drift per leg).
    lost_iterations, hold_lost_iterations : int
        Iterations without a detection before casting (tracking, holding).
    window : int
        Iterations of readings in the axis fit.
    max_shift_m : float
        Largest correction toward the fitted axis per iteration.
    on_axis_m : float
        The nose counts as on the axis within this distance of it.
    quiet : int
        Low on-axis nose readings in a row that end a pass.
    hold_fraction : float
        Hold only at a best reading at least this fraction of the strongest seen; leave the hold
        when a reading beats the held best by ``1 / hold_fraction``.
    blob_ratio : float
        Fields with a maximum no more elongated than ``1 : blob_ratio`` are sought as smooth
        sources (step to the fitted maximum), until a plume has been passed.
    steady_tol : float
        The convergence signal (:attr:`arrival`) needs the formation's strongest reading to change
        by at most this fraction (plus 3 noise standard deviations) from the last iteration.
    sigmas : float
        Detection threshold, noise standard deviations above the background.
    """

    name = "plume"

    def __init__(self, wind_from_deg: float | None = None, *, surge_m: float = 3.0, probe_m: float = 0.5,
                 pass_m: float = 2.0, back_m: float = 3.0, drop: float = 0.3, cast_m: float = 4.0,
                 cast_growth: float = 1.5, cast_max_m: float = 30.0, cast_drift_m: float = 1.0,
                 lost_iterations: int = 3, hold_lost_iterations: int = 8, window: int = 16,
                 max_shift_m: float = 3.0, on_axis_m: float = 0.75, quiet: int = 1, hold_fraction: float = 0.7,
                 blob_ratio: float = 0.1, steady_tol: float = 0.3,
                 sigmas: float = 3.0):
        self.wind_from_deg = None if wind_from_deg is None else float(wind_from_deg)
        self._down = None if wind_from_deg is None else downwind_from_deg(wind_from_deg)
        for name, v in (("surge_m", surge_m), ("probe_m", probe_m), ("pass_m", pass_m), ("back_m", back_m),
                        ("cast_m", cast_m), ("cast_max_m", cast_max_m), ("max_shift_m", max_shift_m),
                        ("on_axis_m", on_axis_m)):
            setattr(self, name, _positive(name, v))
        self.cast_drift_m = _positive("cast_drift_m", cast_drift_m, allow_zero=True)
        if not 0 <= hold_fraction < 1:
            raise ValueError(f"hold_fraction must be in [0, 1), got {hold_fraction!r}")
        self.hold_fraction = float(hold_fraction)
        if not 0 <= blob_ratio <= 1:
            raise ValueError(f"blob_ratio must be in [0, 1], got {blob_ratio!r}")
        self.blob_ratio = float(blob_ratio)
        self.steady_tol = _positive("steady_tol", steady_tol)
        if not 0 < drop < 1:
            raise ValueError(f"drop must be in (0, 1), got {drop!r}")
        if not (np.isfinite(cast_growth) and cast_growth >= 1):
            raise ValueError(f"cast_growth must be a finite number >= 1, got {cast_growth!r}")
        for name, v in (("lost_iterations", lost_iterations), ("hold_lost_iterations", hold_lost_iterations),
                        ("window", window), ("quiet", quiet)):
            if int(v) != v or v < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
        self.drop, self.cast_growth = float(drop), float(cast_growth)
        self.lost_iterations, self.hold_lost_iterations = int(lost_iterations), int(hold_lost_iterations)
        self.window = int(window)
        self.quiet = int(quiet)
        self.floor = SignalFloor(sigmas=sigmas)
        self.reset()

    def reset(self) -> None:
        """Forget everything (a new run)."""
        self.floor.reset()
        self._k = None
        self.arrival = None
        self._buf: deque = deque(maxlen=self.window)

    def source_estimate(self, k: int = 0) -> None:
        """None: this seeker reacts to the latest readings and has no model of the source, so no
        region to give (where it holds, the mission reports the monitor's mean of the centres)."""
        return None

    def _init_state(self, c: np.ndarray) -> None:
        k = c.shape[0]
        self._k = k
        self.phase = np.full(k, _ACQUIRE)
        self.miss = np.full(k, self.lost_iterations)  # no detection yet: cast from the start
        self.anchor = c.copy()
        self.leg = np.zeros(k, dtype=int)
        self.best_v = np.full(k, -np.inf)
        self.best_s = np.zeros(k)
        self.best_pos = c.copy()
        self.coarse_s = np.zeros(k)
        self.coarse_pos = c.copy()
        self.lows = np.zeros(k, dtype=int)
        self.nose_hits = np.zeros(k, dtype=int)
        self.nose_quiet = np.ones(k, dtype=bool)
        self.peak = np.full(k, -np.inf)
        self.prev_max = np.full(k, np.inf)
        self.estimate = c.copy()
        self.upwind_sum = np.zeros((k, 3))
        self.signal = np.zeros(k, dtype=bool)
        self.arrival = None
        self.detected = np.zeros(k, dtype=bool)

    # ------------------------------------------------------------------ geometry
    def _upwind(self, fit, det_any) -> np.ndarray:
        """Unit upwind vectors (K, 3): the given wind, else the running axis estimate (module doc)."""
        if self._down is not None:
            return np.broadcast_to(-self._down, (self._k, 3)).copy()
        h = fit.hessian[:, :2, :2]
        lam, vec = np.linalg.eigh(h)
        e = vec[:, :, 1]  # least curvature (largest eigenvalue) horizontally: along the plume
        aniso = np.clip((lam[:, 1] - lam[:, 0]) / np.maximum(np.abs(lam[:, 0]), 1e-300), 0.0, 1.0)
        sign = np.sign(np.einsum("ki,ki->k", fit.grad[:, :2], e))
        w = np.where(det_any & (lam[:, 0] < 0) & (fit.used >= 10), aniso, 0.0)
        self.upwind_sum[:, :2] += (w * sign)[:, None] * e
        g = np.concatenate([fit.grad[:, :2], np.zeros((self._k, 1))], axis=1)
        known = np.linalg.norm(self.upwind_sum, axis=1) >= 1.0
        u = np.where(known[:, None], self.upwind_sum, g)
        n = np.linalg.norm(u, axis=1, keepdims=True)
        return np.where(n > 0, u / np.where(n > 0, n, 1.0), np.array([1.0, 0.0, 0.0]))

    def _axis_point(self, c, p, v, det, fit, up) -> np.ndarray:
        """The plume's centreline in the plane across the wind through ``c`` (module doc, step 3)."""
        e1 = np.cross(_Z, up)
        e1 /= np.maximum(np.linalg.norm(e1, axis=1, keepdims=True), 1e-12)
        basis = np.stack([e1, np.broadcast_to(_Z, e1.shape)], axis=1)  # (K, 2, 3)
        h = np.einsum("kai,kij,kbj->kab", basis, fit.hessian, basis)
        g = np.einsum("kai,ki->ka", basis, fit.grad)
        lam = np.linalg.eigvalsh(h)
        ok = (lam[:, -1] < 0) & (fit.used >= 6)
        t = -np.linalg.solve(np.where(ok[:, None, None], h, -np.eye(2)), g[..., None])[..., 0]
        shift = np.einsum("ka,kai->ki", t, basis)
        w = np.where(det, np.maximum(v - self.floor.background[:, None], 0.0), 0.0)
        wsum = w.sum(axis=1, keepdims=True)
        cen = np.einsum("kn,kni->ki", w, p) / np.where(wsum > 0, wsum, 1.0) - c
        cen = cen - np.einsum("ki,ki->k", cen, up)[:, None] * up
        shift = np.where(ok[:, None], shift, np.where(wsum > 0, cen, 0.0))
        length = np.linalg.norm(shift, axis=1, keepdims=True)
        return c + shift * np.minimum(1.0, self.max_shift_m / np.maximum(length, 1e-12))

    # ------------------------------------------------------------------ the step
    def propose(self, centre, positions, values) -> np.ndarray:
        """Next centres ``(K, 3)`` from centres ``(K, 3)``, positions ``(K, N, 3)``, readings ``(K, N)``."""
        c, p, v = seeker_inputs(centre, positions, values)
        if self._k != c.shape[0]:
            self.reset()
            self._init_state(c)
        det = self.floor.update(v)
        sig = det.any(axis=1)
        self.signal = sig
        self.detected |= sig
        self.arrival = None  # set below: holding with a detection (the convergence test's signal)
        self._buf.append((p, v, det))
        pw, vw, dw = (np.concatenate([b[i] for b in self._buf], axis=1) for i in range(3))
        fit = fit_quadratic(pw, vw, dw & (vw > 0), c, log=True)
        up = self._upwind(fit, sig)
        axis = self._axis_point(c, p, v, det, fit, up)
        self.miss = np.where(sig, 0, self.miss + 1)
        self.anchor = np.where(sig[:, None], c, self.anchor)
        start = (self.phase == _ACQUIRE) & sig
        self.phase = np.where(start, _COARSE, self.phase)
        self.best_v = np.where(start, -np.inf, self.best_v)
        target = self._track(c, p, v, axis, up, sig)
        lost = ((self.phase == _COARSE) | (self.phase == _FINE)) & (self.miss >= self.lost_iterations)
        lost |= (self.phase == _HOLD) & (self.miss >= self.hold_lost_iterations)
        self.leg = np.where(lost, 0, self.leg)
        self.phase = np.where(lost, _ACQUIRE, self.phase)
        cast = self._cast(c, up)
        tracking = (self.phase == _COARSE) | (self.phase == _FINE)
        out = np.where(tracking[:, None], np.where(sig[:, None], target, c), c)
        out = np.where((self.phase == _HOLD)[:, None], self.estimate, out)
        out = np.where((self.phase == _ACQUIRE)[:, None], cast, out)
        blob, peak = self._blob(c, pw, vw)
        vmax = v.max(axis=1)
        steady = np.abs(vmax - self.prev_max) <= self.steady_tol * np.maximum(vmax, self.prev_max) \
            + 3.0 * self.floor.noise_std  # a patchy plume's readings never settle: no arrival there
        self.prev_max = vmax
        holding = (self.phase == _HOLD) & sig & self.nose_quiet & steady
        self.arrival = holding | (blob & (np.linalg.norm(peak - c, axis=1) < 0.5))
        return np.where(blob[:, None], peak, out)

    def _blob(self, c, pw, vw):
        """Not a plume: where no plume has been passed yet (searching, or a first pass) and the
        log-quadratic fit of all the window's readings has a confident maximum that is no more
        elongated than ``1 : blob_ratio`` (a plume's is 1 : 50 and more), that maximum (the
        ``model`` seeker's step): a smooth source such as the paper's sigma_2."""
        fit = fit_quadratic(pw, vw, vw > 0, c, log=True)
        lam = np.linalg.eigvalsh(fit.hessian)
        p = np.where(fit.concave[:, None], np.nan_to_num(fit.newton), 0.0)
        length = np.linalg.norm(p, axis=1)
        ok = fit.concave & (lam[:, -1] <= self.blob_ratio * lam[:, 0]) & (fit.used >= 16)
        ok &= fit.newton_std_m <= np.maximum(length, 0.5)
        ok &= (self.phase == _ACQUIRE) | (self.phase == _COARSE)
        return ok, c + p

    def _track(self, c, p, v, axis, up, sig) -> np.ndarray:
        """Best points, pass detection and the surge target (module doc, steps 4-5)."""
        along = np.einsum("kni,ki->kn", p - c[:, None, :], up)
        j = np.argmax(along, axis=1)
        rows = np.arange(self._k)
        nose_p, nose_v, nose_o = p[rows, j], v[rows, j], p[rows, j] - c
        nose_s = np.einsum("ki,ki->k", nose_p, up)
        off = nose_p - axis
        off = off - np.einsum("ki,ki->k", off, up)[:, None] * up
        coarse, fine = (self.phase == _COARSE) & sig, (self.phase == _FINE) & sig
        on_axis = (coarse | fine) & (np.linalg.norm(off, axis=1) <= self.on_axis_m)
        # first pass: the best of all readings; second pass: the best of the nose's on the axis
        i = np.argmax(v, axis=1)
        cand_v = np.where(coarse, v[rows, i], nose_v)
        cand_p = np.where(coarse[:, None], p[rows, i], nose_p - off)
        better = (coarse | (fine & on_axis)) & (cand_v > self.best_v)
        self.best_v = np.where(better, cand_v, self.best_v)
        self.best_s = np.where(better, np.einsum("ki,ki->k", cand_p, up), self.best_s)
        self.best_pos = np.where(better[:, None], cand_p, self.best_pos)
        known = np.isfinite(self.best_v)
        ref = np.where(known, self.best_s, self.coarse_s)
        low = on_axis & known & (nose_v < self.drop * self.best_v) & (nose_s > ref + self.pass_m)
        self.lows = np.where(low, self.lows + 1, np.where(coarse | fine, 0, self.lows))
        far = np.einsum("ki,ki->k", c, up) > ref + 3.0 * self.pass_m  # the whole formation well upwind of it
        passed = (coarse | fine) & ((self.lows >= self.quiet) | far)
        self.lows = np.where(passed, 0, self.lows)
        self.peak = np.maximum(self.peak, v.max(axis=1))
        weak = self.best_v < self.hold_fraction * self.peak  # not where the strongest readings were: search on
        to_fine, to_hold, again = passed & coarse, passed & fine & ~weak, passed & fine & weak
        self.coarse_s = np.where(to_fine, self.best_s, self.coarse_s)
        self.coarse_pos = np.where(to_fine[:, None], self.best_pos, self.coarse_pos)
        self.estimate = np.where(to_hold[:, None], np.where(known[:, None], self.best_pos, self.coarse_pos),
                                 self.estimate)
        self.nose_quiet = ~(nose_v > self.drop * v.max(axis=1))
        hits = (self.phase == _HOLD) & sig & ~self.nose_quiet
        self.nose_hits = np.where(hits, self.nose_hits + 1, self.nose_hits)
        stronger = (self.phase == _HOLD) & (self.hold_fraction * v.max(axis=1) > self.best_v)
        resume = (self.nose_hits >= 2) | stronger  # holding, but upwind or stronger readings: not the source
        self.nose_hits = np.where(resume | to_hold, 0, self.nose_hits)
        self.best_v = np.where(resume | again, -np.inf, self.best_v)
        self.phase = np.select([to_fine, to_hold, resume | again], [_FINE, _HOLD, _COARSE], self.phase)
        self.best_v = np.where(to_fine, -np.inf, self.best_v)
        step = np.where(self.phase == _FINE, self.probe_m, self.surge_m)
        s_next = np.where(to_fine, self.coarse_s - self.back_m, nose_s + step)
        s_axis = np.einsum("ki,ki->k", axis, up)
        return axis + (s_next - s_axis)[:, None] * up - nose_o  # the nose at the axis point s_next

    def _cast(self, c, up) -> np.ndarray:
        """Zig-zag across the wind about the anchor (module doc, step 6); next leg once reached."""
        e1 = np.cross(_Z, up)
        e1 /= np.maximum(np.linalg.norm(e1, axis=1, keepdims=True), 1e-12)
        width = np.minimum(self.cast_m * self.cast_growth ** (self.leg // 2), self.cast_max_m)
        side = np.where(self.leg % 2 == 0, 1.0, -1.0)
        vert = np.where((self.leg // 2) % 2 == 0, 0.5, -0.5)
        drift = np.where(self.detected, -1.0, 1.0) * self.cast_drift_m * (self.leg + 1)  # upwind until a first detection
        target = self.anchor + (side * width)[:, None] * e1 + (vert * width)[:, None] * _Z + drift[:, None] * up
        reached = (self.phase == _ACQUIRE) & (np.linalg.norm(target - c, axis=1) < 0.5)
        self.leg = np.where(reached, self.leg + 1, self.leg)
        return target
