"""Offline Monte Carlo: one faulty sensor in an 8-robot formation seeking sigma_2.

Prints a table of the final error ``||c - r*||`` (per trial: mean over the last ``--tail``
iterations; then mean and std over trials) for

* estimators: eq. (3) on the symmetric formation, Theorem 2 on the CVT, the robust
  estimator (:class:`estimator.robust.RobustGradientEstimator`) on the CVT and on the symmetric
  formation, and the robust estimator with sensor retirement on the CVT (``CVT robust+retire``:
  the faulty robot parked at the centre, the others re-formed into a 7-point CVT);
* faults: none (noise 0.1 on all), one robot at 0.5 (5x, the paper's Fig. 4), one at 1.0 (10x),
  one stuck (frozen at its first reading), one biased (+0.5 = 5 sigma), one spiking (5 % of its
  readings off by +-5);

with the paper's eps = 1, gamma = 0.1, N = 8, D = 1, sigma_2 with its source at the origin,
start (20, -20, 5) (as ``swarmseek paper``). Trial k has robot ``k mod 8`` faulty and its own
random rotation of the formation; every estimator sees the same noise in the same trial
(paired comparison). For the robust estimator it also reports how often the faulty robot was
named with the right reason at the end, and how often a healthy robot was named; for the
retiring one, how often the faulty robot was retired, when, and how often a healthy one was.
The target line gives 95 % bootstrap intervals (trials resampled in pairs).

With ``--seeker newton|model|plume`` the same faults are flown by that seeker instead of the
paper's gradient step (``benchmarks/faulty_seekers.py``: one seeker per trial, steps capped at
``--gamma``, 20 m by default as in ``swarmseek run``), with all readings, with the mission's
faulty-sensor detection (the excluded sensors' readings left out) and with detection plus
retirement.

Run::

    python benchmarks/bench_faulty_sensor.py            # 100 trials x 5000 iterations (~20 min)
    python benchmarks/bench_faulty_sensor.py --quick    # 20 x 1500, a smoke run
    python benchmarks/bench_faulty_sensor.py --seeker model   # 40 trials x 200 iterations, D = 4 m, noise 0.01
                                                              # (run's); --quick: 16 x 120
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from estimator import estimator_weights, gradient_batch, seek_step  # noqa: E402
from estimator.retire import SensorRetirement  # noqa: E402
from estimator.robust_faults import REASONS
from estimator.robust import RobustGradientEstimator
from estimator.robust_wls import weighted_gradient
from formation import cvt_sphere, reconfigure, symmetric_cylinder  # noqa: E402
from sitl_mock.fields_gaussian import sigma2

N = 8
EPS, GAMMA = 1.0, 0.1
START_ENU = (20.0, -20.0, 5.0)
NOISE = 0.1
FAULTS = ("none", "noisy 5x", "noisy 10x", "stuck", "biased", "spiking")
#: the suspect reason each injected fault should be reported with
_WANT = {"noisy 5x": "noisy", "noisy 10x": "noisy", "stuck": "stuck", "biased": "biased", "spiking": "spiking"}
ESTIMATORS = ("symmetric eq.3", "CVT Thm 2", "CVT robust", "CVT robust+retire", "symmetric robust")
#: the robust estimator plus :class:`estimator.retire.SensorRetirement` (its defaults): a sensor
#: named stuck, or noisy at 3x the median noise or more, for ``RETIRE_AFTER`` consecutive
#: iterations is retired, its robot parked at the formation centre, and the others re-formed into
#: an (N-1)-point CVT (warm-started :func:`formation.reconfigure`), as the mission does
#: (``mission.flight.faults.retire``)
RETIRE = "CVT robust+retire"
RETIRE_AFTER = 20
#: not in the default table: weighted least squares with the TRUE noise variances (a bound on
#: what any weighting can achieve; it cannot see stuck/biased/spiking sensors)
ORACLE = "CVT oracle"


def _faulty_readings(fault, clean, noise, faulty, first, rng_spike, noise_std=NOISE):
    """Readings (K, N) of one iteration with the fault applied to robot ``faulty[k]``."""
    y = clean + noise
    k = np.arange(len(y))
    if fault == "stuck":
        y[k, faulty] = first[k, faulty]
    elif fault == "biased":
        y[k, faulty] += 5 * noise_std
    elif fault == "spiking":
        spike = rng_spike.random(len(y)) < 0.05
        y[k, faulty] += np.where(spike, 50 * noise_std * rng_spike.choice([-1.0, 1.0], len(y)), 0.0)
    return y


class _Retiring:
    """The robust estimator with sensor retirement over a batch of formations (``RETIRE``).

    Until a trial retires a sensor, its gradient comes from one batched N-sensor robust
    estimator; at the retirement its robot is parked at the centre (offset 0, its readings
    ignored), the others get the warm-started (N-1)-CVT slots of :func:`formation.reconfigure`
    and a fresh (N-1)-sensor robust estimator, shared by the trials that retire at the same
    iteration. A second retirement is counted (``second``) but not acted on here.
    """

    def __init__(self, off, radius_m):
        self.off = off  # (trials, N, 3), updated in place at a retirement
        self.radius_m = radius_m
        trials = off.shape[0]
        self.est = RobustGradientEstimator(N, batch_shape=(trials,))
        self.rule = SensorRetirement(N, RETIRE_AFTER, batch_shape=(trials,))
        self.retired = np.full(trials, -1)
        self.retired_at = np.full(trials, -1)
        self.second = np.zeros(trials, dtype=bool)
        self.groups = []  # (trial indices, kept sensor indices (k, N-1), estimator, rule)

    @property
    def suspect_codes(self):
        return self.est.suspect_codes

    def update(self, t, y):
        g = self.est.update(self.off, y)
        for idx, keep, est, rule in self.groups:
            rows = idx[:, None]
            g[idx] = est.update(self.off[rows, keep], y[rows, keep])
            self.second[idx] |= rule.update(est.suspect_codes, est.noise_std_estimates) >= 0
        pick = self.rule.update(self.est.suspect_codes, self.est.noise_std_estimates)
        new = np.flatnonzero((pick >= 0) & (self.retired < 0))
        if len(new):
            keep = np.empty((len(new), N - 1), dtype=int)
            for j, k in enumerate(new):
                rec = reconfigure(self.off[k], int(pick[k]), self.radius_m)
                keep[j] = rec.survivors
                self.off[k, rec.survivors] = rec.slots[rec.assignment]
                self.off[k, pick[k]] = 0.0
            self.retired[new] = pick[new]
            self.retired_at[new] = t + 1
            self.groups.append((new, keep, RobustGradientEstimator(N - 1, batch_shape=(len(new),)),
                                SensorRetirement(N - 1, RETIRE_AFTER, batch_shape=(len(new),))))
        return g


def run(fault, estimator, trials, iterations, tail, radius_m, seed, noise_std=NOISE):
    """One (fault, estimator) cell: final errors (trials,), robust flags, seconds per iteration."""
    field = sigma2()
    base = cvt_sphere(N, radius_m, 0) if estimator.startswith("CVT") else symmetric_cylinder(N, radius_m)
    rot = Rotation.random(trials, random_state=seed).as_matrix()
    off = np.einsum("kij,nj->kni", rot, base)
    faulty = np.arange(trials) % N
    std = np.full((trials, N), noise_std)
    if fault == "noisy 5x":
        std[np.arange(trials), faulty] = 5 * noise_std
    elif fault == "noisy 10x":
        std[np.arange(trials), faulty] = 10 * noise_std
    rng = np.random.default_rng(seed + 1)
    rng_spike = np.random.default_rng(seed + 2)
    if estimator == RETIRE:
        robust = _Retiring(off, radius_m)
    elif "robust" in estimator:
        robust = RobustGradientEstimator(N, batch_shape=(trials,))
    else:
        robust = None
    method = "symmetric" if estimator.startswith("symmetric") else "cvt"
    oracle = estimator == ORACLE
    weights = None if (robust or oracle) else estimator_weights(off, method)
    c = np.broadcast_to(np.asarray(START_ENU), (trials, 3)).copy()
    dist = np.empty((iterations, trials))
    want = _WANT.get(fault)
    want_code = REASONS.index(want) + 1 if want else -1
    first_named = np.full(trials, -1)
    first = None
    t0 = time.perf_counter()
    for t in range(iterations):
        clean = field.value(c[:, None, :] + off)
        noise = rng.standard_normal((trials, N)) * std
        if first is None:
            first = clean + noise
        y = _faulty_readings(fault, clean, noise, faulty, first, rng_spike, noise_std)
        if estimator == RETIRE:
            g = robust.update(t, y)
            named_now = robust.suspect_codes[np.arange(trials), faulty] == want_code
            first_named = np.where(named_now & (first_named < 0), t + 1, first_named)
        elif robust is not None:
            g = robust.update(off, y)
            named_now = robust.suspect_codes[np.arange(trials), faulty] == want_code
            first_named = np.where(named_now & (first_named < 0), t + 1, first_named)
        elif oracle:
            g = weighted_gradient(off, y, 1.0 / std**2)
        else:
            g = gradient_batch(None, y, method, weights=weights)
        c = seek_step(c, g, EPS, GAMMA)
        dist[t] = np.linalg.norm(c - field.source_enu(), axis=1)
    per_iter = (time.perf_counter() - t0) / iterations
    final = dist[-tail:].mean(axis=0)
    flags = None
    if robust is not None:
        codes = robust.suspect_codes
        right = codes[np.arange(trials), faulty]
        others = codes.copy()
        others[np.arange(trials), faulty] = 0
        named = np.mean(right == want_code) if want else float("nan")
        false = np.mean(np.any(others > 0, axis=1))
        false_excl = np.mean(np.any((others == 1) | (others == 2), axis=1))
        when = first_named[first_named > 0]
        detect = (float(np.median(when)), float(np.percentile(when, 90))) if len(when) else (np.nan, np.nan)
        flags = (named, false, false_excl, detect)
    if estimator == RETIRE:
        r = robust
        right = np.mean(r.retired == faulty)
        healthy = np.mean((r.retired >= 0) & (r.retired != faulty))
        when = r.retired_at[r.retired == faulty]
        at = (float(np.median(when)), float(np.percentile(when, 90))) if len(when) else (np.nan, np.nan)
        flags = flags + ((right, healthy, at, float(np.mean(r.second))),)
    return final, flags, per_iter


def _ratio_ci(a, b, seed, resamples=2000):
    """95 % bootstrap intervals of ``mean(a)/mean(b) - 1`` and ``std(a)/std(b) - 1``.

    Trial ``k`` of ``a`` and of ``b`` share the rotation and the faulty robot, so trials are
    resampled in pairs.
    """
    rng = np.random.default_rng(seed + 3)
    idx = rng.integers(0, len(a), (resamples, len(a)))
    ra, rb = a[idx], b[idx]
    mean = ra.mean(axis=1) / rb.mean(axis=1) - 1
    std = ra.std(axis=1) / rb.std(axis=1) - 1
    return tuple(np.percentile(mean, [2.5, 97.5])), tuple(np.percentile(std, [2.5, 97.5]))


def main(argv=None) -> int:
    """Print the table; returns 0."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--trials", type=int, default=None, help="default 100 (gradient), 40 (other seekers)")
    ap.add_argument("--iterations", type=int, default=None, help="default 5000 (gradient), 200 (other seekers)")
    ap.add_argument("--tail", type=int, default=None,
                    help="final iterations averaged per trial (default 1000 (gradient), 50 (other seekers))")
    ap.add_argument("--seeker", choices=("gradient", "newton", "model", "plume"), default="gradient",
                    help="the paper's gradient step (the estimators' table) or another seeker (its variants' table)")
    ap.add_argument("--gamma", type=float, default=None,
                    help="largest step, m (default 0.1, the paper's, for gradient; 20, run's, for the others)")
    ap.add_argument("--radius", type=float, default=None,
                    help="formation radius D (m; default 1, the paper's, for gradient; 4, run's, for the others)")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--noise", type=float, default=None,
                    help="sensor noise std (signal units; default 0.1, the paper's, for gradient; 0.01, run's, for "
                         "the others); the faults scale with it (5x, 10x, bias 5x, spikes 50x)")
    ap.add_argument("--quick", action="store_true", help="20 trials x 1500 iterations")
    ap.add_argument("--faults", default=",".join(FAULTS))
    ap.add_argument("--estimators", default=",".join(ESTIMATORS),
                    help=f"comma-separated subset of: {', '.join(ESTIMATORS + (ORACLE,))}")
    args = ap.parse_args(argv)
    paper = args.seeker == "gradient"
    args.noise = (NOISE if paper else 0.01) if args.noise is None else args.noise
    args.radius = (1.0 if paper else 4.0) if args.radius is None else args.radius
    if not (np.isfinite(args.noise) and args.noise > 0):
        ap.error(f"--noise must be a positive number, got {args.noise}")
    faults = [f for f in args.faults.split(",") if f]
    if args.seeker != "gradient":
        return _seeker_table(args, faults)
    if args.quick:
        args.trials, args.iterations, args.tail = 20, 1500, 300
    args.trials, args.iterations, args.tail = (args.trials or 100, args.iterations or 5000, args.tail or 1000)
    if args.gamma is not None and args.gamma != GAMMA:
        ap.error("--gamma applies to --seeker newton/model/plume (the gradient table uses the paper's 0.1)")
    ests = [e for e in args.estimators.split(",") if e]
    print(f"sigma_2, N = {N}, D = {args.radius:g} m, eps = {EPS:g}, gamma = {GAMMA:g}, start {START_ENU}, "
          f"noise {args.noise:g}; {args.trials} trials x {args.iterations} iterations, final error = mean "
          f"||c - r*|| over the last {args.tail}; faulty robot = trial mod {N}, random rotation per trial")
    results = {}
    for fault in faults:
        for est in ests:
            final, flags, per_iter = run(fault, est, args.trials, args.iterations, args.tail, args.radius,
                                         args.seed, args.noise)
            results[fault, est] = (final, flags, per_iter)
            print(f"  ... {fault:10s} {est:17s} {final.mean():.3f} +- {final.std():.3f} m "
                  f"({per_iter * 1e3:.2f} ms/iteration)", file=sys.stderr, flush=True)
    print()
    print("| fault | " + " | ".join(ests) + " |")
    print("|---|" + "---|" * len(ests))
    for fault in faults:
        cells = []
        for est in ests:
            final = results[fault, est][0]
            cell = f"{final.mean():.2f} +- {final.std():.2f}"
            if ("none", est) in results and fault != "none":
                base = results["none", est][0]
                cell += f" ({final.mean() / base.mean() - 1:+.0%} / {final.std() / base.std() - 1:+.0%})"
            cells.append(cell)
        print(f"| {fault} | " + " | ".join(cells) + " |")
    print("\n(+x% / +y%): change of the mean / std against the same estimator with no fault.")
    robust_ests = [e for e in ests if "robust" in e]
    if robust_ests:
        print("\n| fault | estimator | faulty robot named at the end (right reason) | first named: median / "
              "90th pct iteration | trials with a healthy robot named | ... named stuck/biased (excluded) |")
        print("|---|---|---|---|---|---|")
        for fault in faults:
            for est in robust_ests:
                named, false, false_excl, (med, p90) = results[fault, est][1][:4]
                named_s = "-" if np.isnan(named) else f"{named:.0%}"
                when_s = "-" if np.isnan(med) else f"{med:.0f} / {p90:.0f}"
                print(f"| {fault} | {est} | {named_s} | {when_s} | {false:.0%} | {false_excl:.0%} |")
    if RETIRE in ests:
        print(f"\n| fault | {RETIRE}: faulty robot retired | retired at: median / 90th pct iteration | trials "
              "with a healthy robot retired | trials with a second sensor due (not acted on) |")
        print("|---|---|---|---|---|")
        for fault in faults:
            right, healthy, (med, p90), second = results[fault, RETIRE][1][4]
            when_s = "-" if np.isnan(med) else f"{med:.0f} / {p90:.0f}"
            right_s = f"{right:.0%}" if fault != "none" else "-"
            print(f"| {fault} | {right_s} | {when_s} | {healthy:.0%} | {second:.0%} |")
    for est in ("CVT robust", RETIRE):
        if ("none", "CVT Thm 2") not in results or ("noisy 5x", est) not in results:
            continue
        base = results["none", "CVT Thm 2"][0]
        rob = results["noisy 5x", est][0]
        (m_lo, m_hi), (s_lo, s_hi) = _ratio_ci(rob, base, args.seed)
        print(f"\nTarget (one sensor at 5x): {est} {rob.mean():.3f} +- {rob.std():.3f} m vs all-equal-noise CVT "
              f"Thm 2 {base.mean():.3f} +- {base.std():.3f} m: mean {rob.mean() / base.mean() - 1:+.1%} "
              f"(95 % CI {m_lo:+.1%} .. {m_hi:+.1%}), std {rob.std() / base.std() - 1:+.1%} "
              f"(95 % CI {s_lo:+.1%} .. {s_hi:+.1%}) (target: both within 10 %)")
    return 0


