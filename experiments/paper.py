"""``swarmseek paper``: regenerate the paper's table, footnote figures and Figs. 1-5.

Everything is computed from our own geometry (:mod:`formation`), estimators (:mod:`estimator`)
and offline simulation (:mod:`experiments.offline`), deterministically (fixed seeds). The paper
does not give starting points, the radius of Fig. 4 or the number of iterations; our choices are
the constants of :mod:`experiments.paper_setup` and are written into
``summary.json``. The faulty-robot study is in :mod:`experiments.paper_robustness`, the physics
and convergence checks in :mod:`experiments.paper_checks`, the figures in
:mod:`experiments.paper_figures`.

Outputs (in ``--out DIR``): ``table1.{csv,json,md}``, ``footnote.{csv,json}``,
``fig1_trajectory.{png,csv,json}``, ``fig2_gradient.{png,csv}``, ``fig3_error_radius.{png,csv}``,
``fig4_noise.{png,csv}``, ``fig4_robustness.{csv,json,md}``, ``fig5_cvt30.{png,json}``,
``physics.json`` and ``summary.json``.

Theorem 2 here is the paper's as printed: ``sigma_c`` = the mean of the readings with the
uncentred ``M`` (``sigma_c="remark"``), so the figures are the paper's method. The mission and
``swarmseek simulate`` use the centred least-squares form (exact on linear fields for any
geometry); for the N = 7 and 8 CVTs of these figures (``||r_bar|| < 1e-12``) the two differ
only in rounding.
"""
from __future__ import annotations

import argparse
import math
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

import formation
from estimator import estimator_weights, gradient_batch
from experiments.offline import simulate
from experiments.paper_checks import convergence_sigma1, convergence_sigma2, physics_checks
from experiments.paper_robustness import robustness, robustness_summary
from experiments.paper_setup import (
    CVT_SEED,
    EPS,
    GAMMA,
    NOISE_SEED,
    PAPER_TABLE1,
    SIGMA1_START_ENU,
    SIGMA2_START_ENU,
    TABLE_NS,
    PaperConfig,
    cvt_formation,
    paper_formation,
)
from sitl_mock.fields_gaussian import sigma1, sigma2
from wire.cli_args import path_arg, usage_error

__all__ = ["table1", "footnote", "generate", "configure", "main"]


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
        cvt = formation.metrics(cvt_formation(n)).d_min
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
            m = formation.metrics(paper_formation(kind, n, 1.0))
            rows.append({"n": n, "formation": kind, "r_bar_norm": m.r_bar_norm,
                         "norm_M_alpha": m.norm_M_alpha, "norm_scaled_Minv": m.norm_scaled_Minv,
                         "cond_M": m.cond_M, "d_min": m.d_min})
    return rows


# ----------------------------------------------------------------------------- runs
def _sigma1_runs(cfg: PaperConfig) -> dict:
    """Figs. 1-3: N = 7 CVT, Theorem 2, sigma_1, D = 1, 4, 7 from SIGMA1_START_ENU."""
    runs = {}
    for radius_m in (1.0, 4.0, 7.0):
        off = cvt_formation(7, radius_m)
        res = simulate(off, sigma1(), SIGMA1_START_ENU, eps=EPS, gamma=GAMMA,
                       iterations=cfg.iterations_sigma1, method="cvt", sigma_c="remark")
        eq3 = gradient_batch(None, res.readings[:, 0], weights=estimator_weights(off, "symmetric"))
        runs[radius_m] = (res, eq3)
    return runs


