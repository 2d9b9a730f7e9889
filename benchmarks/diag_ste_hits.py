"""The ``ste`` seeker's intermittent-plume hit model against the simulated puff plume (no assertions).

For the default ``intermittent`` field (release (0, 0, 15), west wind 2 m/s, class C, s0 = 1 m)
at points along and across the wind at the release height: the empirical hit rate (readings
above the background + 0.03, i.e. 3 x the 1 % noise) over independent times, the mean reading,
and :func:`estimator.ste_model.hit_probability` / :func:`estimator.ste_model.plume_mean` (puff
mean) with the true parameters; then the ``(pi0, beta, s)`` of a small grid that best fits the
hit rates (binomial log-likelihood). The seeker's defaults come from this fit.

Usage::

    python benchmarks/diag_ste_hits.py [--times 300]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402


def main(argv=None) -> int:
    """Print the table and the fit."""
    from estimator.ste_model import hit_probability, plume_mean
    from sitl_mock.fields_config import make_field

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--times", type=int, default=300, help="independent times (97 s apart)")
    args = ap.parse_args(argv)
    field = make_field("intermittent", np.array([0.0, 0.0, 15.0]))
    pts = np.array([[x, y, 15.0] for x in (-3, -2, -1, -0.5, 0, 0.5, 1, 2, 4, 8, 15, 25, 40) for y in (0, 1, 2, 4)])
    vals = np.stack([field.value(pts, t) for t in np.arange(args.times) * 97.0])
    threshold = 0.03
    emp = ((vals - field.background) > threshold).mean(axis=0)
    params = np.array([[[0.0, 0.0, 15.0, 0.0, 0.0]]])  # release, A = 1, wind toward east
    mu, g = plume_mean(params, pts[None], smooth=True)
    fits = []
    for pi0 in (0.5, 0.55, 0.6, 0.65, 0.7):
        for beta in (0.6, 0.8, 1.0, 1.2):
            for s in (1.0, 1.3, 1.6):
                ph = hit_probability(mu, g, threshold=threshold, pi0=pi0, beta=beta, log_sd=s, eps=0.0)[0, 0]
                ll = np.sum(args.times * (emp * np.log(ph + 1e-9) + (1 - emp) * np.log(1 - ph + 1e-9)))
                fits.append((ll, pi0, beta, s))
    ll, pi0, beta, s = max(fits)
    ph = hit_probability(mu, g, threshold=threshold, pi0=pi0, beta=beta, log_sd=s, eps=0.0)[0, 0]
    print(f"best fit: pi0 = {pi0}, beta = {beta}, s = {s} (log-likelihood {ll:.1f})")
    print("| x, m | y, m | hit rate | model | mean reading | model mean |")
    print("|---|---|---|---|---|---|")
    for i, p in enumerate(pts):
        print(f"| {p[0]:g} | {p[1]:g} | {emp[i]:.2f} | {ph[i]:.2f} | {vals[:, i].mean():.4f} | {mu[0, 0, i]:.4f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