def _seeker_table(args, faults) -> int:
    """``--seeker newton|model|plume``: the faults flown by that seeker, per variant (faulty_seekers)."""
    from faulty_seekers import VARIANTS, run_seeker  # noqa: E402 (next to this script)

    if args.quick:
        args.trials, args.iterations, args.tail = 16, 120, 30
    trials, iterations, tail = args.trials or 40, args.iterations or 200, args.tail or 50
    gamma = 20.0 if args.gamma is None else args.gamma
    print(f"sigma_2, seeker {args.seeker}, N = {N}, D = {args.radius:g} m, gamma = {gamma:g} m, start {START_ENU}, "
          f"noise {args.noise:g}; {trials} trials x {iterations} iterations, final error = mean ||c - r*|| over "
          f"the last {tail}; faulty robot = trial mod {N}, random rotation per trial")
    results = {}
    for fault in faults:
        for var in VARIANTS:
            t0 = time.perf_counter()
            results[fault, var] = run_seeker(fault, var, args.seeker, trials, iterations, tail, args.radius,
                                             args.seed, args.noise, gamma, START_ENU)
            final = results[fault, var][0]
            print(f"  ... {fault:10s} {var:14s} {final.mean():.3f} +- {final.std():.3f} m "
                  f"({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)
    print("\n| fault | " + " | ".join(VARIANTS) + " |")
    print("|---|" + "---|" * len(VARIANTS))
    for fault in faults:
        cells = [f"{results[fault, v][0].mean():.2f} +- {results[fault, v][0].std():.2f}" for v in VARIANTS]
        print(f"| {fault} | " + " | ".join(cells) + " |")
    print("\n| fault | detect+retire: faulty robot retired | healthy robot retired | retired at (median "
          "iteration) | detect: iterations with a healthy robot excluded |")
    print("|---|---|---|---|---|")
    for fault in faults:
        right, wrong, med, _ = results[fault, "detect+retire"][1]
        frac = results[fault, "detect"][1][3]
        print(f"| {fault} | {'-' if fault == 'none' else f'{right:.0%}'} | {wrong:.0%} | "
              f"{'-' if np.isnan(med) else f'{med:.0f}'} | {frac:.1%} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
