"""``swarmseek paper``: regenerate the paper's table, footnote figures and Figs. 1-5.

Everything is computed from our own geometry (:mod:`formation`), estimators (:mod:`estimator`)
and offline simulation (:mod:`experiments.offline`), deterministically (fixed seeds). The paper
does not give starting points, the radius of Fig. 4 or the number of iterations; our choices are
the module constants below and are written into ``summary.json``.

Outputs (in ``--out DIR``): ``table1.{csv,json,md}``, ``footnote.{csv,json}``,
``fig1_trajectory.{png,csv,json}``, ``fig2_gradient.{png,csv}``, ``fig3_error_radius.{png,csv}``,
``fig4_noise.{png,csv}``, ``fig4_robustness.{csv,json,md}``, ``fig5_cvt30.{png,json}``,
``physics.json`` and ``summary.json``.
"""
from __future__ import annotations

import argparse
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

import formation
from estimator import convergence_scan, estimator_weights, gradient_batch
from sitl_mock.fields import S1, S2, sigma1, sigma2
from experiments.offline import simulate

__all__ = [
    "EPS",
    "GAMMA",
    "SIGMA1_START_ENU",
    "SIGMA2_START_ENU",
    "TABLE_NS",
    "PAPER_TABLE1",
    "PaperConfig",
    "table1",
    "footnote",
    "generate",
    "configure",
    "main",
]

#: Seeking parameters of every run in the paper (Sec. V).
EPS, GAMMA = 1.0, 0.1
#: Start of the sigma_1 runs (Figs. 1-3): 52 m from the source, mostly along the weak y axis
#: (S_1 eigenvalue 1e-4 /m^2), off in x (narrow axis, 0.01 /m^2) and z.
SIGMA1_START_ENU = (10.0, 50.0, 10.0)
#: Start of the sigma_2 runs (Fig. 4): 28.7 m from the source, mostly along S_2's weakest
#: eigenvector (1, -1, 0)/sqrt(2) (0.0015 /m^2) and 5 m up the strongest (z, 0.01 /m^2).
SIGMA2_START_ENU = (20.0, -20.0, 5.0)
#: N of Table I.
TABLE_NS = (6, 8, 10, 20)
#: The paper's Table I (D = 1), for comparison.
PAPER_TABLE1 = {"symmetric": (1.00, 0.81, 0.68, 0.37), "cvt": (1.41, 1.14, 1.06, 0.76)}
_CVT_STARTS = 10
_CVT_SEED = 0
_NOISE_SEED = 2024


@dataclass(frozen=True)
class PaperConfig:
    """Sizes of the experiments (``full`` for the README, ``quick`` for tests).

    Attributes
    ----------
    footnote_ns : tuple of int
        N of the footnote table.
    iterations_sigma1 : int
        Iterations of the sigma_1 runs (Figs. 1-3).
    iterations_sigma2 : int
        Iterations of the sigma_2 runs (Fig. 4).
    trials : int
        Trials per curve of Fig. 4.
    fig4_radius_m : float
        Formation radius D of Fig. 4 (not given by the paper).
    robustness_radii_m : tuple of float
        Radii of the faulty-robot study.
    robustness_trials : int
        Trials per (formation, faulty robot, orientation) case of the study.
    tail : int
        Final iterations averaged into "final distance" figures.
    iterations_checks : int
        Iterations of the physics and convergence-test runs.
    """

    footnote_ns: tuple = tuple(range(4, 31))
    iterations_sigma1: int = 3000
    iterations_sigma2: int = 5000
    trials: int = 100
    fig4_radius_m: float = 1.0
    robustness_radii_m: tuple = (1.0, 4.0)
    robustness_trials: int = 50
    tail: int = 1000
    iterations_checks: int = 5000

    @classmethod
    def quick(cls) -> "PaperConfig":
        """A small configuration that still writes every output."""
        return cls(
            footnote_ns=tuple(range(4, 11)),
            iterations_sigma1=600,
            iterations_sigma2=400,
            trials=8,
            robustness_radii_m=(1.0,),
            robustness_trials=4,
            tail=100,
            iterations_checks=400,
        )


def _cvt(n: int, radius_m: float = 1.0) -> np.ndarray:
    # The CVT of n points is the lowest-energy one: the energy has several local minima for
    # some n (e.g. n = 20), so take the best of _CVT_STARTS seeded starts.
    return formation.cvt_sphere(n, radius_m, seed=_CVT_SEED, n_starts=_CVT_STARTS)


