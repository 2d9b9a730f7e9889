"""Offline source seeking with any seeker, and the mission's stop-and-go time model.

:func:`simulate_seeker` runs ``K`` independent trials at once (perfect tracking: each robot
reads exactly at ``centre + offset_i``, with Gaussian noise), the seeker proposing each next
centre (:mod:`estimator.seekers`) and the cap ``gamma_m`` applied outside it, as the mission
does. A seeker with a ``formation_radius_m`` attribute (``(K,)`` after each ``propose``; the
``ste`` seeker) sizes the formation: the next readings are taken with the offsets scaled to that
mean radius (their directions kept), and the iteration's time is the longest vehicle flight to
its new slot; every other seeker keeps the given offsets. :class:`StopAndGo` turns each
iteration's moves into mission time.

The time model (what ``mission.flight.phases.seek`` does per iteration): the ramp moves every setpoint
to its slot about the new centre at ``max_speed_m_s`` horizontally and at most
``max_vertical_speed_m_s`` vertically (``mission.flight.targets``), so the move takes
``max(|m| / v, |m_z| / v_z)``; then the vehicles settle to within ``arrival_tol_m`` and a reading
taken after the arrival comes in (``settle_s`` plus ``lag_s_per_m`` per metre of move: a longer
move ends at a higher speed, so the tracking lag to catch up is longer); iterations are at least
``1 / rate_hz`` apart. The constants were read off the iteration records of lock-step missions
of the default plan (moves of 0-10 m: 0.5 s for no move, 1.6 s for 1 m, 3.2-3.4 s for 5 m, 5.0 s
for 10 m); ``benchmarks/bench_seek_mission.py`` prints the model's time beside each mission's
measured one (``docs/seekers.md`` has the check).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from estimator.seek_signal import ArrivalSignal
from estimator.seekers import cap_move

__all__ = ["StopAndGo", "SeekRun", "simulate_seeker"]


@dataclass(frozen=True)
class StopAndGo:
    """Mission time of one seek iteration from its centre move (module docstring).

    Attributes
    ----------
    max_speed_m_s, max_vertical_speed_m_s : float
        The ramp's speed limits (plan ``max_speed_m_s``; vertical 1 m/s).
    settle_s : float
        Settling within ``arrival_tol_m`` and the first reading after arrival, for a zero move.
    lag_s_per_m : float
        Extra settling per metre of move.
    max_settle_s : float
        Cap of the per-metre settling term (the vehicles reach their cruise speed).
    far_s_per_m : float
        Settling per metre beyond that (a longer move leaves the formation a little more spread).
    rate_hz : float
        Plan ``rate_hz``: estimates at least ``1 / rate_hz`` apart.
    """

    max_speed_m_s: float = 3.0
    max_vertical_speed_m_s: float = 1.0
    settle_s: float = 0.45
    lag_s_per_m: float = 0.8
    max_settle_s: float = 1.25
    far_s_per_m: float = 0.04
    rate_hz: float = 2.0

    def iteration_s(self, move_m) -> np.ndarray:
        """Time of iterations whose centre moves are ``move_m`` (..., 3)."""
        m = np.asarray(move_m, dtype=float)
        length = np.linalg.norm(m, axis=-1)
        fly = np.maximum(length / self.max_speed_m_s, np.abs(m[..., 2]) / self.max_vertical_speed_m_s)
        settle = np.minimum(self.settle_s + self.lag_s_per_m * length, self.max_settle_s) + self.far_s_per_m * length
        return np.maximum(fly + settle, 1.0 / self.rate_hz)


@dataclass(frozen=True)
class SeekRun:
    """A batch of offline seeking runs.

    Attributes
    ----------
    centres : ndarray, shape (T + 1, K, 3)
        Commanded centre before each iteration and after the last.
    offsets : ndarray, shape (K, N, 3)
        Each trial's formation offsets.
    source_enu : ndarray, shape (3,)
    signal : ndarray of bool, shape (T + 1, K)
        The convergence test's signal for the iteration that led to each centre, as the mission
        computes it: the seeker's own ``arrival`` if it has one, else
        :class:`estimator.seek_signal.ArrivalSignal` on the noisy readings (index 0, the start: True).
    radii_m : ndarray, shape (T + 1, K), optional
        The formation's radius about each centre when the seeker sets it (``formation_radius_m``);
        None: ``offsets`` throughout.
    estimates_enu : ndarray, shape (T + 1, K, 3), optional
        The seeker's own estimate of the source after the iteration that led to each centre
        (``source_estimate``; NaN where it has none, and at index 0); None: a seeker without one.
    regions_m : ndarray, shape (T + 1, K), optional
        Its 95 % region's radius (NaN where none or not recorded; ``inf`` where not computed: the
        formation farther from the estimate than :func:`simulate_seeker`'s ``own_estimates``).
    formation_centres : ndarray, shape (T + 1, K, 3), optional
        The centroid of where the readings of the iteration that led to each centre were taken.
    """

    centres: np.ndarray
    offsets: np.ndarray
    source_enu: np.ndarray
    signal: np.ndarray | None = None
    radii_m: np.ndarray | None = None
    estimates_enu: np.ndarray | None = None
    regions_m: np.ndarray | None = None
    formation_centres: np.ndarray | None = None

    def distance_m(self) -> np.ndarray:
        """Distance of the centre to the source, (T + 1, K)."""
        return np.linalg.norm(self.centres - self.source_enu, axis=-1)

    def moves(self) -> np.ndarray:
        """Centre moves per iteration, (T, K, 3)."""
        return np.diff(self.centres, axis=0)

    def iteration_s(self, time_model: StopAndGo) -> np.ndarray:
        """Mission time of each iteration, (T, K): the centre's move, or with a changing formation
        radius the longest of the vehicles' flights to their new slots."""
        if self.radii_m is None:
            return time_model.iteration_s(self.moves())
        slots = _scaled(self.offsets, self.radii_m[:, :, None, None])  # (T + 1, K, N, 3)
        flights = self.moves()[:, :, None, :] + np.diff(slots, axis=0)
        return time_model.iteration_s(flights).max(axis=-1)


