"""Benchmark of the vectorised offline simulation: prints wall times (no assertions).

Target: 100 trials x 3000 iterations x 8 robots in under 1 s.
Run: ``python benchmarks/bench_offline.py``.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from sitl_mock.fields_gaussian import sigma2
from experiments.offline import simulate  # noqa: E402

__all__ = ["main"]


def _offsets(n: int) -> np.ndarray:
    try:
        from formation import cvt_sphere

        return cvt_sphere(n, 1.0, seed=0)
    except ImportError:  # formation not available: any well-spread set will do for timing
        rng = np.random.default_rng(0)
        v = rng.normal(size=(n, 3))
        return v / np.linalg.norm(v, axis=1, keepdims=True)


def main() -> int:
    """Time the target case and a few variants; print one line per case."""
    offsets = _offsets(8)
    field = sigma2()
    cases = [
        ("100 trials x 3000 it x 8 robots, noise 0.1, cvt", dict(trials=100, iterations=3000, noise_std=0.1)),
        ("100 trials x 3000 it x 8 robots, no noise, cvt", dict(trials=100, iterations=3000)),
        ("100 trials x 3000 it x 8 robots, noise, rotated, symmetric",
         dict(trials=100, iterations=3000, noise_std=0.1, rotate=True, method="symmetric")),
        ("1000 trials x 3000 it x 8 robots, noise 0.1, cvt", dict(trials=1000, iterations=3000, noise_std=0.1)),
    ]
    for label, kw in cases:
        best = np.inf
        for _ in range(3):
            t0 = time.perf_counter()
            simulate(offsets, field, (20.0, -20.0, 5.0), seed=1, **kw)
            best = min(best, time.perf_counter() - t0)
        print(f"{label:60s} best of 3: {best:6.3f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