def _formation(kind: str, n: int, radius_m: float) -> np.ndarray:
    if kind == "cvt":
        return _cvt(n, radius_m)
    return formation.symmetric_cylinder(n, radius_m)


# ----------------------------------------------------------------------------- tables
def table1(ns=TABLE_NS) -> list[dict]:
    """Table I: d_min (D = 1) of both formations, computed from the positions.

    Returns
    -------
    list of dict
        One row per N: ``n``, ``symmetric_d_min``, ``cvt_d_min``, the paper's two values and the
        paper's closed form ``2 cos(theta_F) sin(2 pi / N)``.
    """
    rows = []
    for idx, n in enumerate(ns):
        sym = formation.metrics(formation.symmetric_cylinder(n, 1.0)).d_min
        cvt = formation.metrics(_cvt(n)).d_min
        row = {"n": n, "symmetric_d_min": sym, "cvt_d_min": cvt,
               "paper_formula_symmetric": 2.0 * math.sqrt(1.0 / 3.0) * math.sin(2 * math.pi / n)}
        if tuple(ns) == TABLE_NS:
            row["paper_symmetric_d_min"] = PAPER_TABLE1["symmetric"][idx]
            row["paper_cvt_d_min"] = PAPER_TABLE1["cvt"][idx]
        rows.append(row)
    return rows


def footnote(ns) -> list[dict]:
    """Footnote figures for N in ``ns`` (D = 1): ||r_bar||, ||M_alpha||, ||(N D^2/3) M^-1||,
    cond M and d_min, for the CVT formation (every N) and the symmetric one (even N)."""
    rows = []
    for n in ns:
        kinds = ("cvt", "symmetric") if n % 2 == 0 else ("cvt",)
        for kind in kinds:
            m = formation.metrics(_formation(kind, n, 1.0))
            rows.append({"n": n, "formation": kind, "r_bar_norm": m.r_bar_norm,
                         "norm_M_alpha": m.norm_M_alpha, "norm_scaled_Minv": m.norm_scaled_Minv,
                         "cond_M": m.cond_M, "d_min": m.d_min})
    return rows


# ----------------------------------------------------------------------------- runs
def _sigma1_runs(cfg: PaperConfig) -> dict:
    """Figs. 1-3: N = 7 CVT, Theorem 2, sigma_1, D = 1, 4, 7 from SIGMA1_START_ENU."""
    runs = {}
    for radius_m in (1.0, 4.0, 7.0):
        off = _cvt(7, radius_m)
        res = simulate(off, sigma1(), SIGMA1_START_ENU, eps=EPS, gamma=GAMMA,
                       iterations=cfg.iterations_sigma1, method="cvt")
        eq3 = gradient_batch(None, res.readings[:, 0], weights=estimator_weights(off, "symmetric"))
        runs[radius_m] = (res, eq3)
    return runs


def _fig4_runs(cfg: PaperConfig) -> dict:
    """Fig. 4: N = 8, sigma_2, symmetric (eq. 3) vs CVT (Thm. 2), noise 0.1 / one robot 0.5."""
    out = {}
    for case, std in (("equal", np.full(8, 0.1)), ("faulty", np.r_[0.5, np.full(7, 0.1)])):
        for kind in ("symmetric", "cvt"):
            res = simulate(_formation(kind, 8, cfg.fig4_radius_m), sigma2(), SIGMA2_START_ENU,
                           eps=EPS, gamma=GAMMA, iterations=cfg.iterations_sigma2,
                           trials=cfg.trials, noise_std=std, method=kind, seed=_NOISE_SEED)
            out[(case, kind)] = res.distance_to_source_m()
    return out


def _predicted_rms(weights: np.ndarray, std: np.ndarray, rotate: bool) -> float:
    """RMS of ||c - r*|| predicted by the linearised noisy seeking map near sigma_2's source.

    ``c(k+1) = F c(k) + eps W^T nu`` with ``F = I - 2 eps A S_2`` and reading noise ``nu``; the
    stationary covariance solves ``P = F P F^T + eps^2 Q``, ``Q = sum_i std_i^2 w_i w_i^T``
    (averaged over rotations, ``Q`` becomes ``tr(Q)/3 I``). Ignores the gamma clipping.
    """
    from scipy.linalg import solve_discrete_lyapunov

    q = np.einsum("i,ij,ik->jk", std**2, weights, weights)
    if rotate:
        q = np.trace(q) / 3.0 * np.eye(3)
    f = np.eye(3) - 2.0 * EPS * 1.0 * S2
    return float(np.sqrt(np.trace(solve_discrete_lyapunov(f, EPS**2 * q))))


