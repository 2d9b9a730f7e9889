"""CPU of the ``ste`` seeker's likelihoods, plain (:mod:`estimator.ste_model`) against fast
(:mod:`estimator.ste_fast`), on random particles and readings (no assertions).

``K`` trials x ``P`` particles spread over the 60 m prior x ``M`` readings; ``--near`` of the readers
placed on some particle's plume line; ``--spread-m 2`` puts the particles within 2 m (a converged
posterior). Prints the best of
``--repeat`` CPU times (``time.process_time``), ms per call.

Usage::

    python benchmarks/bench_ste_likelihood.py --particles 3000 --readings 50 --near 0 0.35 1 [--spread-m 2]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

__all__ = ["main"]

_PATCHY = dict(threshold=0.03, pi0=0.6, beta=0.5, log_sd=1.0, eps=0.01)


def _inputs(k: int, p: int, m: int, near: float, spread_m: float = 60.0, seed: int = 1):
    rng = np.random.default_rng(seed)
    parts = np.empty((k, p, 5))
    parts[..., :2] = rng.uniform(-spread_m, spread_m, (k, p, 2))
    parts[..., 2], parts[..., 3] = rng.uniform(0.1, 20.0, (k, p)), rng.uniform(-3.0, 3.0, (k, p))
    parts[..., 4] = rng.uniform(-np.pi, np.pi, (k, p))
    pts = rng.uniform(-10.0, 40.0, (k, m, 3))
    pts[..., 2] = rng.uniform(0.0, 20.0, (k, m))
    src = np.take_along_axis(parts, rng.integers(0, p, (k, m))[..., None], axis=1)
    d = rng.uniform(0.0, 10.0, (k, m))
    on = src[..., :3] + np.stack([d * np.cos(src[..., 4]), d * np.sin(src[..., 4]), np.zeros((k, m))], axis=-1)
    pts = np.where((rng.random((k, m)) < near)[..., None], on, pts)
    v = np.where(rng.random((k, m)) < 0.3, rng.lognormal(-1.0, 1.0, (k, m)), rng.normal(0.0, 0.01, (k, m)))
    return parts, pts, v


def _best_ms(fn, repeat: int, inner: int = 5) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.process_time()
        for _ in range(inner):
            fn()
        best = min(best, (time.process_time() - t0) / inner)
    return 1e3 * best


def main(argv=None) -> int:
    from estimator import ste_fast as fast
    from estimator import ste_model as plain

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=1)
    ap.add_argument("--particles", type=int, default=3000)
    ap.add_argument("--readings", type=int, default=50)
    ap.add_argument("--near", type=float, nargs="+", default=[0.0, 0.35, 1.0])
    ap.add_argument("--spread-m", type=float, default=60.0, help="particles within +- this of the origin, m "
                    "(60: the prior; 2: a converged posterior)")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    print("| readers on a plume | patchy plain, ms | patchy fast, ms | steady plain, ms | steady fast, ms |")
    print("|---|---|---|---|---|")
    for near in args.near:
        parts, pts, v = _inputs(args.trials, args.particles, args.readings, near, args.spread_m)
        edge = dict(stability="C", s0_m=1.0, ground_alt_m=0.0, smooth=True)
        gauss = dict(edge, smooth=False)
        steady = dict(background=0.0, noise_std=0.01, rel_error=0.3)
        row = [_best_ms(lambda: plain.loglik_patchy(*plain.plume_mean(parts, pts, **edge), v[:, None, :],
                                                    background=0.0, **_PATCHY), args.repeat),
               _best_ms(lambda: fast.loglik_patchy_fast(parts, pts, v, model=edge, background=0.0, **_PATCHY),
                        args.repeat),
               _best_ms(lambda: plain.loglik_steady(plain.plume_mean(parts, pts, **gauss)[0], v[:, None, :], **steady),
                        args.repeat),
               _best_ms(lambda: fast.loglik_steady_fast(parts, pts, v, model=gauss, **steady), args.repeat)]
        print(f"| {near:.2f} | " + " | ".join(f"{x:.1f}" for x in row) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