def _fig4_runs(cfg: PaperConfig) -> dict:
    """Fig. 4: N = 8, sigma_2, symmetric (eq. 3) vs CVT (Thm. 2), noise 0.1 / one robot 0.5."""
    out = {}
    for case, std in (("equal", np.full(8, 0.1)), ("faulty", np.r_[0.5, np.full(7, 0.1)])):
        for kind in ("symmetric", "cvt"):
            res = simulate(paper_formation(kind, 8, cfg.fig4_radius_m), sigma2(), SIGMA2_START_ENU,
                           eps=EPS, gamma=GAMMA, iterations=cfg.iterations_sigma2,
                           trials=cfg.trials, noise_std=std, method=kind, seed=NOISE_SEED,
                           sigma_c="remark")
            out[(case, kind)] = res.distance_to_source_m()
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
    figs.fig1_trajectory(out / "fig1_trajectory.png", c, res.offsets[0], k_mid, note=cfg.quick_note())
    exact, thm2 = res.grad_true[:, 0], res.grad_est[:, 0]
    g2 = {"k": k}
    for i, axis in enumerate("xyz"):
        g2.update({f"exact_{axis}": exact[:, i], f"eq3_{axis}": eq3[:, i],
                   f"thm2_{axis}": thm2[:, i]})
    figs.write_csv(out / "fig2_gradient.csv", figs.rows_from_series(g2))
    figs.fig2_gradient(out / "fig2_gradient.png", k, exact, eq3, thm2, note=cfg.quick_note())
    errs = {f"D{r:g}": s1[r][0].error_norm()[:, 0] for r in s1}
    figs.write_csv(out / "fig3_error_radius.csv", figs.rows_from_series({"k": k, **errs}))
    figs.fig3_error(out / "fig3_error_radius.png", k, errs, note=cfg.quick_note())
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
    figs.fig4_noise(out / "fig4_noise.png", k4, f4, note=cfg.quick_note())
    rob = robustness(cfg)
    figs.write_csv(out / "fig4_robustness.csv", rob)
    figs.write_json(out / "fig4_robustness.json", rob)
    rob_summary = robustness_summary(rob)
    label = f"**{cfg.quick_note().replace(chr(10), ' ')}**\n\n" if cfg.quick_note() else ""
    (out / "fig4_robustness.md").write_text(label + figs.markdown_table(
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
    p30 = cvt_formation(30)
    m30 = formation.metrics(p30)
    figs.write_json(out / "fig5_cvt30.json", {
        "n": 30, "seed": CVT_SEED, "generators": p30, "d_min": m30.d_min,
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
    physics = physics_checks(cfg, s1)
    physics["convergence_sigma1"] = convergence_sigma1(s1)
    physics["convergence_sigma2"] = convergence_sigma2(cfg)
    figs.write_json(out / "physics.json", physics)
    summary = {"quick": quick, "note": cfg.quick_note(), "config": asdict(cfg), "eps": EPS, "gamma": GAMMA,
               "sigma1_start_enu": SIGMA1_START_ENU, "sigma2_start_enu": SIGMA2_START_ENU,
               "cvt_seed": CVT_SEED, "noise_seed": NOISE_SEED, "table1": t1,
               **s1_summary, **fig4_summary, "elapsed_s": time.perf_counter() - t0}
    figs.write_json(out / "summary.json", summary)
    return summary


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``paper`` command's arguments."""
    parser.add_argument("--out", type=path_arg, default="paper-out", metavar="DIR",
                        help="output folder (created if missing; default: %(default)s)")
    parser.add_argument("--quick", action="store_true",
                        help="small runs (seconds) that still write every file")


def main(args: argparse.Namespace) -> int:
    """Run ``swarmseek paper``; print where the outputs went and the key numbers."""
    from wire.cli_args import output_dir_problem

    problem = output_dir_problem(args.out, "output directory (--out)")
    if problem:
        return usage_error("swarmseek paper", problem)
    summary = generate(args.out, quick=args.quick)
    note = summary["note"]
    print(f"wrote the paper's table and figures to {args.out} in {summary['elapsed_s']:.1f} s")
    if note:
        print(f"{note.replace(chr(10), ' ')}.\n  The final distances below are where those short runs stopped; `swarmseek paper` "
              "(without --quick) gives the paper's figures.")
    for row in summary["table1"]:
        print(f"  N={row['n']:2d}  d_min symmetric {row['symmetric_d_min']:.3f}  "
              f"cvt {row['cvt_d_min']:.3f}")
    stopped = " (quick run: stopped before convergence)" if note else ""
    for key, val in summary["fig4_final"].items():
        print(f"  fig4 {key:16s} final ||c - r*|| {val['final_mean_m']:.3f} m{stopped}")
    return 0