def _robustness(cfg: PaperConfig) -> list[dict]:
    """Faulty-robot study: every faulty robot, paper frame and random rotations, each D.

    Per row: final distance (mean over the last ``tail`` iterations, then mean/std over
    trials), the faulty robot's estimator weight norm ``||w_j||`` and its gain along S_2's
    weakest axis ``|w_j . u|`` (weights with sigma_c = mean folded in), and the linearised
    prediction of the RMS distance (:func:`_predicted_rms`).
    """
    weak = np.linalg.eigh(S2)[1][:, 0]
    rows = []
    n, trials = 8, cfg.robustness_trials
    for radius_m in cfg.robustness_radii_m:
        for kind in ("symmetric", "cvt"):
            off = _formation(kind, n, radius_m)
            w, _ = estimator_weights(off, kind)
            if kind == "cvt":
                w = w - w.mean(axis=0)  # sigma_c = mean of the readings folds -b/N into W
            norms, weak_gain = np.linalg.norm(w, axis=-1), np.abs(w @ weak)
            for rotate in (False, True):
                std = np.full((n, trials, n), 0.1)
                for j in range(n):
                    std[j, :, j] = 0.5
                std = np.concatenate([np.full((1, trials, n), 0.1), std]).reshape(-1, n)
                res = simulate(off, sigma2(), SIGMA2_START_ENU, eps=EPS, gamma=GAMMA,
                               iterations=cfg.iterations_sigma2, trials=std.shape[0],
                               noise_std=std, method=kind, rotate=rotate, seed=_NOISE_SEED)
                dist = res.distance_to_source_m()[-cfg.tail:].mean(axis=0).reshape(n + 1, trials)
                for j in range(-1, n):
                    d = dist[j + 1]
                    std_j = np.full(n, 0.1)
                    if j >= 0:
                        std_j[j] = 0.5
                    rows.append({
                        "radius_m": radius_m, "formation": kind,
                        "orientation": "random" if rotate else "paper",
                        "faulty_robot": "none" if j < 0 else j,
                        "final_dist_mean_m": float(d.mean()), "final_dist_std_m": float(d.std()),
                        "weight_norm": float(norms[j]) if j >= 0 else float("nan"),
                        "weak_axis_gain": float(weak_gain[j]) if j >= 0 else float("nan"),
                        "predicted_rms_m": _predicted_rms(w, std_j, rotate),
                    })
    return rows


def _robustness_summary(rows: list[dict]) -> list[dict]:
    """Average the study over the faulty robot, per (radius, formation, orientation)."""
    out = []
    keys = sorted({(r["radius_m"], r["formation"], r["orientation"]) for r in rows})
    for radius_m, kind, orient in keys:
        sel = [r for r in rows if (r["radius_m"], r["formation"], r["orientation"])
               == (radius_m, kind, orient)]
        base = [r for r in sel if r["faulty_robot"] == "none"][0]
        faulty = np.array([r["final_dist_mean_m"] for r in sel if r["faulty_robot"] != "none"])
        out.append({"radius_m": radius_m, "formation": kind, "orientation": orient,
                    "no_fault_m": base["final_dist_mean_m"], "faulty_mean_m": float(faulty.mean()),
                    "faulty_best_m": float(faulty.min()), "faulty_worst_m": float(faulty.max())})
    return out


def _effective_rate(radius_m: float) -> dict:
    """Linearised seeking map near the source of sigma_1 for N = 7 CVT of radius D:
    eigenvalues of I + eps * d g_hat / d c (|.| < 1 means locally convergent)."""
    off = _cvt(7, radius_m)
    w = estimator_weights(off, "cvt")
    f = sigma1()
    h = 1e-5
    jac = np.empty((3, 3))
    for k in range(3):
        dc = np.zeros(3)
        dc[k] = h
        gp = gradient_batch(None, f.value(dc + off), weights=w)
        gm = gradient_batch(None, f.value(-dc + off), weights=w)
        jac[:, k] = (gp - gm) / (2 * h)
    fixed = np.linalg.solve(jac, -gradient_batch(None, f.value(off), weights=w))
    eig = np.linalg.eigvals(np.eye(3) + EPS * jac)
    return {"radius_m": radius_m, "eigenvalues": sorted(np.real(eig).tolist()),
            "predicted_fixed_point_enu": fixed.tolist()}


