"""The paper's faulty-robot study (Fig. 4): which robot's noise hurts the seeking most.

For N = 8, sigma_2 and each radius of
:attr:`~experiments.paper_setup.PaperConfig.robustness_radii_m`, both formations are flown
with each robot in turn 5x noisier than the others, in the paper's orientation and in random
ones (:func:`robustness`); the final distances are compared with the faulty robot's estimator
weight and with the linearised noisy seeking map's prediction (:func:`predicted_rms`), then
averaged over the faulty robot (:func:`robustness_summary`).
"""
from __future__ import annotations

import numpy as np

from estimator import estimator_weights
from experiments.offline import simulate
from experiments.paper_setup import (
    EPS,
    GAMMA,
    NOISE_SEED,
    SIGMA2_START_ENU,
    PaperConfig,
    paper_formation,
)
from sitl_mock.fields_gaussian import S2, sigma2

__all__ = ["predicted_rms", "robustness", "robustness_summary"]


def predicted_rms(weights: np.ndarray, std: np.ndarray, rotate: bool) -> float:
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


def robustness(cfg: PaperConfig) -> list[dict]:
    """Faulty-robot study: every faulty robot, paper frame and random rotations, each D.

    Per row: final distance (mean over the last ``tail`` iterations, then mean/std over
    trials), the faulty robot's estimator weight norm ``||w_j||`` and its gain along S_2's
    weakest axis ``|w_j . u|`` (weights with sigma_c = mean folded in), and the linearised
    prediction of the RMS distance (:func:`predicted_rms`).
    """
    weak = np.linalg.eigh(S2)[1][:, 0]
    rows = []
    n, trials = 8, cfg.robustness_trials
    for radius_m in cfg.robustness_radii_m:
        for kind in ("symmetric", "cvt"):
            off = paper_formation(kind, n, radius_m)
            w, _ = estimator_weights(off, kind, centred=False)  # the paper's Remark
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
                               noise_std=std, method=kind, rotate=rotate, seed=NOISE_SEED,
                               sigma_c="remark")
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
                        "predicted_rms_m": predicted_rms(w, std_j, rotate),
                    })
    return rows


def robustness_summary(rows: list[dict]) -> list[dict]:
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
