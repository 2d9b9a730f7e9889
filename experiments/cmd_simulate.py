"""``swarmseek simulate``: one offline source-seeking run (perfect tracking, no MAVLink).

Uses the mission's convergence test (:func:`estimator.convergence_scan`, the same maths as the
:class:`estimator.ConvergenceMonitor` that ends a mission's seek) and reports two different
things, each with its own distance to the true source:

* where a mission with these settings would stop: the first iteration at which the test passes,
  the estimated source there (the mean of the window's centres, what a mission reports) and the
  centre's own position there;
* where the run is after all ``--iterations`` (it goes on past convergence unless
  ``--stop-at-convergence``): the centre, and the test over the last window.

``--json`` prints the same as one JSON object.
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from estimator.seekers import MOVING_SEEKERS
from wire.cli_args import fail, float_in_range, int_in_range, nonnegative_float, positive_float

__all__ = ["configure", "main", "run", "report_lines"]

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


def _seekers() -> tuple[str, ...]:
    from estimator.seekers import SEEKERS

    return SEEKERS


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``simulate`` command's arguments."""
    parser.add_argument("--n", type=_positive(int), default=8, help="number of robots (default 8)")
    parser.add_argument("--formation", choices=("cvt", "symmetric"), default="cvt")
    parser.add_argument("--method", choices=("cvt", "symmetric"), default=None,
                        help="estimator: Theorem 2 or eq. (3) (default: the formation's)")
    parser.add_argument("--radius", type=positive_float, default=1.0, help="formation radius D, m")
    parser.add_argument("--field", choices=("sigma1", "sigma2"), default=None, help="the paper's field (default sigma2)")
    parser.add_argument("--field-python", default=None, metavar="PKG.MODULE:FACTORY",
                        help="your own field instead of --field: a factory importable from sys.path, called with "
                             "{'python': SPEC} (docs/fields.md, \"Your own field\")")
    parser.add_argument("--noise", type=nonnegative_float, default=0.0,
                        help="reading noise standard deviation (signal units)")
    parser.add_argument("--start", type=_vector3, default=None, metavar="E,N,U",
                        help="initial centre, ENU metres (default: sigma1 10,50,10; sigma2 20,-20,5; a plug-in: "
                             "20 m east and 20 m south of its source)")
    parser.add_argument("--eps", type=positive_float, default=None,
                        help="the gradient seeker's step size (default 1)")
    parser.add_argument("--gamma", type=positive_float, default=0.1,
                        help="largest centre move per iteration, m (default 0.1)")
    parser.add_argument("--seeker", choices=_seekers(), default="gradient",
                        help="how the centre moves (docs/seekers.md): the paper's gradient ascent "
                             "(default), Newton trust-region, the log-quadratic model, the plume "
                             "seeker (surge/cast) or ste (source-term estimation: a particle filter over the "
                             "release, for plumes); all but gradient take --gamma as their largest step (give e.g. 20)")
    parser.add_argument("--seek-wind-from", type=float_in_range(0.0, 360.0), default=None,
                        metavar="DEG",
                        help="wind direction the plume or ste seeker is given (where it comes from, degrees from "
                             "north); default: it estimates the plume's axis")
    parser.add_argument("--min-signal-fraction", type=float_in_range(0.0, 1.0), default=None,
                        help="convergence criterion 3 for the seekers but gradient: a signal in at least this "
                             "fraction of the window (default 1, as a plan; 0: off; docs/seekers.md)")
    parser.add_argument("--sampling", choices=("stop_and_go", "moving"), default="stop_and_go",
                        help="stop_and_go (default) or moving: newton/model re-plan while the formation flies "
                             "at 3 m/s, from every reading since the last estimate (experiments.offline_moving; "
                             "docs/seekers.md)")
    parser.add_argument("--iterations", type=_positive(int), default=3000)
    parser.add_argument("--seed", type=int_in_range(0, None, "--seed"), default=0, help="noise and CVT seed")
    parser.add_argument("--window", type=_positive(int), default=400,
                        help="convergence test window, iterations")
    parser.add_argument("--tol", type=positive_float, default=1.0,
                        help="convergence test tolerance, m")
    parser.add_argument("--stop-at-convergence", action="store_true",
                        help="end the run where the convergence test first passes, as a mission does")
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
    from experiments.offline import convergence_report, simulate

    problem = _inapplicable_option(args)
    if problem:
        raise ValueError(problem)
    if getattr(args, "eps", None) is None:
        args.eps = 1.0
    if getattr(args, "min_signal_fraction", None) is None:
        args.min_signal_fraction = 1.0
    if args.formation == "symmetric":
        offsets = formation.symmetric_cylinder(args.n, args.radius)
    else:
        offsets = formation.cvt_sphere(args.n, args.radius, seed=args.seed)
    method = args.method or args.formation
    field_name, field, start = _field_and_start(args)
    seeker = getattr(args, "seeker", "gradient")
    sampling = getattr(args, "sampling", "stop_and_go")
    if sampling == "moving" and seeker not in MOVING_SEEKERS:
        raise ValueError(f"--sampling moving needs --seeker model, newton or ste, got {seeker} (the paper's gradient "
                         "seeker and the plume seeker sample stop and go)")
    if sampling == "moving":
        res = _simulate_moving(args, offsets, field, start)
    elif seeker == "gradient":
        res = simulate(offsets, field, start, eps=args.eps, gamma=args.gamma,
                       iterations=args.iterations, noise_std=args.noise, method=method, seed=args.seed)
    else:
        res = _simulate_seeker(args, offsets, field, start)
    out = {
        "field": field_name, "formation": args.formation, "method": method, "n": args.n,
        "radius_m": args.radius, "noise_std": args.noise, "eps": args.eps, "gamma_m": args.gamma,
        "iterations": args.iterations, "seed": args.seed, "start_enu": start.tolist(), "seeker": seeker,
        "sampling": sampling,
        "source_enu": np.asarray(res.source_enu, dtype=float).tolist(), "window": args.window, "tol_m": args.tol,
    }
    out.update(convergence_report(res, window=args.window, tol_m=args.tol,
                                  stop_at_convergence=args.stop_at_convergence,
                                  min_signal_fraction=getattr(args, "min_signal_fraction", 0.0)))
    post = getattr(res, "posterior", None)
    if post is not None:  # ste: its own estimate (the posterior mean), 95 % region and arrival
        est = np.asarray(post.estimate_enu[0], dtype=float)
        out.update(posterior_estimate_enu=est.tolist(), region95_m=float(post.region95_m[0]),
                   posterior_error_m=float(np.linalg.norm(est - np.asarray(res.source_enu, dtype=float))),
                   posterior_arrival=bool(post.arrival[0]), posterior_misfit=bool(post.misfit[0]))
    if sampling == "moving":  # mission time of the kinematic model, which the stop-and-go runs do not have
        t_1m = float(res.moving.time_within_s(1.0)[0])
        out["time_within_1m_s"] = t_1m if np.isfinite(t_1m) else None
    return out


