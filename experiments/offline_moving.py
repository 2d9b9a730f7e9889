"""Offline source seeking with sampling while moving (the mission's ``[seeking] sampling = "moving"``).

:func:`simulate_moving` flies ``K`` trials one after the other (the number of readings an
iteration differs between trials), each with its own seeker (:mod:`estimator.seekers`), on a
simple kinematic model of what :mod:`mission.flight.seek_moving` does:

* the formation is rigid and its centre ``x`` follows the ramp exactly: towards the commanded
  centre ``c`` at most ``speed_m_s`` horizontally and ``vertical_speed_m_s`` vertically (no
  acceleration, no tracking lag, so it is faster than the mission);
* every vehicle reads the field at ``x + offset_i`` every ``1 / sensor_rate_hz`` s, with Gaussian
  noise, optionally through a first-order lag of time constant ``sensor_tau_s``
  (:class:`sitl_mock.sensor_response.FirstOrderLag`);
* the next estimate is made once ``x`` has covered ``replan_fraction`` of its distance to ``c``
  (or is within ``arrival_tol_m`` of it) and at least ``1 / rate_hz`` after the last one; the
  seeker gets every reading since the last estimate, at the positions where they were taken (or,
  with ``sensor_lag_s``, where the vehicle was that long before), and its proposal, capped at
  ``gamma_m``, becomes the new ``c``.

The first estimate is made at rest at the start from one reading per vehicle, as in the mission.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimator.seekers import cap_move, make_seeker

__all__ = ["MovingRun", "simulate_moving"]


@dataclass(frozen=True)
class MovingRun:
    """A batch of offline runs sampling while moving.

    Attributes
    ----------
    centres : ndarray, shape (T + 1, K, 3)
        Commanded centre before each iteration and after the last.
    formation_enu : ndarray, shape (T + 1, K, 3)
        The formation's (actual) centre at each estimate, and at the end.
    times_s : ndarray, shape (T + 1, K)
        Mission time of each estimate (0 for the first), and of the end.
    readings : ndarray of int, shape (T, K)
        Readings the seeker got at each estimate.
    source_enu : ndarray, shape (3,)
    """

    centres: np.ndarray
    formation_enu: np.ndarray
    times_s: np.ndarray
    readings: np.ndarray
    source_enu: np.ndarray

    def time_within_s(self, tol_m: float = 1.0) -> np.ndarray:
        """Per trial: the first estimate time from which on the formation stays within ``tol_m``
        of the source (NaN if it does not)."""
        far = np.linalg.norm(self.formation_enu - self.source_enu, axis=-1) > tol_m  # (T + 1, K)
        out = np.full(far.shape[1], np.nan)
        for k in range(far.shape[1]):
            idx = np.flatnonzero(far[:, k])
            first = 0 if idx.size == 0 else int(idx[-1]) + 1
            if first < far.shape[0]:
                out[k] = self.times_s[first, k]
        return out


@dataclass
class _Trial:
    """One trial's kinematic state and its reading history (positions per sample tick)."""

    x: np.ndarray
    t_s: float
    hist_t: list
    hist_x: list


def _fly(trial: _Trial, goal: np.ndarray, dt_s: float, speed_m_s: float, vz_m_s: float) -> None:
    """Advance ``trial.x`` towards ``goal`` for ``dt_s`` under the ramp's speed limits."""
    d = goal - trial.x
    h = float(np.hypot(d[0], d[1]))
    scale = min(1.0, speed_m_s * dt_s / h if h > 0 else 1.0, vz_m_s * dt_s / abs(d[2]) if d[2] else 1.0)
    trial.x = trial.x + d * scale
    trial.t_s += dt_s