def _physics(cfg: PaperConfig, s1_runs: dict) -> dict:
    """Step sizes, iteration counts and stability: what eps = 1, gamma = 0.1 imply."""
    out = {}
    for name, field, s_mat, start in (("sigma1", sigma1(), S1, SIGMA1_START_ENU),
                                      ("sigma2", sigma2(), S2, SIGMA2_START_ENU)):
        lam = np.linalg.eigvalsh(s_mat)
        amp = float(field.value(field.source_enu()))
        g0 = float(np.linalg.norm(field.gradient(np.asarray(start))))
        slow = 1.0 - 2 * EPS * amp * lam[0]
        out[name] = {
            "start_enu": list(start), "start_distance_m": float(np.linalg.norm(start)),
            "start_value": float(field.value(np.asarray(start))), "start_grad_norm": g0,
            "start_step_m": min(EPS * g0, GAMMA),
            "S_eigenvalues_per_m2": lam.tolist(),
            "exact_gradient_linear_factors": (1.0 - 2 * EPS * amp * lam).tolist(),
            "iterations_per_decade_near_source": math.log(10) / -math.log(abs(slow)),
        }
    # sigma_2 noise-free, N = 8 CVT, D = 1: how many iterations the run needs.
    res = simulate(_cvt(8, cfg.fig4_radius_m), sigma2(), SIGMA2_START_ENU, eps=EPS, gamma=GAMMA,
                   iterations=cfg.iterations_checks, method="cvt")
    d = res.distance_to_source_m()[:, 0]
    steps = np.linalg.norm(np.diff(res.centres[:, 0], axis=0), axis=-1)
    out["sigma2"].update({
        "noise_free_iterations_to": {f"{t} m": _first_below(d, t) for t in (10.0, 1.0, 0.1)},
        "max_step_m": float(steps.max()), "iterations_at_gamma": int(np.sum(steps > 0.999 * GAMMA)),
    })
    res1 = s1_runs[4.0][0]
    d1 = res1.distance_to_source_m()[:, 0]
    steps1 = np.linalg.norm(np.diff(res1.centres[:, 0], axis=0), axis=-1)
    out["sigma1"].update({
        "D4_iterations_to": {f"{t} m": _first_below(d1, t) for t in (10.0, 1.0)},
        "D4_iterations_at_gamma": int(np.sum(steps1 > 0.999 * GAMMA)),
        "linearised_estimator_map": [_effective_rate(r) for r in (1.0, 4.0, 7.0)],
    })
    return out


def _first_below(dist: np.ndarray, threshold_m: float):
    idx = np.flatnonzero(dist < threshold_m)
    return int(idx[0]) if idx.size else None


def _convergence(s1_runs: dict) -> dict:
    """Apply the convergence test (defaults) to the runs; report when and how close."""
    out = {}
    for radius_m, (res, _) in s1_runs.items():
        first, est, spread = convergence_scan(res.centres)
        out[f"sigma1_D{radius_m:g}"] = {
            "first_iteration": int(first[0]),
            "estimate_error_m": float(np.linalg.norm(est[0])) if first[0] >= 0 else None,
            "final_distance_m": float(res.distance_to_source_m()[-1, 0])}
    return out


def _convergence_fig4(cfg: PaperConfig) -> dict:
    """The convergence test (defaults) on sigma_2 runs: noise-free and noise 0.1, D = 1 and 4."""
    out = {}
    for kind in ("symmetric", "cvt"):
        for label, std, radius_m in (("noise-free", 0.0, cfg.fig4_radius_m),
                                     ("noise 0.1", 0.1, cfg.fig4_radius_m),
                                     ("noise 0.1", 0.1, 4.0)):
            res = simulate(_formation(kind, 8, radius_m), sigma2(), SIGMA2_START_ENU, eps=EPS,
                           gamma=GAMMA, iterations=cfg.iterations_checks,
                           trials=cfg.trials, noise_std=std, method=kind, seed=_NOISE_SEED)
            first, est, _ = convergence_scan(res.centres)
            ok = first >= 0
            err = np.linalg.norm(est[ok], axis=-1)
            out[f"sigma2_{kind}_{label}_D{radius_m:g}"] = {
                "converged_fraction": float(ok.mean()),
                "median_first_iteration": float(np.median(first[ok])) if ok.any() else None,
                "estimate_error_m_median": float(np.median(err)) if ok.any() else None,
                "estimate_error_m_max": float(err.max()) if ok.any() else None,
            }
    return out