def _scaled(offsets: np.ndarray, radius_m) -> np.ndarray:
    """Offsets ``(K, N, 3)`` scaled so that their mean distance from the centre is ``radius_m``."""
    base = np.linalg.norm(offsets, axis=-1).mean(axis=-1)[:, None, None]
    return offsets * (radius_m / np.where(base > 0, base, 1.0))


def _rotated(offsets: np.ndarray, trials: int, rng) -> np.ndarray:
    rot = Rotation.random(trials, random_state=rng).as_matrix()
    return np.einsum("kij,nj->kni", rot, offsets)


def simulate_seeker(offsets, field, start, seeker, *, gamma_m: float, iterations: int,
                    noise_std: float = 0.0, rotate: bool = True, seed: int = 0,
                    time_model: StopAndGo | None = None, trial_time_offset_s: float = 1.0e4,
                    own_estimates: float | None = None) -> SeekRun:
    """Run ``K = len(start)`` trials of ``seeker`` on ``field`` (module docstring).

    Parameters
    ----------
    offsets : array_like, shape (N, 3)
        Formation offsets (rigid), metres.
    field : Field
        ``value(points)`` and ``source_enu()`` (:mod:`sitl_mock.fields_config`).
    start : array_like, shape (K, 3)
        Initial centres.
    seeker : estimator.seekers.Seeker
        Reset before the run.
    gamma_m : float
        Largest centre move per iteration (the cap outside the seeker).
    iterations : int
        Iterations ``T``.
    noise_std : float
        Reading noise standard deviation.
    rotate : bool
        A uniformly random orientation of the formation per trial.
    seed : int
        Seed of the rotations and the noise.
    time_model : StopAndGo, optional
        Mission time of each iteration (default ``StopAndGo()``): a time-dependent field
        (``field.time_dependent``, the intermittent plume) is read at the mission time of the
        iteration plus ``trial * trial_time_offset_s`` (independent realisations per trial).
    own_estimates : float, optional
        Record the seeker's ``source_estimate`` after each iteration (``SeekRun.estimates_enu``,
        ``regions_m``) for the region rule of :mod:`estimator.seek_confirm` with this tolerance
        (metres): regions only where the formation is that close to the estimate and the region can be
        that small (``inf`` elsewhere), nothing after the rule first passed (NaN); None: not recorded.

    Returns
    -------
    SeekRun
    """
    c0 = np.asarray(start, dtype=float)
    if c0.ndim != 2 or c0.shape[1] != 3:
        raise ValueError(f"start must have shape (K, 3), got {c0.shape}")
    if not (np.isfinite(gamma_m) and gamma_m > 0) or int(iterations) < 1 or noise_std < 0:
        raise ValueError("need gamma_m > 0, iterations >= 1 and noise_std >= 0")
    rng = np.random.default_rng(seed)
    k = c0.shape[0]
    off = np.asarray(offsets, dtype=float)
    trial_off = _rotated(off, k, rng) if rotate else np.broadcast_to(off, (k,) + off.shape).copy()
    seeker.reset()
    model = time_model or StopAndGo()
    timed = bool(getattr(field, "time_dependent", False))
    now_s = np.arange(k)[:, None] * float(trial_time_offset_s)
    centres = np.empty((int(iterations) + 1, k, 3))
    centres[0] = c0
    arrival = ArrivalSignal()
    signal = np.ones((int(iterations) + 1, k), dtype=bool)
    radii = np.full((int(iterations) + 1, k), np.nan)
    radii[0] = np.linalg.norm(trial_off, axis=-1).mean(axis=-1)
    slots = trial_off
    own_est = _OwnEstimates(seeker, own_estimates, int(iterations), k, c0)
    for t in range(int(iterations)):
        pos = centres[t][:, None, :] + slots
        vals = field.value(pos, now_s) if timed else field.value(pos)
        if noise_std > 0:
            vals = vals + rng.standard_normal(vals.shape) * noise_std
        centres[t + 1] = cap_move(centres[t], seeker.propose(centres[t], pos, vals), gamma_m)
        own = getattr(seeker, "arrival", None)  # a seeker that knows (plume: holding with a detection)
        generic = arrival.signal(vals)  # kept up to date either way, as in the mission
        signal[t + 1] = generic if own is None else own
        own_est.record(t + 1, pos, centres[t + 1], signal[t + 1])
        radius = getattr(seeker, "formation_radius_m", None)  # a seeker that sizes the formation (ste)
        radii[t + 1] = radii[t] if radius is None else radius
        new_slots = slots if radius is None else _scaled(trial_off, radii[t + 1][:, None, None])
        flights = (centres[t + 1] - centres[t])[:, None, :] + new_slots - slots
        now_s = now_s + model.iteration_s(flights).max(axis=-1)[:, None]
        slots = new_slots
    sized = not np.allclose(radii, radii[0])
    return SeekRun(centres, trial_off, np.asarray(field.source_enu(), dtype=float), signal,
                   radii if sized else None, *own_est.arrays())