def _field_and_start(args: argparse.Namespace):
    """The field's name (``python:SPEC`` for a plug-in), the field (``--field`` or
    ``--field-python``) and the start (``--start``, else the field's default)."""
    from sitl_mock.fields_config import make_field

    if field_is_plugin(args):
        if getattr(args, "field", None) is not None:
            raise ValueError(f"give --field or --field-python, not both (--field {args.field})")
        field, name = _plugin_field(args.field_python), f"python:{args.field_python}"
        default_start = field.source_enu() + np.array([20.0, -20.0, 0.0])
    else:
        name = getattr(args, "field", None) or "sigma2"
        field, default_start = make_field(name), _vector3(_DEFAULT_STARTS[name])
    return name, field, (args.start if args.start is not None else default_start)


def field_is_plugin(args: argparse.Namespace) -> bool:
    """True when the run's field is a plug-in (``--field-python``)."""
    return bool(getattr(args, "field_python", None))


def _plugin_field(spec: str):
    """The plug-in ``spec`` loaded with the table ``{"python": spec}`` and probed at the offline
    run's times (0 s on) around its source (+-50 m; the default start 20 m east, 20 m south).

    Raises
    ------
    FieldPluginError
        One line naming the plug-in (a ValueError: exit 2).
    """
    from sitl_mock.fields_plugin import load_plugin, probe_field, probe_points_enu

    field = load_plugin(spec, {"python": spec})
    src = field.source_enu()
    box = [(src[0] + e, src[1] + n) for e, n in ((-50, -50), (50, -50), (50, 50), (-50, 50))]
    probe_field(field, probe_points_enu(box, src[2] - 20.0, src[2] + 20.0, extra=[src, src + (20.0, -20.0, 0.0)]))
    return field


def _inapplicable_option(args: argparse.Namespace) -> str | None:
    """Why an option given cannot apply to this run's seeker (refused, never ignored), or None:
    ``--seek-wind-from`` is the plume seeker's, ``--method`` the gradient seeker's estimator."""
    seeker = getattr(args, "seeker", "gradient")
    if getattr(args, "seek_wind_from", None) is not None and seeker not in ("plume", "ste"):
        return (f"--seek-wind-from applies to the plume and ste seekers only (--seeker plume or ste); this run's "
                f"seeker is {seeker}")
    if getattr(args, "method", None) is not None and seeker != "gradient":
        return (f"--method (the gradient estimator) applies to the gradient seeker only; the {seeker} seeker "
                "fits its own model to the readings")
    return None


def _ignored_option_warnings(args: argparse.Namespace) -> list[str]:
    """Warnings for harmless options this run does not use: ``--eps`` with a seeker other than
    gradient (its step is bounded by ``--gamma``), ``--min-signal-fraction`` where the runs have no
    signal test (the gradient seeker, or sampling while moving)."""
    seeker = getattr(args, "seeker", "gradient")
    out = []
    if getattr(args, "eps", None) is not None and seeker != "gradient":
        out.append(f"--eps is the gradient seeker's step size; the {seeker} seeker does not use it")
    if getattr(args, "min_signal_fraction", None) is not None and (
            seeker == "gradient" or getattr(args, "sampling", "stop_and_go") == "moving"):
        out.append("--min-signal-fraction is a criterion of the stop-and-go newton, model and plume runs; "
                   "this run does not use it")
    return out