def _write_tables(out: Path, cfg: PaperConfig, figs) -> list[dict]:
    """Table I and the footnote table; returns Table I's rows."""
    t1 = table1()
    figs.write_csv(out / "table1.csv", t1)
    figs.write_json(out / "table1.json", t1)
    (out / "table1.md").write_text(figs.markdown_table(
        t1, ["n", "symmetric_d_min", "paper_symmetric_d_min", "cvt_d_min", "paper_cvt_d_min"]))
    fn = footnote(cfg.footnote_ns)
    figs.write_csv(out / "footnote.csv", fn)
    figs.write_json(out / "footnote.json", fn)
    return t1


def _write_sigma1(out: Path, cfg: PaperConfig, figs) -> tuple[dict, dict]:
    """Figs. 1-3; returns the runs and their summary figures."""
    s1 = _sigma1_runs(cfg)
    res, eq3 = s1[4.0]
    k = np.arange(cfg.iterations_sigma1)
    c = res.centres[:, 0]
    figs.write_csv(out / "fig1_trajectory.csv", figs.rows_from_series(
        {"k": np.arange(len(c)), "east_m": c[:, 0], "north_m": c[:, 1], "up_m": c[:, 2],
         "dist_m": res.distance_to_source_m()[:, 0]}))
    k_mid = min(500, cfg.iterations_sigma1)
    figs.write_json(out / "fig1_trajectory.json", {
        "field": "sigma1", "n": 7, "radius_m": 4.0, "method": "cvt (Theorem 2)", "eps": EPS,
        "gamma": GAMMA, "start_enu": SIGMA1_START_ENU, "iterations": cfg.iterations_sigma1,
        "offsets": res.offsets[0], "k_intermediate": k_mid,
        "positions_initial": c[0] + res.offsets[0],
        "positions_intermediate": c[k_mid] + res.offsets[0], "final_centre_enu": c[-1]})
    figs.fig1_trajectory(out / "fig1_trajectory.png", c, res.offsets[0], k_mid)
    exact, thm2 = res.grad_true[:, 0], res.grad_est[:, 0]
    g2 = {"k": k}
    for i, axis in enumerate("xyz"):
        g2.update({f"exact_{axis}": exact[:, i], f"eq3_{axis}": eq3[:, i],
                   f"thm2_{axis}": thm2[:, i]})
    figs.write_csv(out / "fig2_gradient.csv", figs.rows_from_series(g2))
    figs.fig2_gradient(out / "fig2_gradient.png", k, exact, eq3, thm2)
    errs = {f"D{r:g}": s1[r][0].error_norm()[:, 0] for r in s1}
    figs.write_csv(out / "fig3_error_radius.csv", figs.rows_from_series({"k": k, **errs}))
    figs.fig3_error(out / "fig3_error_radius.png", k, errs)
    eq3_err = np.linalg.norm(eq3 - exact, axis=-1)
    thm2_err = np.linalg.norm(thm2 - exact, axis=-1)
    summary = {
        "fig2_error_norm_mean": {"eq3": float(eq3_err.mean()), "thm2": float(thm2_err.mean())},
        "fig2_error_norm_max": {"eq3": float(eq3_err.max()), "thm2": float(thm2_err.max())},
        "fig3_final_error": {key: float(v[-cfg.tail:].mean()) for key, v in errs.items()},
        "fig3_final_distance_m": {f"D{r:g}": float(s1[r][0].distance_to_source_m()[-1, 0])
                                  for r in s1},
    }
    return s1, summary