def simulate_moving(offsets, field, start, seeker: str, *, gamma_m: float, iterations: int,
                    noise_std: float = 0.0, rotate: bool = True, seed: int = 0, speed_m_s: float = 3.0,
                    vertical_speed_m_s: float = 1.0, sensor_rate_hz: float = 10.0, rate_hz: float = 2.0,
                    replan_fraction: float = 0.5, arrival_tol_m: float = 0.35, sensor_tau_s: float = 0.0,
                    sensor_lag_s: float = 0.0) -> MovingRun:
    """Run ``K = len(start)`` trials of the ``seeker`` (a name of :data:`estimator.seekers.SEEKERS`
    other than ``gradient``) sampling while moving (module docstring); returns a :class:`MovingRun`.

    Raises
    ------
    ValueError
        A bad shape or parameter, or the ``gradient`` seeker (it samples stop and go).
    """
    from experiments.offline_seek import _rotated

    c0 = np.asarray(start, dtype=float)
    if c0.ndim != 2 or c0.shape[1] != 3:
        raise ValueError(f"start must have shape (K, 3), got {c0.shape}")
    if seeker == "gradient":
        raise ValueError("sampling while moving needs the newton or model seeker (the gradient seeker samples "
                         "stop and go)")
    if not (gamma_m > 0 and int(iterations) >= 1 and noise_std >= 0 and 0 < replan_fraction <= 1
            and speed_m_s > 0 and vertical_speed_m_s > 0 and sensor_rate_hz > 0 and rate_hz > 0
            and sensor_tau_s >= 0 and sensor_lag_s >= 0):
        raise ValueError("need gamma_m, speeds and rates > 0, iterations >= 1, noise_std, sensor_tau_s and "
                         "sensor_lag_s >= 0, 0 < replan_fraction <= 1")
    rng = np.random.default_rng(seed)
    k = c0.shape[0]
    off = np.asarray(offsets, dtype=float)
    trial_off = _rotated(off, k, rng) if rotate else np.broadcast_to(off, (k,) + off.shape).copy()
    shape = (int(iterations) + 1, k)
    out = {"c": np.empty(shape + (3,)), "x": np.empty(shape + (3,)), "t": np.empty(shape),
           "m": np.zeros((int(iterations), k), dtype=int)}
    params = dict(gamma_m=gamma_m, noise_std=noise_std, speed_m_s=speed_m_s, vz_m_s=vertical_speed_m_s,
                  dt_s=1.0 / sensor_rate_hz, period_s=1.0 / rate_hz, fraction=replan_fraction,
                  arrival_tol_m=arrival_tol_m, tau_s=sensor_tau_s, lag_s=sensor_lag_s)
    for j in range(k):
        _one_trial(make_seeker(seeker), field, c0[j], trial_off[j], rng, out, j, params)
    return MovingRun(out["c"], out["x"], out["t"], out["m"], np.asarray(field.source_enu(), dtype=float))


def _one_trial(seeker, field, c0, offsets, rng, out: dict, j: int, p: dict) -> None:
    """Fly trial ``j`` (module docstring) into ``out``."""
    from sitl_mock.sensor_response import FirstOrderLag

    lags = [FirstOrderLag(p["tau_s"]) for _ in range(len(offsets))]
    trial = _Trial(x=c0.copy(), t_s=0.0, hist_t=[], hist_x=[])
    c = c0.copy()
    last_est = 0.0

    def read():
        pos = trial.x + offsets
        vals = field.value(pos) + (rng.standard_normal(len(pos)) * p["noise_std"] if p["noise_std"] else 0.0)
        vals = np.array([lag(trial.t_s, float(v)) for lag, v in zip(lags, vals)])
        trial.hist_t.append(trial.t_s)
        trial.hist_x.append(trial.x.copy())
        return vals

    pos, vals = [trial.x + offsets], [read()]
    for it in range(out["t"].shape[0]):
        out["c"][it, j], out["x"][it, j], out["t"][it, j] = c, trial.x, trial.t_s
        if it == out["t"].shape[0] - 1:
            break
        placed = _placed(trial, len(pos), offsets, p["lag_s"])
        values = np.concatenate(vals)
        out["m"][it, j] = len(values)
        c = cap_move(c[None], seeker.propose(c[None], placed[None], values[None]), p["gamma_m"])[0]
        last_est = trial.t_s
        start_gap = float(np.linalg.norm(c - trial.x))
        left = max((1.0 - p["fraction"]) * start_gap, p["arrival_tol_m"])
        pos, vals = [], []
        while not pos or float(np.linalg.norm(trial.x - c)) > left or trial.t_s - last_est < p["period_s"] - 1e-9:
            _fly(trial, c, p["dt_s"], p["speed_m_s"], p["vz_m_s"])
            pos.append(trial.x + offsets)
            vals.append(read())


def _placed(trial: _Trial, ticks: int, offsets, lag_s: float) -> np.ndarray:
    """Positions ``(ticks * N, 3)`` the seeker gets for the last ``ticks`` sample ticks: where they
    were taken, or where the formation was ``lag_s`` before."""
    t = np.asarray(trial.hist_t[-ticks:])
    hx = np.asarray(trial.hist_x)
    x = hx[-ticks:] if lag_s <= 0 else np.stack(
        [np.interp(t - lag_s, np.asarray(trial.hist_t), hx[:, i]) for i in range(3)], axis=-1)
    return (x[:, None, :] + offsets[None]).reshape(-1, 3)