class _SeekerRun:
    """A newton/model seeker's run in the shape :func:`experiments.offline.convergence_report` reads
    (its gradient error is not comparable with the paper's estimator: NaN)."""

    def __init__(self, centres, source_enu, signal=None):
        self.centres = centres
        self.signal = signal
        self.source_enu = np.asarray(source_enu, dtype=float)
        self.grad_est = np.zeros((centres.shape[0] - 1,) + centres.shape[1:])

    def error_norm(self):
        return np.full(self.grad_est.shape[:2], np.nan)


def _simulate_seeker(args, offsets, field, start) -> _SeekerRun:
    """One run of a newton/model seeker (centres of shape (T + 1, 1, 3))."""
    from estimator.seekers import make_seeker
    from experiments.offline_seek import simulate_seeker

    kw = {"wind_from_deg": getattr(args, "seek_wind_from", None)} if args.seeker in ("plume", "ste") else {}
    if args.seeker == "ste" and args.noise > 0:
        kw["noise_std"] = args.noise  # the sensor's (the seeker's default, 0.01, for a noise-free run)
    seeker = make_seeker(args.seeker, **kw)
    run = simulate_seeker(offsets, field, np.asarray(start, dtype=float)[None], seeker,
                          gamma_m=args.gamma, iterations=args.iterations, noise_std=args.noise,
                          rotate=False, seed=args.seed)
    out = _SeekerRun(run.centres, field.source_enu(), run.signal)
    out.posterior = seeker if getattr(seeker, "region95_m", None) is not None else None
    return out


def _simulate_moving(args, offsets, field, start) -> _SeekerRun:
    """One run of a newton/model seeker sampling while moving (:mod:`experiments.offline_moving`)."""
    from experiments.offline_moving import simulate_moving

    moving = simulate_moving(offsets, field, np.asarray(start, dtype=float)[None], args.seeker, gamma_m=args.gamma,
                             iterations=args.iterations, noise_std=args.noise, rotate=False, seed=args.seed)
    run = _SeekerRun(moving.centres, field.source_enu())
    run.moving = moving
    return run


def main(args: argparse.Namespace) -> int:
    """Run ``swarmseek simulate``; 0 on success, 2 on bad arguments."""
    for warning in _ignored_option_warnings(args):
        print(f"swarmseek simulate: warning: {warning}", file=sys.stderr)
    try:
        out = run(args)
    except ValueError as exc:
        return fail("swarmseek simulate", str(exc))
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"{out['field']}, {out['n']} robots, {out['formation']} formation (D = {out['radius_m']:g} m), "
          f"estimator {out['method']}, seeker {out['seeker']}, noise {out['noise_std']:g}, start {out['start_enu']}")
    for line in report_lines(out):
        print(line)
    if out["sampling"] == "moving":
        t_1m = out["time_within_1m_s"]
        print("sampling while moving: " + ("the formation never stayed within 1 m" if t_1m is None else
                                           f"the formation within 1 m from {t_1m:.1f} s of mission time on"))
    return 0


def report_lines(out: dict) -> list[str]:
    """The human-readable result of :func:`run`: the stop a mission would make, then the run's end."""
    r3 = lambda v: np.round(v, 3).tolist()  # noqa: E731
    test = f"convergence test (the mission's: window {out['window']} iterations, tolerance {out['tol_m']:g} m)"
    lines = []
    if out["converged"]:
        lines += [f"{test} passed at iteration {out['converged_at_iteration']}: a mission would stop there",
                  f"  estimated source {r3(out['estimated_source_enu'])} (mean of the window's centres, spread "
                  f"{out['estimate_spread_m']:.3f} m): {out['estimate_error_m']:.3f} m from the true source",
                  f"  centre there {r3(out['centre_at_convergence_enu'])}: "
                  f"{out['centre_at_convergence_distance_m']:.3f} m from the true source"]
    else:
        lines.append(f"{test} never passed: not converged, no estimated source")
    goes_on = " (the run goes on past convergence)" if out["converged"] and not out["stopped_at_convergence"] else ""
    lines.append(f"after {out['final_iteration']} iterations{goes_on}: centre {r3(out['final_centre_enu'])}, "
                 f"{out['final_distance_m']:.3f} m from the true source, gradient error "
                 f"{out['final_gradient_error']:.3g}")
    if goes_on:
        verdict = "passes" if out["converged_at_end"] else "does not pass"
        lines.append(f"  the test over the last {out['window']} iterations {verdict}; their mean is "
                     f"{out['final_window_error_m']:.3f} m from the true source")
    if out.get("region95_m") is not None:
        lines.append(f"the ste posterior at the end: estimate {r3(out['posterior_estimate_enu'])}, 95 % region "
                     f"{out['region95_m']:.3f} m, {out['posterior_error_m']:.3f} m from the true source (arrival "
                     f"{'yes' if out['posterior_arrival'] else 'no'}, misfit {'yes' if out['posterior_misfit'] else 'no'})")
    return lines
