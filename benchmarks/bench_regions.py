"""How often the true source lies inside each seeker's reported 95 % region (no assertions).

The same offline set-up as ``bench_seekers.py`` (8-vehicle CVT of radius 4 m, random orientation
per trial, starts 10-50 m from the source, downwind on a plume; ``--noise realistic``: 1 % of the
peak), ``--iterations`` iterations per trial, each reading taken ``--jitter-m`` off its slot (a
real formation never sits exactly on its slots; 0: exactly on them). At the end of each trial the estimate a mission
would report (:func:`estimator.estimate.reported_estimate`): the seeker's own
``source_estimate`` (``model``: the log-quadratic fit's maximum; ``ste``: the posterior), else the
mean of the last ``--window`` centres with the radius holding 95 % of them (the mission's
convergence monitor, window 12 by default). Per seeker and field: how many trials had the seeker's
own estimate, the calibration (source inside the region, Wilson 95 % interval; trials without a
region count as outside), the same over the trials where the seeker had its own estimate and over
the trials whose centre ended within 1 m of the source, the median error and region radius.

Usage::

    python benchmarks/bench_regions.py --trials 50 --fields sigma2 --seekers model,gradient,newton,plume
    python benchmarks/bench_regions.py --trials 50 --fields sigma2 --seekers model --jitter-m 0.1
    python benchmarks/bench_regions.py --mission-seeds 20 --fields sigma2,sigma1   # whole missions
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_seekers import _field_and_noise, _seeker, _starts, wilson  # noqa: E402


def _calibration(inside: np.ndarray) -> dict:
    lo, hi = wilson(int(inside.sum()), len(inside))
    return {"calibration": float(inside.mean()) if len(inside) else float("nan"), "calibration_ci95": [lo, hi],
            "trials": int(len(inside))}


def _simulate(seeker, field, starts, gamma_m: float, iterations: int, noise: float, jitter_m: float, rng):
    """Centres ``(T + 1, K, 3)``: a rigid CVT (random orientation per trial), each reading taken
    ``N(0, jitter_m^2)`` per axis off its slot (tracking error) and seen by the seeker where it was."""
    import formation
    from estimator.seekers import cap_move
    from experiments.offline_seek import _rotated

    k = len(starts)
    off = _rotated(formation.cvt_sphere(8, 4.0, seed=0), k, rng)
    centres = [np.asarray(starts, dtype=float)]
    seeker.reset()
    for _ in range(iterations):
        c = centres[-1]
        pos = c[:, None, :] + off + jitter_m * rng.standard_normal(off.shape)
        vals = field.value(pos) + noise * rng.standard_normal(pos.shape[:2])
        centres.append(cap_move(c, seeker.propose(c, pos, vals), gamma_m))
    return np.asarray(centres)


def run_cell(seeker_name: str, field_name: str, trials: int, iterations: int, seed: int, window: int,
             noise_level: str = "realistic", jitter_m: float = 0.0) -> dict:
    """One row: ``trials`` runs, the reported estimate of each at the end (module docstring)."""
    from estimator import ConvergenceMonitor
    from estimator.estimate import reported_estimate
    from mission.sim.embedded import downwind_en

    rng = np.random.default_rng(seed)
    source = np.array([0.0, 0.0, 15.0])
    field, noise = _field_and_noise(field_name, source, noise_level)
    starts, _ = _starts(field.source_enu(), trials, rng, downwind_en(field))
    seeker, gamma = _seeker(seeker_name, field)
    centres = _simulate(seeker, field, starts, gamma, iterations, noise, jitter_m, rng)
    truth = np.asarray(field.source_enu(), dtype=float)
    err, region, own = [], [], 0
    for k in range(trials):
        mon = ConvergenceMonitor(window=max(window, 8))
        for c in centres[-window:, k]:
            mon.update(c)
        est = reported_estimate(seeker, mon, k)
        own += getattr(seeker, "source_estimate", lambda k: None)(k) is not None
        err.append(float(np.linalg.norm(est.enu - truth)))
        region.append(np.nan if est.region95_m is None else est.region95_m)
    err, region = np.array(err), np.array(region)
    inside = np.where(np.isnan(region), False, err <= np.nan_to_num(region, nan=-1.0))
    near = np.linalg.norm(centres[-1] - truth, axis=1) <= 1.0
    row = {"seeker": seeker_name, "field": field_name, "noise": noise, "jitter_m": jitter_m, "own_estimate": own,
           "error_m_median": float(np.median(err)), "region95_m_median": float(np.nanmedian(region)),
           **_calibration(inside)}
    mine = np.array([getattr(seeker, "source_estimate", lambda k: None)(k) is not None for k in range(trials)])
    row["own"] = _calibration(inside[mine])
    row["near"] = _calibration(inside[near])
    return row


def mission_cell(seeds: int, field_name: str) -> dict:
    """Lock-step ``swarmseek run --json --seed S --field F`` for ``S < seeds`` (the default mission:
    8 vehicles, the model seeker, moving sampling, noise 0.01): the reported region holds the true
    source how often."""
    import contextlib
    import io
    import tempfile

    from mission.cli import main as cli_main

    rows = []
    for seed in range(seeds):
        with tempfile.TemporaryDirectory() as tmp:
            buf = io.StringIO()
            with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(io.StringIO()):
                cli_main(["run", "--json", "--no-tlog", "--seed", str(seed), "--field", field_name,
                          "--log-dir", str(Path(tmp) / "log")])
            rows.append(json.loads(buf.getvalue()))
    err = np.array([r["error_m"] for r in rows], dtype=float)
    region = np.array([np.nan if r["estimate_region95_m"] is None else r["estimate_region95_m"] for r in rows])
    inside = ~np.isnan(region) & (err <= np.nan_to_num(region, nan=-1.0))
    own = np.array([str(r["estimate_basis"]).startswith("maximum") for r in rows])
    return {"field": field_name, "converged": sum(r["outcome"] == "converged" for r in rows), "own": int(own.sum()),
            "error_m_median": float(np.median(err)), "region95_m_median": float(np.nanmedian(region)),
            **_calibration(inside)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=50)
    ap.add_argument("--iterations", type=int, default=150)
    ap.add_argument("--window", type=int, default=12, help="centres in the monitor's fallback estimate")
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--fields", default="sigma2")
    ap.add_argument("--seekers", default="model,gradient,newton")
    ap.add_argument("--noise", default="realistic", choices=("0", "realistic"))
    ap.add_argument("--jitter-m", type=float, default=0.0,
                    help="each reading's position error about its slot (standard deviation per axis, m)")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--mission-seeds", type=int, default=0,
                    help="instead: this many lock-step `swarmseek run` missions per field (mission_cell)")
    args = ap.parse_args(argv)
    rows = []
    if args.mission_seeds:
        for f in args.fields.split(","):
            row = mission_cell(args.mission_seeds, f)
            rows.append(row)
            lo, hi = row["calibration_ci95"]
            print(f"| run --field {f} | {row['trials']} seeds, {row['converged']} converged, {row['own']} with the "
                  f"fit's region | {row['calibration']:.2f} ({lo:.2f}-{hi:.2f}) | {row['error_m_median']:.3f} / "
                  f"{row['region95_m_median']:.3f} |", flush=True)
        if args.json:
            args.json.write_text(json.dumps(rows, indent=2))
        return 0
    print("| seeker | field | jitter (m) | calibration (Wilson 95 %) | seeker's own estimate: trials, calibration "
          "| ended within 1 m: trials, calibration | median error (m) | median region (m) |")
    for f in args.fields.split(","):
        for s in args.seekers.split(","):
            row = run_cell(s, f, args.trials, args.iterations, args.seed, args.window, args.noise, args.jitter_m)
            rows.append(row)
            lo, hi = row["calibration_ci95"]
            near, own = row["near"], row["own"]
            print(f"| {s} | {f} | {args.jitter_m:g} | {row['calibration']:.2f} ({lo:.2f}-{hi:.2f}) | "
                  f"{own['trials']}: {own['calibration']:.2f} | {near['trials']}: {near['calibration']:.2f} | "
                  f"{row['error_m_median']:.2f} | {row['region95_m_median']:.2f} |", flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
