"""Benchmark of the simulated fields: evaluations per second (no assertions), and the
intermittent plume's statistics quoted in ``docs/fields.md``.

Run: ``python benchmarks/bench_fields.py`` (``--quick`` for fewer repetitions).

Prints, per field, points evaluated per second for a batch of 800 points at one time (the
offline simulation's 100 trials x 8 robots) and for 8 points at one time (one fleet tick), then
100 trials x 200 iterations of the offline simulation on each field; then, for the default
intermittent plume, the fraction of "zero" readings (< 5 % of the mean) and the coefficient of
variation at a few points, over independent times.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from experiments.offline import simulate  # noqa: E402
from sitl_mock.fields_config import make_field

__all__ = ["main"]

T0 = 1767225600.0
SOURCE = (0.0, 0.0, 15.0)


def _fields() -> dict:
    return {
        "sigma2": make_field("sigma2", SOURCE),
        "plume": make_field("plume", SOURCE),
        "plume x3 sources": make_field("plume", SOURCE, extra_sources=[(0, 40, 15), (30, -30, 12)]),
        "intermittent": make_field("intermittent", SOURCE, seed=1),
        "intermittent x3 sources": make_field("intermittent", SOURCE, extra_sources=[(0, 40, 15), (30, -30, 12)]),
    }


def _rate(field, n_points: int, repeats: int) -> float:
    """Points per second, best of ``repeats`` calls, each at a new time."""
    pts = np.random.default_rng(0).uniform([-20, -30, 5], [80, 30, 25], (n_points, 3))
    best = np.inf
    for i in range(repeats):
        t0 = time.perf_counter()
        field.value(pts, T0 + 0.1 * i)
        best = min(best, time.perf_counter() - t0)
    return n_points / best


def _offline_s(field, trials: int, iterations: int) -> float:
    from formation import cvt_sphere

    t0 = time.perf_counter()
    simulate(cvt_sphere(8, 4.0, seed=0), field, (25.0, 1.0, 15.0), eps=1.0, gamma=1.0,
             iterations=iterations, trials=trials, rotate=True, seed=1, noise_std=0.01)
    return time.perf_counter() - t0


def _intermittency(n_times: int) -> None:
    f = make_field("intermittent", SOURCE, seed=1)
    gap = f.max_range_m / f.steady.wind_speed_m_s + 2.0 * f.meander_time_s + 1.0
    times = T0 + np.arange(n_times) * gap + np.random.default_rng(0).uniform(0.0, 1.0, n_times)
    x = np.array([10.0, 20.0, 40.0, 80.0, 20.0])
    y = np.array([0.0, 0.0, 0.0, 0.0, 2.0 * f.steady.spreads(20.0)[0]])
    pts = f.steady.to_enu(x, y, SOURCE[2])
    v = f.value(np.broadcast_to(pts, (n_times,) + pts.shape), times[:, None])
    mean = f.mean_value(pts)
    print(f"\nintermittent plume (defaults), {n_times} independent times:")
    for i in range(len(x)):
        zero = np.mean(v[:, i] < 0.05 * mean[i])
        print(f"  x = {x[i]:5.1f} m, y = {y[i]:4.1f} m: mean {mean[i]:.4f}, time-average {v[:, i].mean():.4f}, "
              f"'zero' (< 5 % of mean) {100 * zero:4.1f} %, c.v. {v[:, i].std() / mean[i]:.2f}")


def main(argv=None) -> int:
    """Print the evaluation rates and the intermittent plume's statistics."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repetitions")
    args = ap.parse_args(argv)
    repeats = 3 if args.quick else 10
    print(f"{'field':26s} {'pts/s (800 pts)':>16s} {'pts/s (8 pts)':>14s} {'offline 100x200 s':>18s}")
    for name, field in _fields().items():
        big, small = _rate(field, 800, repeats), _rate(field, 8, repeats)
        offline = _offline_s(field, 100, 50 if args.quick else 200)
        print(f"{name:26s} {big:16.3g} {small:14.3g} {offline:18.2f}")
    _intermittency(400 if args.quick else 2000)
    return 0


if __name__ == "__main__":
    sys.exit(main())
