"""The seeking step and the convergence test.

Seeking step (paper Sec. II): ``c(k+1) = c(k) + eps * g_hat`` with the move clipped to
``||c(k+1) - c(k)|| <= gamma`` (the direction is kept, the length capped).

Convergence criterion
---------------------
A source-seeking run never "arrives": without noise the centre creeps towards the estimator's
fixed point (geometric decay, or a small limit cycle when ``eps`` is at the edge of stability);
with noise it wanders about the source. Far from a Gaussian source it may also move very
slowly (``eps ||grad||`` << ``gamma``), so "small steps" alone would stop it far away.
The test therefore looks at the last ``window`` centres ``c_1..c_W`` (``W - 1`` steps of length
``s_j``) and declares convergence when

1. the *spread* (RMS distance of the centres to their mean) is ``<= tol_m``, and
2. the centre is not going anywhere, i.e. either

   a. the motion is *undirected*: the net progress is no larger than a random walk of the same
      steps would make, ``||c_W - c_1|| <= drift_factor * sqrt(sum s_j^2)`` (oscillation, or
      noise-driven wandering about a point; a drift of ``v`` per step hidden in per-component
      step noise ``s`` passes only when ``v`` is below about ``drift_factor * s * sqrt(3 / W)``), or
   b. the motion is *decaying* and short: the path over the window is ``<= tol_m`` and,
      fitting a geometric decay ``s_j ~ rho^j`` between the mean step of the first and of the
      last quarter of the window, the predicted remaining travel ``s_last * rho / (1 - rho)``
      is ``<= tol_m / 2`` (``rho >= 1`` never passes). The window mean is then within
      ``tol_m`` of the limit point.

A slow but steady drift (constant or growing steps, straight path) fails 2 whatever its speed.
The estimated source is the mean of the window's centres, reported with the spread.

3. **Signal** (optional, ``min_signal_fraction > 0``): at least that fraction of the window's
   iterations had a detection (:class:`estimator.seek_signal.SignalFloor`: a reading above the
   noise floor the readings themselves show). On a plume, standing still at the background
   (between the puffs of an intermittent plume, or beside a narrow plume) satisfies 1 and 2: the
   estimated gradient is noise and the centre hardly moves. Centres given without a signal (the
   start, a resumed seek's history) count as having one.

Limitation (physics, not code): where the true gradient is far below the noise of its
estimate, the centre performs a random walk that this test cannot tell from wandering about the
source; choose ``tol_m`` below that random walk's spread (about ``gamma * sqrt(W / 6)``) or
start where the gradient is measurable. With noise the estimate's error is set by the noise
(the wandering about the source, averaged over the window) and by the residual drift that 2a
cannot see.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from estimator.estimate import SourceEstimate, centres_estimate

__all__ = ["seek_step", "ConvergenceMonitor", "ConvergenceVerdict", "convergence_scan"]


def seek_step(centre, grad, eps: float, gamma: float) -> np.ndarray:
    """One gradient-ascent step of the formation centre, with a capped length.

    Parameters
    ----------
    centre : array_like, shape (..., 3)
        Current centre(s), metres.
    grad : array_like, shape (..., 3)
        Gradient estimate(s) at the centre(s).
    eps : float
        Step size (> 0), metres per (signal unit per metre).
    gamma : float
        Largest move per step (> 0), metres.

    Returns
    -------
    ndarray, shape (..., 3)
        ``centre + eps * grad`` with the move scaled down to length ``gamma`` if longer.

    Raises
    ------
    ValueError
        Non-positive or non-finite ``eps``/``gamma``, NaN/inf inputs, shapes not ending in 3.
    """
    if not (np.isfinite(eps) and eps > 0):
        raise ValueError(f"eps must be a positive finite number, got {eps!r}")
    if not (np.isfinite(gamma) and gamma > 0):
        raise ValueError(f"gamma must be a positive finite number, got {gamma!r}")
    c = np.asarray(centre, dtype=float)
    g = np.asarray(grad, dtype=float)
    if c.shape[-1:] != (3,) or g.shape[-1:] != (3,):
        raise ValueError(f"centre and grad must have shape (..., 3), got {c.shape} and {g.shape}")
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(g))):
        raise ValueError("centre and grad must be finite")
    move = eps * g
    length = np.linalg.norm(move, axis=-1, keepdims=True)
    over = length > gamma
    scale = np.where(over, gamma / np.where(over, length, 1.0), 1.0)
    return c + move * scale


@dataclass(frozen=True)
class ConvergenceVerdict:
    """Result of the convergence test over one window.

    Attributes
    ----------
    converged : bool
        The criterion of the module docstring holds.
    estimate_enu : ndarray, shape (3,)
        Mean of the window's centres (the estimated source position).
    spread_m : float
        RMS distance of the window's centres to their mean.
    net_m : float
        Distance between the window's first and last centres.
    path_m : float
        Length of the path over the window.
    walk_m : float
        ``sqrt(sum s_j^2)``: the net progress a random walk of the same steps would make.
    remaining_m : float
        Predicted remaining travel under geometric decay (``inf`` if not decaying).
    signal_fraction : float
        Fraction of the window's iterations with a detection (1.0 when no signal is given).
    """

    converged: bool
    estimate_enu: np.ndarray
    spread_m: float
    net_m: float
    path_m: float
    walk_m: float
    remaining_m: float
    signal_fraction: float = 1.0


def _check_params(window: int, tol_m: float, drift_factor: float, min_signal_fraction: float = 0.0) -> None:
    if not (np.isfinite(min_signal_fraction) and 0.0 <= min_signal_fraction <= 1.0):
        raise ValueError(f"min_signal_fraction must be in [0, 1], got {min_signal_fraction!r}")
    if int(window) != window or window < 8:
        raise ValueError(f"window must be an integer >= 8, got {window!r}")
    if not (np.isfinite(tol_m) and tol_m > 0):
        raise ValueError(f"tol_m must be a positive finite number, got {tol_m!r}")
    if not (np.isfinite(drift_factor) and drift_factor > 0):
        raise ValueError(f"drift_factor must be a positive finite number, got {drift_factor!r}")


def _sliding_stats(centres: np.ndarray, window: int):
    """Window statistics for every window end ``t >= window - 1``; ``centres`` (T, ..., 3)."""
    w = window
    q = w // 4
    origin = centres[:1]
    centres = centres - origin  # keeps the running sums small (no cancellation far away)
    csum = np.concatenate([np.zeros_like(centres[:1]), np.cumsum(centres, axis=0)])
    sq = np.sum(centres**2, axis=-1)
    sqsum = np.concatenate([np.zeros_like(sq[:1]), np.cumsum(sq, axis=0)])
    mean = (csum[w:] - csum[:-w]) / w
    msq = (sqsum[w:] - sqsum[:-w]) / w
    spread = np.sqrt(np.maximum(msq - np.sum(mean**2, axis=-1), 0.0))
    steps = np.linalg.norm(np.diff(centres, axis=0), axis=-1)  # steps[j] = |c[j+1] - c[j]|
    ssum = np.concatenate([np.zeros_like(steps[:1]), np.cumsum(steps, axis=0)])
    s2sum = np.concatenate([np.zeros_like(steps[:1]), np.cumsum(steps**2, axis=0)])
    n_win = centres.shape[0] - w + 1
    start = np.arange(n_win)  # window covers centres start..start+w-1, steps start..start+w-2
    path = ssum[start + w - 1] - ssum[start]
    walk = np.sqrt(np.maximum(s2sum[start + w - 1] - s2sum[start], 0.0))
    first_q = (ssum[start + q] - ssum[start]) / q
    last_q = (ssum[start + w - 1] - ssum[start + w - 1 - q]) / q
    net = np.linalg.norm(centres[start + w - 1] - centres[start], axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(first_q > 0, last_q / np.where(first_q > 0, first_q, 1.0), 0.0)
        rho = np.where(ratio < 1.0, np.power(np.clip(ratio, 0.0, 1.0), 1.0 / (w - 1 - q)), 1.0)
        remaining = np.where(rho < 1.0, last_q * rho / np.where(rho < 1.0, 1.0 - rho, 1.0), np.inf)
    remaining = np.where(path == 0.0, 0.0, remaining)
    return mean + origin, spread, net, path, walk, remaining


def _verdict_mask(spread, net, path, walk, remaining, tol_m, drift_factor):
    undirected = net <= drift_factor * walk
    decaying = (remaining <= 0.5 * tol_m) & (path <= tol_m)
    return (spread <= tol_m) & (undirected | decaying)


def convergence_scan(centres, window: int = 400, tol_m: float = 1.0, drift_factor: float = 0.5,
                     signal=None, min_signal_fraction: float = 0.0):
    """Apply the convergence test to whole trajectories (vectorised, same maths as the monitor).

    Parameters
    ----------
    centres : array_like, shape (T, ..., 3)
        Centres over iterations (axis 0), any number of trials after it.
    window, tol_m, drift_factor, min_signal_fraction
        As :class:`ConvergenceMonitor`.
    signal : array_like of bool, shape (T, ...), optional
        Whether the iteration that led to each centre had a detection (index 0, the start:
        True); None: every one (criterion 3 off).

    Returns
    -------
    first : ndarray of int, shape (...)
        Index of the first iteration (window end) at which the test passes, ``-1`` if never.
    estimate_enu : ndarray, shape (..., 3)
        Estimated source (window mean) at ``first``; NaN where never converged.
    spread_m : ndarray, shape (...)
        Spread at ``first``; NaN where never converged.
    """
    _check_params(window, tol_m, drift_factor, min_signal_fraction)
    c = np.asarray(centres, dtype=float)
    if c.ndim < 2 or c.shape[-1] != 3:
        raise ValueError(f"centres must have shape (T, ..., 3), got {c.shape}")
    lead = c.shape[1:-1]
    if c.shape[0] < window:
        return (np.full(lead, -1), np.full(lead + (3,), np.nan), np.full(lead, np.nan))
    mean, spread, net, path, walk, remaining = _sliding_stats(c, window)
    ok = _verdict_mask(spread, net, path, walk, remaining, tol_m, drift_factor)
    if signal is not None:
        sig = np.broadcast_to(np.asarray(signal, dtype=float), c.shape[:-1])
        csum = np.concatenate([np.zeros_like(sig[:1]), np.cumsum(sig, axis=0)])
        ok = ok & ((csum[window:] - csum[:-window]) / window >= min_signal_fraction - 1e-12)
    any_ok = ok.any(axis=0)
    idx = np.argmax(ok, axis=0)
    first = np.where(any_ok, idx + window - 1, -1)
    est = np.take_along_axis(mean, idx[None, ..., None], axis=0)[0]
    est = np.where(any_ok[..., None], est, np.nan)
    spr = np.take_along_axis(spread, idx[None], axis=0)[0]
    spr = np.where(any_ok, spr, np.nan)
    return first, est, spr


class ConvergenceMonitor:
    """Online convergence test on the formation centre (criterion in the module docstring).

    Parameters
    ----------
    window : int
        Number of most recent centres examined (>= 8).
    tol_m : float
        Spread and remaining-travel tolerance, metres.
    drift_factor : float
        The window counts as undirected when its net progress is <= this times the progress of
        a random walk made of the same steps.
    min_signal_fraction : float
        Criterion 3: at least this fraction of the window's iterations had a detection (0: off).

    Examples
    --------
    >>> mon = ConvergenceMonitor(window=20, tol_m=0.1)
    >>> for _ in range(25):
    ...     done = mon.update([1.0, 2.0, 3.0])
    >>> done, mon.estimate_enu.tolist()
    (True, [1.0, 2.0, 3.0])
    """

    def __init__(self, window: int = 400, tol_m: float = 1.0, drift_factor: float = 0.5,
                 min_signal_fraction: float = 0.0):
        _check_params(window, tol_m, drift_factor, min_signal_fraction)
        self.min_signal_fraction = float(min_signal_fraction)
        self._signals: deque[bool] = deque(maxlen=int(window))
        self.window = int(window)
        self.tol_m = float(tol_m)
        self.drift_factor = float(drift_factor)
        self._centres: deque[np.ndarray] = deque(maxlen=self.window)
        self._iterations = 0
        self._verdict: ConvergenceVerdict | None = None

    @property
    def iterations(self) -> int:
        """Number of centres seen since construction or :meth:`reset`."""
        return self._iterations

    def reset(self) -> None:
        """Forget every centre seen."""
        self._centres.clear()
        self._signals.clear()
        self._iterations = 0
        self._verdict = None

    def update(self, centre, signal: bool | None = None) -> bool:
        """Record the newest centre (and whether the iteration that led to it had a detection;
        None: counts as yes); return whether the run has converged.

        Raises
        ------
        ValueError
            ``centre`` not a finite 3-vector.
        """
        c = np.asarray(centre, dtype=float)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise ValueError(f"centre must be a finite 3-vector, got {centre!r}")
        self._centres.append(c.copy())
        self._signals.append(True if signal is None else bool(signal))
        self._iterations += 1
        if len(self._centres) < self.window:
            self._verdict = None
            return False
        arr = np.asarray(self._centres)[:, None, :]
        stats = [x[-1, 0] for x in _sliding_stats(arr, self.window)]
        mean, spread, net, path, walk, remaining = stats
        fraction = float(np.mean(self._signals))
        ok = bool(_verdict_mask(spread, net, path, walk, remaining, self.tol_m, self.drift_factor))
        ok = ok and fraction >= self.min_signal_fraction - 1e-12
        self._verdict = ConvergenceVerdict(
            ok, mean.copy(), float(spread), float(net), float(path), float(walk), float(remaining), fraction
        )
        return ok

    @property
    def verdict(self) -> ConvergenceVerdict | None:
        """Details of the last test (``None`` until ``window`` centres have been seen)."""
        return self._verdict

    @property
    def converged(self) -> bool:
        """Whether the last test passed."""
        return self._verdict is not None and self._verdict.converged

    @property
    def estimate_enu(self) -> np.ndarray:
        """Estimated source position: mean of the recent centres (up to ``window``)."""
        if not self._centres:
            raise ValueError("no centre recorded yet")
        return np.mean(np.asarray(self._centres), axis=0)

    @property
    def spread_m(self) -> float:
        """RMS distance of the recent centres to their mean."""
        if not self._centres:
            raise ValueError("no centre recorded yet")
        arr = np.asarray(self._centres)
        return float(np.sqrt(np.mean(np.sum((arr - arr.mean(axis=0)) ** 2, axis=-1))))

    def source_estimate(self) -> SourceEstimate | None:
        """The mean of the recent centres with the radius about it holding 95 % of them, labelled
        as not a confidence region (:func:`estimator.estimate.centres_estimate`); None before any centre."""
        if not self._centres:
            return None
        return centres_estimate(np.asarray(self._centres))
