"""The seek's convergence confirmation offline: the window test alone against the window test or the
region rule (:mod:`estimator.seek_confirm`), on the same runs.

For each field and seed, one offline stop-and-go run of ``swarmseek simulate`` (the options below,
``--stop-at-convergence`` semantics) and, from it, where each test first passes and the error there:

* ``window``: the iteration the window test passes (today's only test), the error of the mean of
  its centres (``simulate``'s ``error_m`` before) and of the seeker's own estimate there (what a
  mission reports for the ``model`` seeker);
* ``declared``: the iteration the seek ends with both tests, by which, and the reported error
  (the seeker's own estimate when the region rule ends it);
* ``false``: declared with the reported estimate farther than the tolerance from the source.

Usage::

    python benchmarks/bench_confirm.py --fields sigma2,sigma1 --seeds 0-19
    python benchmarks/bench_confirm.py --fields sigma2 --seeds 0-99 --noise 0.01 --n 8
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

__all__ = ["main", "trial"]


def trial(field: str, seed: int, n: int, noise: float, gamma_m: float, iterations: int) -> dict:
    """One offline run judged both ways (module docstring)."""
    import copy

    import formation
    from experiments.cmd_simulate import _field_and_start, _simulate_seeker, configure
    from experiments.offline import convergence_report

    ap = argparse.ArgumentParser()
    configure(ap)
    args = ap.parse_args(["--n", str(n), "--field", field, "--seeker", "model", "--gamma", str(gamma_m),
                          "--noise", str(noise), "--iterations", str(iterations), "--seed", str(seed)])
    window, tol_m = 12, 0.5  # a mission plan's (simulate's defaults for this seeker)
    args.window, args.tol = window, tol_m
    _, fld, start = _field_and_start(args)
    res = _simulate_seeker(args, formation.cvt_sphere(n, args.radius, seed=seed), fld, start)
    both = convergence_report(res, window=window, tol_m=tol_m, stop_at_convergence=True, min_signal_fraction=1.0)
    alone = copy.copy(res)
    alone.estimates_enu = None
    old = convergence_report(alone, window=window, tol_m=tol_m, stop_at_convergence=True, min_signal_fraction=1.0)
    kw = old["converged_at_iteration"]
    own_w = None
    if kw is not None and res.estimates_enu is not None and np.all(np.isfinite(res.estimates_enu[kw, 0])):
        own_w = float(np.linalg.norm(res.estimates_enu[kw, 0] - res.source_enu))
    return {"field": field, "seed": seed, "window_k": kw, "window_mean_err": old["estimate_error_m"],
            "window_own_err": own_w, "k": both["converged_at_iteration"], "by": both["converged_by"],
            "err": both["estimate_error_m"], "tol": tol_m}


def _stats(x) -> str:
    x = np.asarray([v for v in x if v is not None], dtype=float)
    if not len(x):
        return "-"
    return f"median {np.median(x):.3f}, max {x.max():.3f}"


def main(argv=None) -> int:
    """Run the trials; one row each, then a summary per field."""
    from bench_seek_mission import _seeds

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fields", default="sigma2,sigma1")
    ap.add_argument("--seeds", default="0-19")
    ap.add_argument("--n", type=int, default=6)  # radius: simulate's default (1 m)
    ap.add_argument("--noise", type=float, default=0.005)
    ap.add_argument("--gamma", type=float, default=20.0)
    ap.add_argument("--iterations", type=int, default=300)
    args = ap.parse_args(argv)
    print("| field | seed | window test: iteration | its centres' mean error, m | the seeker's error there, m "
          "| declared: iteration | by | reported error, m |")
    print("|---|---|---|---|---|---|---|---|")
    for field in args.fields.split(","):
        rows = [trial(field, s, args.n, args.noise, args.gamma, args.iterations) for s in _seeds(args.seeds)]
        for r in rows:
            f = {k: "-" if r[k] is None else f"{r[k]:.3f}" for k in ("err", "window_mean_err", "window_own_err")}
            print(f"| {field} | {r['seed']} | {r['window_k']} | {f['window_mean_err']} | {f['window_own_err']} "
                  f"| {r['k']} | {r['by']} | {f['err']} |")
        by_region = [r for r in rows if r["by"] == "region"]
        false = [r for r in rows if r["err"] is not None and r["err"] > r["tol"]]
        saved = [r["window_k"] - r["k"] for r in by_region if r["window_k"] is not None]
        old_false = [r for r in rows if r["window_mean_err"] is not None and r["window_mean_err"] > r["tol"]]
        print(f"\n{field}: window test alone: converged {sum(r['window_k'] is not None for r in rows)}/{len(rows)}, "
              f"centres' mean error {_stats(r['window_mean_err'] for r in rows)} ({len(old_false)} beyond the "
              f"tolerance), the seeker's own there {_stats(r['window_own_err'] for r in rows)}; with the region rule: "
              f"converged {sum(r['k'] is not None for r in rows)}/{len(rows)}, by it {len(by_region)}, iterations "
              f"saved {_stats(saved)}, reported error {_stats(r['err'] for r in rows)} ({len(false)} beyond the "
              "tolerance)\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
