"""``swarmseek simulate``: one offline source-seeking run (perfect tracking, no MAVLink).

Prints the final distance to the source, the final gradient estimation error, the convergence
test's verdict and the estimated source; ``--json`` prints the same as one JSON object.
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from sitl_mock.cli_args import nonnegative_float, positive_float

__all__ = ["configure", "main", "run"]

_DEFAULT_STARTS = {"sigma1": "10,50,10", "sigma2": "20,-20,5"}


def _vector3(text: str) -> np.ndarray:
    try:
        parts = [float(x) for x in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected E,N,U in metres (3 numbers), got {text!r}") from None
    if len(parts) != 3 or not all(np.isfinite(parts)):
        raise argparse.ArgumentTypeError(f"expected E,N,U in metres (3 finite numbers), got {text!r}")
    return np.array(parts)


def _positive(kind):
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a positive {kind.__name__}, got {text!r}") from None
        if not (np.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"expected a positive {kind.__name__}, got {text!r}")
        return value

    return parse


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``simulate`` command's arguments."""
    parser.add_argument("--n", type=_positive(int), default=8, help="number of robots (default 8)")
    parser.add_argument("--formation", choices=("cvt", "symmetric"), default="cvt")
    parser.add_argument("--method", choices=("cvt", "symmetric"), default=None,
                        help="estimator: Theorem 2 or eq. (3) (default: the formation's)")
    parser.add_argument("--radius", type=positive_float, default=1.0, help="formation radius D, m")
    parser.add_argument("--field", choices=("sigma1", "sigma2"), default="sigma2")
    parser.add_argument("--noise", type=nonnegative_float, default=0.0,
                        help="reading noise standard deviation (signal units)")
    parser.add_argument("--start", type=_vector3, default=None, metavar="E,N,U",
                        help="initial centre, ENU metres (default: sigma1 10,50,10; sigma2 20,-20,5)")
    parser.add_argument("--eps", type=positive_float, default=1.0, help="step size (default 1)")
    parser.add_argument("--gamma", type=positive_float, default=0.1,
                        help="largest centre move per iteration, m (default 0.1)")
    parser.add_argument("--seeker", choices=("gradient", "newton", "model"), default="gradient",
                        help="how the centre moves (docs/seekers.md): the paper's gradient ascent "
                             "(default), Newton trust-region, or the log-quadratic model; newton and "
                             "model take --gamma as their largest step (give e.g. 20)")
    parser.add_argument("--iterations", type=_positive(int), default=3000)
    parser.add_argument("--seed", type=int, default=0, help="noise and CVT seed")
    parser.add_argument("--window", type=_positive(int), default=400,
                        help="convergence test window, iterations")
    parser.add_argument("--tol", type=positive_float, default=1.0,
                        help="convergence test tolerance, m")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def run(args: argparse.Namespace) -> dict:
    """Run the simulation described by ``args``; return the result summary.

    Raises
    ------
    ValueError
        Impossible formation (e.g. odd ``n`` for ``symmetric``), degenerate geometry, or a
        convergence window below 8.
    """
    import formation
    from estimator import convergence_scan
    from sitl_mock.fields import make_field
    from experiments.offline import simulate

    if args.formation == "symmetric":
        offsets = formation.symmetric_cylinder(args.n, args.radius)
    else:
        offsets = formation.cvt_sphere(args.n, args.radius, seed=args.seed)
    method = args.method or args.formation
    start = args.start if args.start is not None else _vector3(_DEFAULT_STARTS[args.field])
    field = make_field(args.field)
    seeker = getattr(args, "seeker", "gradient")
    if seeker == "gradient":
        res = simulate(offsets, field, start, eps=args.eps, gamma=args.gamma,
                       iterations=args.iterations, noise_std=args.noise, method=method, seed=args.seed)
        centres, grad_err = res.centres, float(res.error_norm()[-1, 0])
    else:
        centres, grad_err = _simulate_seeker(args, offsets, field, start)
    source = np.asarray(field.source_enu(), dtype=float)
    dist = np.linalg.norm(centres[:, 0] - source, axis=-1)
    first, est, spread = convergence_scan(centres, window=args.window, tol_m=args.tol)
    converged = bool(first[0] >= 0)
    return {
        "field": args.field, "formation": args.formation, "method": method, "n": args.n,
        "radius_m": args.radius, "noise_std": args.noise, "eps": args.eps, "gamma_m": args.gamma,
        "iterations": args.iterations, "seed": args.seed, "start_enu": start.tolist(),
        "seeker": seeker, "source_enu": source.tolist(),
        "final_centre_enu": centres[-1, 0].tolist(),
        "final_distance_m": float(dist[-1]),
        "final_gradient_error": grad_err,
        "converged": converged,
        "converged_at_iteration": int(first[0]) if converged else None,
        "estimated_source_enu": est[0].tolist() if converged else None,
        "estimate_error_m": float(np.linalg.norm(est[0] - source)) if converged else None,
        "estimate_spread_m": float(spread[0]) if converged else None,
    }


def _simulate_seeker(args, offsets, field, start):
    """Centres (T + 1, 1, 3) of one run of a newton/model seeker; the gradient error at the end
    of the fitted model (the seeker's own gradient, of ``log s`` for ``model``) is not comparable:
    NaN."""
    from estimator.seekers import make_seeker
    from experiments.offline_seek import simulate_seeker

    run = simulate_seeker(offsets, field, np.asarray(start, dtype=float)[None], make_seeker(args.seeker),
                          gamma_m=args.gamma, iterations=args.iterations, noise_std=args.noise,
                          rotate=False, seed=args.seed)
    return run.centres, float("nan")


def main(args: argparse.Namespace) -> int:
    """Run ``swarmseek simulate``; 0 on success, 2 on bad arguments."""
    try:
        out = run(args)
    except ValueError as exc:
        print(f"swarmseek simulate: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(out))
        return 0
    c = np.round(out["final_centre_enu"], 3).tolist()
    print(f"{out['field']}, {out['n']} robots, {out['formation']} formation (D = {out['radius_m']:g} m), "
          f"estimator {out['method']}, seeker {out['seeker']}, noise {out['noise_std']:g}, start {out['start_enu']}")
    print(f"after {out['iterations']} iterations: centre {c}, "
          f"distance to source {out['final_distance_m']:.3f} m, "
          f"gradient error {out['final_gradient_error']:.3g}")
    if out["converged"]:
        e = np.round(out["estimated_source_enu"], 3).tolist()
        print(f"converged at iteration {out['converged_at_iteration']}: estimated source {e} "
              f"(error {out['estimate_error_m']:.3f} m, spread {out['estimate_spread_m']:.3f} m)")
    else:
        print("not converged (convergence test never passed); estimated source: none")
    return 0