class _OwnEstimates:
    """The seeker's own estimates of the source per iteration (``source_estimate``), for the region
    rule of :mod:`estimator.seek_confirm` with the tolerance ``tol_m``; nothing for a seeker without
    them (or ``tol_m`` None). Their 95 % regions cost milliseconds each, so a region is computed only
    where the formation's centroid and the next centre are both within ``tol_m`` of the estimate and
    the region can be that small (a seeker's cheap ``source_point`` tells where the estimate is and a
    lower bound of its region; elsewhere ``inf``: the rule cannot pass there),
    and a trial records nothing after the rule (with the signal) first passed: the scan of
    :func:`estimator.seek_confirm.region_scan`, with or without the signal, has passed by then."""

    def __init__(self, seeker, tol_m: float | None, iterations: int, trials: int, c0: np.ndarray):
        from estimator.seek_confirm import RegionConfirmation

        ok = tol_m is not None and callable(getattr(seeker, "source_estimate", None))
        self.seeker, self.tol_m = (seeker if ok else None), tol_m
        self.rules = [RegionConfirmation(tol_m, use_signal=True) for _ in range(trials)] if ok else []
        self.est = np.full((iterations + 1, trials, 3), np.nan)
        self.region = np.full((iterations + 1, trials), np.nan)
        self.formation = np.full((iterations + 1, trials, 3), np.nan)
        self.formation[0] = c0

    def record(self, t: int, positions: np.ndarray, centres: np.ndarray, signal: np.ndarray) -> None:
        """After iteration ``t - 1``: each trial's estimate, the centroid of ``positions`` (K, N, 3),
        the next ``centres`` (K, 3), the iteration's ``signal`` (K,)."""
        self.formation[t] = positions.mean(axis=1)
        for k, rule in enumerate(self.rules):
            if not rule.passed:
                estimate = self._estimate(t, k, centres[k])
                rule.update(centres[k], estimate, self.formation[t, k], bool(signal[k]))

    def _estimate(self, t: int, k: int, centre: np.ndarray):
        """Trial ``k``'s estimate after iteration ``t - 1``, recorded (None: none, or not computed)."""
        cheap = getattr(self.seeker, "source_point", None)
        found = None if cheap is None else cheap(k)
        if cheap is not None and found is None:
            return None
        if found is not None and (found[1] > self.tol_m or max(np.linalg.norm(self.formation[t, k] - found[0]),
                                                               np.linalg.norm(centre - found[0])) > self.tol_m):
            self.est[t, k], self.region[t, k] = found[0], np.inf
            return None
        e = self.seeker.source_estimate(k)
        if e is not None and e.region95_m is not None:
            self.est[t, k], self.region[t, k] = e.enu, e.region95_m
            return e
        return None

    def arrays(self) -> tuple:
        """``(estimates_enu, regions_m, formation_centres)``; the first two None without estimates."""
        if self.seeker is None or not np.isfinite(self.est).any():
            return None, None, self.formation
        return self.est, self.region, self.formation
