"""Offline source seeking with sampling while moving (the mission's ``[seeking] sampling = "moving"``).

:func:`simulate_moving` flies ``K`` trials one after the other (the number of readings an
iteration differs between trials), each with its own seeker (:mod:`estimator.seekers`), on a
simple kinematic model of what :mod:`mission.flight.phases.seek_moving` does:

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
  ``gamma_m``, becomes the new ``c``. A seeker that takes reading times (``ste``,
  :func:`estimator.seekers.propose_readings`) gets each reading's time and vehicle too.

The first estimate is made at rest at the start from one reading per vehicle, as in the mission.
A time-dependent field (``field.time_dependent``: the intermittent plume) is read at the trial's
mission time plus ``trial * trial_time_offset_s`` (independent realisations per trial). A seeker
that sizes the formation (``formation_radius_m``: ``ste``) gets it: every vehicle then flies to its
own slot (the offsets scaled to that mean radius, directions kept) under the same speed limits, and
the formation's centre is the vehicles' mean less the slots' mean (with a constant radius every
vehicle makes the centre's move: the rigid formation above). The seekers' own estimates at the end
(``estimate_enu``, ``region95_m``, ``arrival``: a seeker with a posterior) are kept per trial.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimator.seekers import cap_move, make_seeker, propose_readings

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
    seekers : list, optional
        Each trial's seeker after the run (its own estimate, if it has one).
    """

    centres: np.ndarray
    formation_enu: np.ndarray
    times_s: np.ndarray
    readings: np.ndarray
    source_enu: np.ndarray
    seekers: list | None = None

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
    """One trial's kinematic state (each vehicle's position ``p`` (N, 3) and its slot offsets)
    and its reading history (positions per sample tick)."""

    p: np.ndarray
    slots: np.ndarray
    t_s: float
    hist_t: list
    hist_x: list

    @property
    def x(self) -> np.ndarray:
        """The formation's centre: the vehicles' mean less the slots' mean."""
        return self.p.mean(axis=0) - self.slots.mean(axis=0)


def _fly(trial: _Trial, goal: np.ndarray, dt_s: float, speed_m_s: float, vz_m_s: float) -> None:
    """Advance every vehicle towards its slot about ``goal`` for ``dt_s`` under the ramp's speed limits."""
    d = goal + trial.slots - trial.p
    h = np.hypot(d[:, 0], d[:, 1])
    with np.errstate(divide="ignore"):
        scale = np.minimum(1.0, np.minimum(np.where(h > 0, speed_m_s * dt_s / h, 1.0),
                                           np.where(d[:, 2] != 0, vz_m_s * dt_s / np.abs(d[:, 2]), 1.0)))
    trial.p = trial.p + d * scale[:, None]
    trial.t_s += dt_s