def _write_fig4(out: Path, cfg: PaperConfig, figs) -> dict:
    """Fig. 4 and the faulty-robot study; returns their summary figures."""
    f4 = _fig4_runs(cfg)
    k4 = np.arange(cfg.iterations_sigma2 + 1)
    cols = {"k": k4}
    for (case, kind), d in f4.items():
        cols[f"{case}_{kind}_mean_m"] = d.mean(axis=1)
        cols[f"{case}_{kind}_std_m"] = d.std(axis=1)
    figs.write_csv(out / "fig4_noise.csv", figs.rows_from_series(cols))
    figs.fig4_noise(out / "fig4_noise.png", k4, f4)
    rob = _robustness(cfg)
    figs.write_csv(out / "fig4_robustness.csv", rob)
    figs.write_json(out / "fig4_robustness.json", rob)
    rob_summary = _robustness_summary(rob)
    (out / "fig4_robustness.md").write_text(figs.markdown_table(
        rob_summary, ["radius_m", "formation", "orientation", "no_fault_m", "faulty_mean_m",
                      "faulty_best_m", "faulty_worst_m"]) + "\n" + figs.markdown_table(
        rob, ["radius_m", "formation", "orientation", "faulty_robot", "final_dist_mean_m",
              "final_dist_std_m", "predicted_rms_m", "weight_norm", "weak_axis_gain"]))
    final = {f"{case}_{kind}": {"final_mean_m": float(d[-cfg.tail:].mean()),
                                "final_std_m": float(d[-cfg.tail:].std(axis=1).mean())}
             for (case, kind), d in f4.items()}
    return {"fig4_final": final, "fig4_robustness": rob_summary}


def _write_fig5(out: Path, figs) -> None:
    """Fig. 5: the 30-generator CVT and its generators."""
    p30 = _cvt(30)
    m30 = formation.metrics(p30)
    figs.write_json(out / "fig5_cvt30.json", {
        "n": 30, "seed": _CVT_SEED, "generators": p30, "d_min": m30.d_min,
        "r_bar_norm": m30.r_bar_norm, "norm_scaled_Minv": m30.norm_scaled_Minv})
    figs.fig5_cvt(out / "fig5_cvt30.png", p30)


def generate(out_dir, quick: bool = False) -> dict:
    """Compute every experiment and write all outputs into ``out_dir``.

    Parameters
    ----------
    out_dir : path-like
        Output folder (created if missing).
    quick : bool
        Use :meth:`PaperConfig.quick` (small runs) instead of the full configuration.

    Returns
    -------
    dict
        The summary also written to ``summary.json``.
    """
    from experiments import paper_figures as figs

    cfg = PaperConfig.quick() if quick else PaperConfig()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    t1 = _write_tables(out, cfg, figs)
    s1, s1_summary = _write_sigma1(out, cfg, figs)
    fig4_summary = _write_fig4(out, cfg, figs)
    _write_fig5(out, figs)
    physics = _physics(cfg, s1)
    physics["convergence_sigma1"] = _convergence(s1)
    physics["convergence_sigma2"] = _convergence_fig4(cfg)
    figs.write_json(out / "physics.json", physics)
    summary = {"quick": quick, "config": asdict(cfg), "eps": EPS, "gamma": GAMMA,
               "sigma1_start_enu": SIGMA1_START_ENU, "sigma2_start_enu": SIGMA2_START_ENU,
               "cvt_seed": _CVT_SEED, "noise_seed": _NOISE_SEED, "table1": t1,
               **s1_summary, **fig4_summary, "elapsed_s": time.perf_counter() - t0}
    figs.write_json(out / "summary.json", summary)
    return summary


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``paper`` command's arguments."""
    parser.add_argument("--out", default="paper-out", metavar="DIR",
                        help="output folder (created if missing; default: %(default)s)")
    parser.add_argument("--quick", action="store_true",
                        help="small runs (seconds) that still write every file")


def main(args: argparse.Namespace) -> int:
    """Run ``swarmseek paper``; print where the outputs went and the key numbers."""
    summary = generate(args.out, quick=args.quick)
    print(f"wrote the paper's table and figures to {args.out} in {summary['elapsed_s']:.1f} s")
    for row in summary["table1"]:
        print(f"  N={row['n']:2d}  d_min symmetric {row['symmetric_d_min']:.3f}  "
              f"cvt {row['cvt_d_min']:.3f}")
    for key, val in summary["fig4_final"].items():
        print(f"  fig4 {key:16s} final ||c - r*|| {val['final_mean_m']:.3f} m")
    return 0
