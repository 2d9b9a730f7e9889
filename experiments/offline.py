"""Vectorised offline source-seeking simulation (perfect tracking, no MAVLink, no zenoh).

Many independent trials run at once as numpy arrays: every iteration, each trial's robots sit
exactly at ``centre + offset_i`` (perfect tracking), read the field with optional Gaussian noise
(one standard deviation per robot), the centre estimates the gradient with
:func:`estimator.gradient_batch` and moves with :func:`estimator.seek_step`.

Any field of :mod:`sitl_mock.fields_config` (or its name, ``make_field(name)``): a time-dependent one
(``field.time_dependent``, the intermittent plume) is read at ``t = k * iteration_period_s +
j * trial_time_offset_s`` in iteration ``k`` of trial ``j`` (trials far apart in time see
independent plume realisations).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from estimator import DEFAULT_MAX_CONDITION, ConvergenceMonitor, convergence_scan, estimator_weights, gradient_batch, seek_step

__all__ = ["OfflineResult", "simulate", "convergence_report", "SIGMA_C_MODES"]

#: How the estimator gets the field at the centre: not measured (``"mean"``: least squares with an
#: intercept, the centred moment matrix), the exact value (as in Theorem 2's statement; a
#: simulation-only oracle), or the paper's Remark exactly as printed (``"remark"``: the mean of
#: the readings with the uncentred ``M``; what ``swarmseek paper`` uses to reproduce the paper).
SIGMA_C_MODES = ("mean", "exact", "remark")
_NOISE_BLOCK = 256


@dataclass(frozen=True)
class OfflineResult:
    """Everything a batch of offline runs produced.

    Attributes
    ----------
    centres : ndarray, shape (T + 1, K, 3)
        Formation centre of each trial before each iteration and after the last one.
    grad_est : ndarray, shape (T, K, 3)
        Gradient estimate used at each iteration.
    grad_true : ndarray, shape (T, K, 3)
        Exact field gradient at the centre at each iteration.
    readings : ndarray, shape (T, K, N)
        Readings (with noise) of each robot at each iteration.
    offsets : ndarray, shape (K, N, 3)
        Each trial's formation offsets (after its rotation).
    source_enu : ndarray, shape (3,)
        The field's source.
    """

    centres: np.ndarray
    grad_est: np.ndarray
    grad_true: np.ndarray
    readings: np.ndarray
    offsets: np.ndarray
    source_enu: np.ndarray

    def distance_to_source_m(self) -> np.ndarray:
        """``||c - r*||`` per iteration and trial, shape (T + 1, K)."""
        return np.linalg.norm(self.centres - self.source_enu, axis=-1)

    def error_norm(self) -> np.ndarray:
        """``||g_hat - grad||`` per iteration and trial, shape (T, K)."""
        return np.linalg.norm(self.grad_est - self.grad_true, axis=-1)


def _trial_offsets(offsets: np.ndarray, trials: int, rotate: bool, rng) -> np.ndarray:
    if not rotate:
        return np.broadcast_to(offsets, (trials,) + offsets.shape).copy()
    rot = Rotation.random(trials, random_state=rng).as_matrix()  # (K, 3, 3)
    return np.einsum("kij,nj->kni", rot, offsets)


def _noise_std(noise_std, n: int, trials: int) -> np.ndarray:
    std = np.asarray(noise_std, dtype=float)
    if std.ndim == 0:
        std = np.full(n, float(std))
    if std.shape not in ((n,), (trials, n)):
        raise ValueError(
            f"noise_std must be a scalar or have shape ({n},) or ({trials}, {n}), got {std.shape}"
        )
    if not np.all(np.isfinite(std)) or np.any(std < 0):
        raise ValueError("noise_std must be finite and >= 0")
    return std


def simulate(
    offsets,
    field,
    start,
    *,
    eps: float = 1.0,
    gamma: float = 0.1,
    iterations: int = 1000,
    trials: int = 1,
    noise_std=0.0,
    method: str = "cvt",
    sigma_c: str = "mean",
    rotate: bool = False,
    seed: int = 0,
    max_condition: float = DEFAULT_MAX_CONDITION,
    iteration_period_s: float = 0.5,
    trial_time_offset_s: float = 1.0e4,
) -> OfflineResult:
    """Simulate ``trials`` independent source-seeking runs at once.

    Parameters
    ----------
    offsets : array_like, shape (N, 3)
        Formation offsets from the centre, metres (N >= 4), kept rigid during the run.
    field : Field or str
        Object with ``value(points)``, ``gradient(points)`` and ``source_enu()``
        (see :mod:`sitl_mock.fields_config`), or a field name for ``sitl_mock.fields_config.make_field``.
    start : array_like, shape (3,) or (K, 3)
        Initial centre (common or per trial), ENU metres.
    eps, gamma : float
        Seeking step size and largest move per iteration (metres).
    iterations : int
        Number of iterations ``T`` (>= 1).
    trials : int
        Number of trials ``K`` (>= 1).
    noise_std : float or array_like, shape (N,) or (K, N)
        Standard deviation of each robot's Gaussian reading noise (signal units), common to
        all trials or per trial.
    method : {"cvt", "symmetric"}
        Estimator (Theorem 2 or eq. (3)).
    sigma_c : {"mean", "exact", "remark"}
        Field value at the centre used by ``"cvt"``: not measured (``"mean"``: least squares
        with an intercept, the centred ``M_c``; see :mod:`estimator.gradient`) or exact
        (Theorem 2 with ``M``), or ``"remark"`` (the paper's Remark: uncentred ``M`` with the
        mean of the readings; exact only when the offsets sum to zero).
    rotate : bool
        Apply an independent uniformly random rotation to the formation of each trial.
    seed : int
        Seed of the noise and rotations (the result is deterministic for a seed).
    max_condition : float
        Passed to the estimator's geometry check.
    iteration_period_s, trial_time_offset_s : float
        Time-dependent fields only: simulated time per iteration and between trials.

    Returns
    -------
    OfflineResult

    Raises
    ------
    estimator.GeometryError
        The formation cannot support the estimator.
    ValueError
        Bad shapes or parameters.
    """
    off = np.asarray(offsets, dtype=float)
    if off.ndim != 2 or off.shape[1] != 3:
        raise ValueError(f"offsets must have shape (N, 3), got {off.shape}")
    if int(iterations) != iterations or iterations < 1:
        raise ValueError(f"iterations must be an integer >= 1, got {iterations!r}")
    if int(trials) != trials or trials < 1:
        raise ValueError(f"trials must be an integer >= 1, got {trials!r}")
    if sigma_c not in SIGMA_C_MODES:
        raise ValueError(f"sigma_c must be one of {SIGMA_C_MODES}, got {sigma_c!r}")
    if isinstance(field, str):
        from sitl_mock.fields_config import make_field

        field = make_field(field)
    timed = bool(getattr(field, "time_dependent", False))
    trial_t = np.arange(int(trials))[:, None] * float(trial_time_offset_s)
    n = off.shape[0]
    std = _noise_std(noise_std, n, int(trials))
    c0 = np.asarray(start, dtype=float)
    if c0.shape not in ((3,), (trials, 3)) or not np.all(np.isfinite(c0)):
        raise ValueError(f"start must be a finite (3,) or ({trials}, 3) array, got shape {c0.shape}")
    rng = np.random.default_rng(seed)
    trial_off = _trial_offsets(off, trials, rotate, rng)
    weights = estimator_weights(trial_off, method, max_condition, centred=sigma_c == "mean")
    if sigma_c == "remark":
        sigma_c = "mean"  # the uncentred weights with s_c = the mean of the readings
    noisy = bool(np.any(std > 0))
    t_count, k_count = int(iterations), int(trials)
    centres = np.empty((t_count + 1, k_count, 3))
    grad_est = np.empty((t_count, k_count, 3))
    grad_true = np.empty((t_count, k_count, 3))
    readings = np.empty((t_count, k_count, n))
    centres[0] = c0
    noise = None
    for k in range(t_count):
        if noisy and k % _NOISE_BLOCK == 0:  # draw the noise in blocks: fewer calls, bounded memory
            noise = rng.standard_normal((min(_NOISE_BLOCK, t_count - k), k_count, n)) * std
        c = centres[k]
        points = c[:, None, :] + trial_off
        vals = field.value(points, k * iteration_period_s + trial_t) if timed else field.value(points)
        if noisy:
            vals = vals + noise[k % _NOISE_BLOCK]
        readings[k] = vals
        sc = field.value(c) if sigma_c == "exact" else None
        g = gradient_batch(None, vals, method, sigma_c=sc, weights=weights)
        grad_est[k] = g
        centres[k + 1] = seek_step(c, g, eps, gamma)
    grad_true[:] = field.gradient(centres[:-1])
    return OfflineResult(centres, grad_est, grad_true, readings, trial_off, field.source_enu())


def convergence_report(result: OfflineResult, *, window: int, tol_m: float, trial: int = 0,
                       stop_at_convergence: bool = False, min_signal_fraction: float = 0.0) -> dict:
    """One trial judged by the mission's convergence test, with every distance named.

    A mission stops at the first iteration where :func:`estimator.convergence_scan` (the
    :class:`estimator.ConvergenceMonitor` maths) passes and reports the mean of the window's
    centres; the simulation may go on. The two places are reported separately, each with its
    distance to the true source, so that "converged" means what a mission means by it.

    Parameters
    ----------
    result : OfflineResult
    window, tol_m : int, float
        The convergence test's window (iterations) and tolerance (metres).
    trial : int
        Which trial of ``result``.
    stop_at_convergence : bool
        Treat the run as ended where the test first passes (as a mission does).
    min_signal_fraction : float
        The test's criterion 3 on ``result.signal`` (a seeker's run has it, as the mission
        computes it; a run without it is judged on the centres alone).

    Returns
    -------
    dict
        ``converged``, ``converged_at_iteration``, ``estimated_source_enu``, ``estimate_error_m``,
        ``estimate_spread_m``, ``centre_at_convergence_enu``, ``centre_at_convergence_distance_m``
        (None when never converged); ``final_iteration``, ``final_centre_enu``,
        ``final_distance_m``, ``final_gradient_error`` (None for a seeker without a gradient
        estimate), ``stopped_at_convergence``, ``distance_flown_m`` (the centre's path to the
        end); the test over the run's last window: ``converged_at_end``, ``final_window_estimate_enu``,
        ``final_window_error_m`` (None when the run is shorter than the window); and, when never
        converged, ``last_window``: why the test fails there (``spread_m``, ``net_m``, ``walk_m``,
        ``path_m``, ``signal_fraction``, ``max_distance_m`` to the source; None when the run is
        shorter than the window).
    """
    centres = result.centres[:, trial]
    source = result.source_enu
    sig = getattr(result, "signal", None)
    sig = None if sig is None else np.asarray(sig)[:, trial, None]
    first, est, spread = convergence_scan(centres[:, None, :], window=window, tol_m=tol_m, signal=sig,
                                          min_signal_fraction=min_signal_fraction)
    k_window = int(first[0])
    by, k, est_k, spread_k = _declared(result, trial, k_window, est[0], float(spread[0]), tol_m, sig,
                                       min_signal_fraction)
    converged = k >= 0
    end = k if converged and stop_at_convergence else centres.shape[0] - 1
    out = {
        "converged": converged,
        "converged_at_iteration": k if converged else None,
        "converged_by": by,
        "window_converged_at_iteration": k_window if k_window >= 0 else None,
        "estimated_source_enu": est_k.tolist() if converged else None,
        "estimate_error_m": float(np.linalg.norm(est_k - source)) if converged else None,
        "estimate_spread_m": spread_k if converged else None,
        **_seeker_estimate(result, trial, k if converged else None, source),
        "centre_at_convergence_enu": centres[k].tolist() if converged else None,
        "centre_at_convergence_distance_m": float(np.linalg.norm(centres[k] - source)) if converged else None,
        "stopped_at_convergence": bool(converged and stop_at_convergence),
        "final_iteration": end,
        "final_centre_enu": centres[end].tolist(),
        "final_distance_m": float(np.linalg.norm(centres[end] - source)),
        "final_gradient_error": _finite_or_none(result.error_norm()[min(end, result.grad_est.shape[0] - 1), trial]),
        "distance_flown_m": float(np.linalg.norm(np.diff(centres[:end + 1], axis=0), axis=-1).sum()),
    }
    last = centres[max(0, end + 1 - window):end + 1]
    if last.shape[0] >= window:
        sig_end = None if sig is None else sig[max(0, end + 1 - window):end + 1]
        ok_end, est_end, _ = convergence_scan(last[:, None, :], window=window, tol_m=tol_m, signal=sig_end,
                                              min_signal_fraction=min_signal_fraction)
        mean = last.mean(axis=0)
        out.update(converged_at_end=bool(ok_end[0] >= 0), final_window_estimate_enu=mean.tolist(),
                   final_window_error_m=float(np.linalg.norm(mean - source)))
    else:
        out.update(converged_at_end=None, final_window_estimate_enu=None, final_window_error_m=None)
    out["last_window"] = None if converged else _last_window(centres[:end + 1], sig, source, window, tol_m,
                                                             min_signal_fraction)
    return out


def _declared(result, trial: int, k_window: int, est_window, spread_window: float, tol_m: float, sig,
              min_signal_fraction: float):
    """Which test ends the run first: ``(by, iteration, estimate, spread)``. The window test
    (``by = "window"``: the window's mean and spread), or the region rule of
    :mod:`estimator.seek_confirm` on the seeker's own estimates (``"region"``: that estimate, no
    spread) when ``result`` has them and it passes earlier; ``(None, -1, NaN, NaN)`` when neither."""
    from estimator.seek_confirm import region_scan

    estimates = getattr(result, "estimates_enu", None)
    k_region = -1
    if estimates is not None:
        use_sig = None if sig is None or min_signal_fraction <= 0 else sig
        k_region = int(region_scan(result.centres[:, trial, None], result.formation_centres[:, trial, None],
                                   estimates[:, trial, None], result.regions_m[:, trial, None], use_sig,
                                   tol_m=tol_m)[0])
    if k_region >= 0 and (k_window < 0 or k_region < k_window):
        return "region", k_region, np.asarray(estimates[k_region, trial], dtype=float), None
    if k_window >= 0:
        return "window", k_window, np.asarray(est_window, dtype=float), spread_window
    return None, -1, np.full(3, np.nan), None


def _seeker_estimate(result, trial: int, k: int | None, source) -> dict:
    """The seeker's own estimate after iteration ``k`` (None: not converged), its distance to the
    source and the radius of its 95 % region (what a mission reports; ``seeker_region95_m`` None
    where it was not computed: larger than the rule's tolerance, or the formation away from the
    estimate); all None for a seeker without estimates of its own (the paper's gradient: the
    window's spread is its uncertainty)."""
    estimates = getattr(result, "estimates_enu", None)
    if k is None or estimates is None or not np.all(np.isfinite(estimates[k, trial])):
        return {"seeker_estimate_error_m": None, "seeker_estimate_enu": None, "seeker_region95_m": None}
    est = np.asarray(estimates[k, trial], dtype=float)
    region = float(result.regions_m[k, trial])
    return {"seeker_estimate_error_m": float(np.linalg.norm(est - source)), "seeker_estimate_enu": est.tolist(),
            "seeker_region95_m": region if np.isfinite(region) else None}


def _finite_or_none(value) -> float | None:
    """``value`` as a float, None when NaN (a seeker without a gradient estimate)."""
    v = float(value)
    return v if np.isfinite(v) else None


def _last_window(centres, sig, source, window: int, tol_m: float, min_signal_fraction: float) -> dict | None:
    """Why the convergence test does not pass at the run's end: the test over the last window
    (:class:`estimator.ConvergenceMonitor`'s verdict), with the window's largest distance to the
    source; None when the run is shorter than the window."""
    if centres.shape[0] < window:
        return None
    monitor = ConvergenceMonitor(window=window, tol_m=tol_m, min_signal_fraction=min_signal_fraction)
    last = centres[-window:]
    signals = [None] * window if sig is None else [bool(x) for x in sig[-window:, 0]]
    for c, s in zip(last, signals):
        monitor.update(c, s)
    v = monitor.verdict
    return {"spread_m": v.spread_m, "net_m": v.net_m, "walk_m": v.walk_m, "path_m": v.path_m,
            "signal_fraction": v.signal_fraction,
            "max_distance_m": float(np.linalg.norm(last - source, axis=-1).max())}