def simulate_moving(offsets, field, start, seeker, *, gamma_m: float, iterations: int,
                    noise_std: float = 0.0, rotate: bool = True, seed: int = 0, speed_m_s: float = 3.0,
                    vertical_speed_m_s: float = 1.0, sensor_rate_hz: float = 10.0, rate_hz: float = 2.0,
                    replan_fraction: float = 0.5, arrival_tol_m: float = 0.35, sensor_tau_s: float = 0.0,
                    sensor_lag_s: float = 0.0, trial_time_offset_s: float = 1.0e4) -> MovingRun:
    """Run ``K = len(start)`` trials of a seeker sampling while moving (module docstring); returns
    a :class:`MovingRun`.

    ``seeker`` is a name of :data:`estimator.seekers.SEEKERS` other than ``gradient`` (built with
    its defaults), or a callable of no argument returning a new seeker (one per trial).

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
    build = seeker if callable(seeker) else (lambda: make_seeker(seeker))
    rng = np.random.default_rng(seed)
    k = c0.shape[0]
    off = np.asarray(offsets, dtype=float)
    trial_off = _rotated(off, k, rng) if rotate else np.broadcast_to(off, (k,) + off.shape).copy()
    shape = (int(iterations) + 1, k)
    out = {"c": np.empty(shape + (3,)), "x": np.empty(shape + (3,)), "t": np.empty(shape),
           "m": np.zeros((int(iterations), k), dtype=int), "seekers": []}
    params = dict(gamma_m=gamma_m, noise_std=noise_std, speed_m_s=speed_m_s, vz_m_s=vertical_speed_m_s,
                  dt_s=1.0 / sensor_rate_hz, period_s=1.0 / rate_hz, fraction=replan_fraction,
                  arrival_tol_m=arrival_tol_m, tau_s=sensor_tau_s, lag_s=sensor_lag_s)
    for j in range(k):
        t0_s = j * float(trial_time_offset_s) if getattr(field, "time_dependent", False) else None
        out["seekers"].append(_one_trial(build(), field, c0[j], trial_off[j], rng, out, j, params, t0_s))
    return MovingRun(out["c"], out["x"], out["t"], out["m"], np.asarray(field.source_enu(), dtype=float),
                     out["seekers"])


def _one_trial(seeker, field, c0, offsets, rng, out: dict, j: int, p: dict, t0_s: float | None = None):
    """Fly trial ``j`` (module docstring) into ``out``; returns the seeker. ``t0_s``: the field's
    time at the trial's start (None: a static field, read without a time)."""
    from sitl_mock.sensor_response import FirstOrderLag

    lags = [FirstOrderLag(p["tau_s"]) for _ in range(len(offsets))]
    trial = _Trial(p=c0 + offsets, slots=offsets, t_s=0.0, hist_t=[], hist_x=[])
    c = c0.copy()
    seeker.reset()

    def read():
        pos = trial.p
        vals = field.value(pos) if t0_s is None else field.value(pos, t0_s + trial.t_s)
        if p["noise_std"]:
            vals = vals + rng.standard_normal(len(pos)) * p["noise_std"]
        vals = np.array([lag(trial.t_s, float(v)) for lag, v in zip(lags, vals)])
        trial.hist_t.append(trial.t_s)
        trial.hist_x.append(trial.p.copy())
        return vals

    vals = [read()]
    for it in range(out["t"].shape[0]):
        out["c"][it, j], out["x"][it, j], out["t"][it, j] = c, trial.x, trial.t_s
        if it == out["t"].shape[0] - 1:
            break
        placed = _placed(trial, len(vals), p["lag_s"])
        values = np.concatenate(vals)
        out["m"][it, j] = len(values)
        times = np.repeat(np.asarray(trial.hist_t[-len(vals):]), len(offsets))  # (ticks * N,), as ``placed``
        sensors = np.tile(np.arange(len(offsets)), len(vals))
        c = cap_move(c[None], propose_readings(seeker, c[None], placed[None], values[None], times[None],
                                               sensors[None]), p["gamma_m"])[0]
        radius = getattr(seeker, "formation_radius_m", None)
        if radius is not None:
            trial.slots = _scaled_slots(offsets, float(np.asarray(radius).ravel()[0]))
        last_est = trial.t_s
        start_gap = float(np.max(np.linalg.norm(c + trial.slots - trial.p, axis=1)))
        left = max((1.0 - p["fraction"]) * start_gap, p["arrival_tol_m"])
        vals = []
        while (not vals or float(np.max(np.linalg.norm(c + trial.slots - trial.p, axis=1))) > left
               or trial.t_s - last_est < p["period_s"] - 1e-9):
            _fly(trial, c, p["dt_s"], p["speed_m_s"], p["vz_m_s"])
            vals.append(read())
    return seeker


def _scaled_slots(offsets: np.ndarray, radius_m: float) -> np.ndarray:
    """``offsets`` (N, 3) scaled so that their mean distance from the centre is ``radius_m``."""
    base = float(np.linalg.norm(offsets, axis=1).mean())
    return offsets * (radius_m / base if base > 0 else 1.0)


def _placed(trial: _Trial, ticks: int, lag_s: float) -> np.ndarray:
    """Positions ``(ticks * N, 3)`` the seeker gets for the last ``ticks`` sample ticks: where they
    were taken, or where each vehicle was ``lag_s`` before."""
    t = np.asarray(trial.hist_t[-ticks:])
    hx = np.asarray(trial.hist_x)  # (ticks so far, N, 3)
    if lag_s <= 0:
        return hx[-ticks:].reshape(-1, 3)
    all_t = np.asarray(trial.hist_t)
    x = np.stack([np.stack([np.interp(t - lag_s, all_t, hx[:, n, i]) for i in range(3)], axis=-1)
                  for n in range(hx.shape[1])], axis=1)
    return x.reshape(-1, 3)
