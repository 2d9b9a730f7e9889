"""Where the ``ste`` seeker's time goes, offline stop and go (no assertions).

Runs ``bench_seekers.py``'s cell (same starts, formation, noise, time model) with the seeker
wrapped so that every iteration's state is recorded, then splits each trial's mission time into
phases by the first iteration at which: a vehicle reads a hit; the vehicles have read 5, 20
hits in all (sustained contact with the plume, not one stray puff); the region is below 10 m; the
centre is within 10 m; the centre is within 3 m of the
release; the 95 % region is below 3 m, 2 m, 1 m (``arrival``); the centre is within 1 m for good
(the benchmark's success time). Prints the median of each milestone's time over the trials that
reach it, the fraction that reach it, the median ratio of the success time to the straight line,
the mean iteration time and step in each phase, and the fraction of the end game (region below
3 m) spent exploiting (the centre sent to the posterior mean).

Usage::

    python benchmarks/diag_ste_time.py --trials 30 --iterations 120 --seeker ste-patchy-wind \
        --field intermittent [--ste-args corr_time_s=3.5] [--start-m 20,40] [--search-box 60]

``--search-box SIDE_M`` bounds the prior by each trial's search box, as ``bench_seekers.py``'s
option does (the same boxes for the same seed), so its rows and this split are of the same runs.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

__all__ = ["main", "trace"]


class _Recorder:
    """A seeker wrapped to record, after every ``propose``, its region, estimate and hits."""

    def __init__(self, seeker):
        self.inner, self.rows = seeker, []

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def reset(self):
        self.rows = []
        self.inner.reset()

    def propose(self, centre, positions, values):
        nxt = self.inner.propose(centre, positions, values)
        s = self.inner
        hits = np.sum(np.asarray(values) - s.background > s.threshold, axis=1)
        exploit = s.region95_m < s.exploit_m
        self.rows.append((s.region95_m.copy(), s.estimate_enu.copy(), hits, exploit, s.arrival.copy()))
        return nxt


def trace(seeker_name: str, field_name: str, trials: int, iterations: int, seed: int = 0,
          ste_args: str | None = None, start_m=(10.0, 50.0), search_box_m: float | None = None) -> dict:
    """Run one benchmark cell with the recorder; per-iteration arrays ``(T, K)`` and the run
    (``search_box_m``: the ``ste`` prior bounded by ``bench_seekers.search_boxes``, as its option)."""
    import formation
    from bench_seekers import _field_and_noise, _seeker, _starts, search_boxes
    from experiments.offline_seek import StopAndGo, simulate_seeker
    from mission.sim.embedded import downwind_en

    rng = np.random.default_rng(seed)
    source = np.array([0.0, 0.0, 15.0])
    field, noise = _field_and_noise(field_name, source, "realistic")
    starts, dist = _starts(field.source_enu(), trials, rng, downwind_en(field), start_m)
    box = None
    if search_box_m is not None and seeker_name.startswith("ste"):
        box = search_boxes(field.source_enu(), starts, search_box_m, np.random.default_rng(seed + 2))
    seeker, gamma = _seeker(seeker_name, field, ste_args, box)
    rec = _Recorder(seeker)
    run = simulate_seeker(formation.cvt_sphere(8, 4.0, seed=0), field, starts, rec, gamma_m=gamma,
                          iterations=iterations, noise_std=noise, rotate=True, seed=seed + 1)
    region, est, hits, exploit, arrival = (np.stack([r[i] for r in rec.rows]) for i in range(5))
    return dict(run=run, dist=dist, region=region, est=est, hits=hits, exploit=exploit, arrival=arrival,
                iter_s=run.iteration_s(StopAndGo()), moves=np.linalg.norm(run.moves(), axis=-1))


def _first(mask: np.ndarray) -> np.ndarray:
    """First index along axis 0 where ``mask`` holds, -1 where never ``(K,)``."""
    return np.where(mask.any(axis=0), np.argmax(mask, axis=0), -1)


def _milestones(tr: dict) -> dict:
    """Iteration index of each milestone per trial (-1: never)."""
    run = tr["run"]
    d = run.distance_m()[1:]  # distance of the centre after each iteration's move
    out = d > 1.0
    stay = np.where(out.any(axis=0), out.shape[0] - np.argmax(out[::-1], axis=0), 0)
    stay = np.where(out[-1], -1, stay)
    total = np.cumsum(tr["hits"], axis=0)
    return {"first hit": _first(tr["hits"] > 0), "5 hits in all": _first(total >= 5),
            "20 hits in all": _first(total >= 20), "region < 10 m": _first(tr["region"] < 10.0),
            "centre within 10 m": _first(d <= 10.0), "centre within 3 m": _first(d <= 3.0),
            "region < 3 m": _first(tr["region"] < 3.0), "region < 2 m": _first(tr["region"] < 2.0),
            "region <= 1 m (arrival)": _first(tr["arrival"]), "centre within 1 m for good": stay}


def report(tr: dict) -> None:
    """Print the milestone table and the per-phase iteration time and step."""
    t_cum = np.concatenate([np.zeros((1, tr["iter_s"].shape[1])), np.cumsum(tr["iter_s"], axis=0)])
    k = t_cum.shape[1]
    straight = tr["dist"] / 3.0
    print(f"trials {k}, straight line median {np.median(straight):.1f} s")
    print("| milestone | reached | time, s (median) | ratio to straight line (median) |")
    print("|---|---|---|---|")
    ms = _milestones(tr)
    for name, idx in ms.items():
        ok = idx >= 0
        t = t_cum[np.where(ok, idx + 1, 0), np.arange(k)]
        med = np.median(t[ok]) if ok.any() else np.nan
        rat = np.median(t[ok] / straight[ok]) if ok.any() else np.nan
        print(f"| {name} | {ok.mean():.2f} | {med:.1f} | {rat:.2f} |")
    reg = tr["region"]
    phases = {"region >= 3 m": reg >= 3.0, "region 1-3 m": (reg < 3.0) & ~tr["arrival"], "arrived": tr["arrival"]}
    print("| phase | share of time before the end | iteration, s (mean) | centre step, m (mean) "
          "| hits per iteration | exploiting |")
    print("|---|---|---|---|---|---|")
    total = tr["iter_s"].sum()
    for name, m in phases.items():
        if not m.any():
            continue
        print(f"| {name} | {tr['iter_s'][m].sum() / total:.2f} | {tr['iter_s'][m].mean():.2f} | "
              f"{tr['moves'][m].mean():.2f} | {tr['hits'][m].mean():.2f} | {tr['exploit'][m].mean():.2f} |")


def main(argv=None) -> int:
    """Run and print (module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=30)
    ap.add_argument("--iterations", type=int, default=120)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--seeker", default="ste-patchy-wind")
    ap.add_argument("--field", default="intermittent")
    ap.add_argument("--ste-args", default=None)
    ap.add_argument("--start-m", default="10,50", help="start distance range, m (lo,hi)")
    ap.add_argument("--search-box", type=float, default=None, metavar="SIDE_M",
                    help="bound the ste prior by a search box of this side, m (as bench_seekers.py)")
    args = ap.parse_args(argv)
    from bench_seekers import _start_range

    if args.search_box is not None and (not np.isfinite(args.search_box) or args.search_box <= 0):
        ap.error(f"--search-box must be a side > 0 m, got {args.search_box!r}")

    try:
        start_m = _start_range(args.start_m)
    except ValueError as exc:
        ap.error(str(exc))
    report(trace(args.seeker, args.field, args.trials, args.iterations, args.seed, args.ste_args, start_m,
                 args.search_box))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
