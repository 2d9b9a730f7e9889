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
from experiments.sweep import (SIMULATE_COLUMNS, Progress, RowWriter, add_sweep_arguments, rows_file_problem, run_sweep,
                               summary, summary_lines, sweep_flag_problem)
from wire.cli_args import fail, float_in_range, int_in_range, nonnegative_float, positive_float

__all__ = ["configure", "main", "run", "report_lines", "trial_row", "sweep_trial", "resolve_defaults"]

_PROG = "swarmseek simulate"
_DEFAULT_STARTS = {"sigma1": "10,50,10", "sigma2": "20,-20,5"}
#: the plume fields' release (ENU m) and the default start's distance down the wind from it (2 m lower)
PLUME_SOURCE_ENU, PLUME_START_DOWNWIND_M = (0.0, 0.0, 15.0), 25.0
#: the paper's step (the gradient seeker's default ``--gamma``) and the other seekers' (``run``'s)
PAPER_GAMMA_M, SEEKER_GAMMA_M = 0.1, 20.0
#: the convergence test of the paper's gradient run (gamma 0.1 m: hundreds of small steps)
PAPER_WINDOW, PAPER_TOL_M = 400, 1.0
#: a mission plan's convergence test (``[seeking] convergence_window`` and ``convergence_tol_m``'s
#: defaults, :class:`mission.core.plan_types.SeekingPlan`; tests/experiments/test_sweep_simulate.py checks they agree)
MISSION_WINDOW, MISSION_TOL_M = 12, 0.5


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
    parser.add_argument("--field", choices=("sigma1", "sigma2", "plume", "intermittent"), default=None,
                        help="the paper's field (default sigma2), or a plume: plume (steady) or intermittent (puffs), "
                             "released at 0,0,15 m, wind from 270 deg at 2 m/s (docs/fields.md)")
    parser.add_argument("--field-python", default=None, metavar="PKG.MODULE:FACTORY",
                        help="your own field instead of --field: a factory importable from sys.path, called with "
                             "{'python': SPEC} (docs/fields.md, \"Your own field\")")
    parser.add_argument("--noise", type=nonnegative_float, default=0.0,
                        help="reading noise standard deviation (signal units)")
    parser.add_argument("--start", type=_vector3, default=None, metavar="E,N,U",
                        help="initial centre, ENU metres (default: sigma1 10,50,10; sigma2 20,-20,5; a plume: 25 m "
                             "down the wind of the release, 2 m lower; a plug-in: 20 m east and 20 m south of its "
                             "source)")
    parser.add_argument("--eps", type=positive_float, default=None,
                        help="the gradient seeker's step size (default 1)")
    parser.add_argument("--gamma", type=positive_float, default=None,
                        help=f"largest centre move per iteration, m (default {PAPER_GAMMA_M:g}, the paper's, for the "
                             f"gradient seeker; {SEEKER_GAMMA_M:g} for the others, as swarmseek run)")
    parser.add_argument("--seeker", choices=_seekers(), default=None,
                        help="how the centre moves (docs/seekers.md): the paper's gradient ascent "
                             "(the default on the paper's fields), Newton trust-region, the log-quadratic model, the "
                             "plume seeker (surge/cast) or ste (source-term estimation: a particle filter over the "
                             "release; the default on the plume fields)")
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
    seed = parser.add_mutually_exclusive_group()
    seed.add_argument("--seed", type=int_in_range(0, None, "--seed"), default=0, help="noise and CVT seed")
    add_sweep_arguments(parser, seed, "trial")
    parser.add_argument("--window", type=_positive(int), default=None,
                        help=f"convergence test window, iterations (default: {PAPER_WINDOW} for the gradient seeker, "
                             f"the paper's run; {MISSION_WINDOW}, a mission plan's, for the others)")
    parser.add_argument("--tol", type=positive_float, default=None,
                        help=f"convergence test tolerance, m (default: {PAPER_TOL_M:g} for the gradient seeker; "
                             f"{MISSION_TOL_M:g}, a mission plan's, for the others)")
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

    resolve_defaults(args)
    problem = _inapplicable_option(args)
    if problem:
        raise ValueError(problem)
    if getattr(args, "eps", None) is None:
        args.eps = 1.0
    if getattr(args, "min_signal_fraction", None) is None:
        args.min_signal_fraction = 1.0
    test_from = _resolve_test(args)
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
        "test_from": test_from, "min_signal_fraction": args.min_signal_fraction,
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


def resolve_defaults(args: argparse.Namespace) -> None:
    """Fill ``args.seeker`` and ``args.gamma`` when not given: on a plume field the best measured
    seeker (:func:`estimator.seekers.best_seeker`: ``ste``), else the paper's gradient ascent; its
    step the paper's 0.1 m, any other seeker's 20 m (``swarmseek run``'s)."""
    from estimator.seekers import BEST_SEEKER_BY_FIELD

    if getattr(args, "seeker", None) is None:
        args.seeker = BEST_SEEKER_BY_FIELD.get(getattr(args, "field", None), "gradient")
    if getattr(args, "gamma", None) is None:
        args.gamma = PAPER_GAMMA_M if args.seeker == "gradient" else SEEKER_GAMMA_M


def _resolve_test(args: argparse.Namespace) -> str:
    """Set ``args.window`` and ``args.tol`` when not given; where they come from: ``paper`` (the
    gradient seeker's defaults), ``plan`` (a mission plan's defaults, the other seekers') or
    ``options`` (one of them given)."""
    given = getattr(args, "window", None) is not None or getattr(args, "tol", None) is not None
    paper = getattr(args, "seeker", "gradient") == "gradient"
    if getattr(args, "window", None) is None:
        args.window = PAPER_WINDOW if paper else MISSION_WINDOW
    if getattr(args, "tol", None) is None:
        args.tol = PAPER_TOL_M if paper else MISSION_TOL_M
    return "options" if given else ("paper" if paper else "plan")


def _field_and_start(args: argparse.Namespace):
    """The field's name (``python:SPEC`` for a plug-in), the field (``--field`` or
    ``--field-python``) and the start (``--start``, else the field's default)."""
    from sitl_mock.fields_config import make_field

    if field_is_plugin(args):
        if getattr(args, "field", None) is not None:
            raise ValueError(f"give --field or --field-python, not both (--field {args.field})")
        field, name = _plugin_field(args.field_python), f"python:{args.field_python}"
        default_start = field.source_enu() + np.array([20.0, -20.0, 0.0])
    elif getattr(args, "field", None) in ("plume", "intermittent"):
        name = args.field
        field = make_field(name, PLUME_SOURCE_ENU)
        east, north = getattr(field, "steady", field).downwind_en
        default_start = np.asarray(PLUME_SOURCE_ENU) + (PLUME_START_DOWNWIND_M * east,
                                                        PLUME_START_DOWNWIND_M * north, -2.0)
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
    if args.seeker in ("plume", "ste") and getattr(args, "field", None) == "intermittent":
        kw["patchy"] = True  # hits and misses: a plan's plume_mode = "intermittent", the default there
    seeker = make_seeker(args.seeker, **kw)
    run = simulate_seeker(offsets, field, np.asarray(start, dtype=float)[None], seeker,
                          gamma_m=args.gamma, iterations=args.iterations, noise_std=args.noise,
                          rotate=False, seed=args.seed,
                          own_estimates=None if args.seeker == "ste" else args.tol)
    out = _SeekerRun(run.centres, field.source_enu(), run.signal)
    out.estimates_enu, out.regions_m, out.formation_centres = run.estimates_enu, run.regions_m, run.formation_centres
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
    """Run ``swarmseek simulate``; 0 on success, 2 on bad arguments (``--seeds``: 1 when a trial failed)."""
    problem = sweep_flag_problem(args)
    if problem:
        return fail(_PROG, f"error: {problem}")
    resolve_defaults(args)
    for warning in _ignored_option_warnings(args):
        print(f"swarmseek simulate: warning: {warning}", file=sys.stderr)
    if getattr(args, "seeds", None) is not None:
        return _sweep(args)
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


def _test_text(out: dict) -> str:
    """The convergence test's name with its window and tolerance, and where they come from."""
    w, tol = out["window"], out["tol_m"]
    origin = {"paper": f"the paper's gradient run's; a mission plan's default is window {MISSION_WINDOW}, "
                       f"tolerance {MISSION_TOL_M:g} m",
              "plan": "a mission plan's defaults",
              "options": "--window, --tol"}.get(out.get("test_from"), "--window, --tol")
    return f"convergence test (a mission's test, here window {w} iterations, tolerance {tol:g} m: {origin})"


def _why_not_lines(out: dict) -> list[str]:
    """Why the test never passed, from its verdict over the run's last window."""
    last = out.get("last_window")
    if last is None:
        return [f"  the run's {out['final_iteration']} iterations are fewer than the test's window of {out['window']}"]
    why = []
    if last["spread_m"] > out["tol_m"]:
        why.append(f"the centres spread {last['spread_m']:.3f} m (over the tolerance; up to "
                   f"{last['max_distance_m']:.3f} m from the source)")
    elif last["net_m"] > 0.5 * last["walk_m"]:
        why.append(f"the centre is still going somewhere (net move {last['net_m']:.3f} m, more than half "
                   f"the {last['walk_m']:.3f} m a random walk of the same steps would make)")
    if last["signal_fraction"] < out.get("min_signal_fraction", 0.0) - 1e-12:
        why.append(f"a detection in {100 * last['signal_fraction']:.0f} % of them (--min-signal-fraction "
                   f"{out['min_signal_fraction']:g})")
    if not why:
        why.append("the steps do not decay fast enough to call the centre settled")
    return [f"  over the last {out['window']} iterations " + "; ".join(why)]


def _check_options(args: argparse.Namespace) -> str | None:
    """What :func:`run` would refuse, found before a sweep starts (else every trial's row would be
    the same error): an option of another seeker, moving sampling for a stop-and-go seeker, an
    impossible formation or window, a plug-in field that does not load."""
    import formation

    problem = _inapplicable_option(args)
    if problem:
        return problem
    if getattr(args, "sampling", "stop_and_go") == "moving" and args.seeker not in MOVING_SEEKERS:
        return f"--sampling moving needs --seeker model, newton or ste, got {args.seeker}"
    if args.window is not None and args.window < 8:
        return f"--window must be at least 8 iterations, got {args.window}"
    try:
        if args.formation == "symmetric":
            formation.symmetric_cylinder(args.n, args.radius)
        else:
            formation.cvt_sphere(args.n, args.radius, seed=0)
        _field_and_start(args)
    except ValueError as exc:
        return str(exc)
    return None


def trial_row(out: dict, wall_s: float) -> dict:
    """The sweep row of one trial's :func:`run` result (:data:`experiments.sweep.SIMULATE_COLUMNS`):
    ``error_m`` is the estimated source's (where a mission would stop; None when never converged)."""
    return {"seed": out["seed"], "n": out["n"], "field": out["field"], "seeker": out["seeker"],
            "outcome": "converged" if out["converged"] else "not_converged", "error_m": out["estimate_error_m"],
            "estimate_region95_m": out.get("region95_m"),
            "iterations": out["converged_at_iteration"] if out["converged"] else out["final_iteration"],
            "distance_flown_m": round(out["distance_flown_m"], 6), "final_distance_m": round(out["final_distance_m"], 6),
            "wall_s": round(wall_s, 3), "reason": ""}


def sweep_trial(options: dict, seed: int) -> dict:
    """One trial of ``options`` (a ``simulate`` namespace's values) with ``seed``; its row (picklable:
    runs in a sweep's worker process too)."""
    import time

    args = argparse.Namespace(**options)
    args.seed = seed
    t0_s = time.perf_counter()
    out = run(args)
    return trial_row(out, time.perf_counter() - t0_s)


def _sweep(args: argparse.Namespace) -> int:
    """``--seeds``: one trial per seed; 0 when every trial ran, 1 when one failed, 2 for bad options."""
    import functools
    import time

    problem = _check_options(args) or rows_file_problem(args.sweep_out)
    if problem:
        return fail(_PROG, f"error: {problem}")
    try:
        writer = RowWriter(args.sweep_out, SIMULATE_COLUMNS)
    except OSError as exc:
        return fail(_PROG, f"error: {rows_file_problem(args.sweep_out, exc)}")
    skip = ("command_module", "command_parser", "seeds", "jobs", "sweep_out")
    options = {k: v for k, v in vars(args).items() if k not in skip}
    progress, jobs, t0_s = Progress(_PROG, len(args.seeds)), args.jobs or 1, time.perf_counter()

    def on_row(row):
        writer.write(row)
        progress.update(row)

    base = {"n": args.n, "field": _field_and_start(args)[0], "seeker": args.seeker}
    try:
        rows = run_sweep(args.seeds, functools.partial(sweep_trial, options), jobs=jobs, on_row=on_row, base=base)
    except OSError as exc:  # the rows file became unwritable (disk full...)
        return fail(_PROG, f"cannot write the rows file: {exc}", 1)
    finally:
        writer.close()
    summ = summary(rows, time.perf_counter() - t0_s, jobs, len(args.seeds))
    print(json.dumps(summ, indent=2) if args.json else "\n".join(summary_lines(_PROG, summ, args.sweep_out)))
    return 1 if any(r["outcome"] == "error" for r in rows) else 0


def _own_estimate_line(out: dict) -> str:
    """The seeker's own estimate where a mission would stop, with its 95 % region, or why it has none."""
    own = out.get("seeker_estimate_enu")
    if own is None and out.get("region95_m") is not None:
        return "  the ste seeker's own estimate is its posterior: its mean and 95 % region at the run's end, below"
    if own is None:
        return (f"  the {out['seeker']} seeker keeps no estimate of its own: the window's spread is the "
                "estimate's uncertainty")
    region = out.get("seeker_region95_m")
    region_text = (f"its 95 % region not within {out['tol_m']:g} m there (estimator.seek_confirm computes it only "
                   "then)" if region is None else f"95 % region {region:.3f} m")
    return (f"  the seeker's own estimate there {np.round(own, 3).tolist()}, {region_text}: "
            f"{out['seeker_estimate_error_m']:.3f} m from the true source")


def report_lines(out: dict) -> list[str]:
    """The human-readable result of :func:`run`: the stop a mission would make, then the run's end."""
    r3 = lambda v: np.round(v, 3).tolist()  # noqa: E731
    test = _test_text(out)
    lines = []
    if out["converged"]:
        if out.get("converged_by") == "region":
            lines += [f"the seeker's 95 % region held below {out['tol_m']:g} m with the formation on it "
                      f"(estimator.seek_confirm) at iteration {out['converged_at_iteration']}: a mission would stop "
                      f"there (the window test: {out['window_converged_at_iteration']})",
                      f"  estimated source {r3(out['estimated_source_enu'])} (the seeker's own): "
                      f"{out['estimate_error_m']:.3f} m from the true source"]
        else:
            lines += [f"{test} passed at iteration {out['converged_at_iteration']}: a mission would stop there",
                      f"  estimated source {r3(out['estimated_source_enu'])} (mean of the window's centres, spread "
                      f"{out['estimate_spread_m']:.3f} m): {out['estimate_error_m']:.3f} m from the true source"]
        lines.append(f"  centre there {r3(out['centre_at_convergence_enu'])}: "
                     f"{out['centre_at_convergence_distance_m']:.3f} m from the true source")
        lines.append(_own_estimate_line(out))
    else:
        lines.append(f"{test} never passed: not converged, no estimated source")
        lines += _why_not_lines(out)
    goes_on = " (the run goes on past convergence)" if out["converged"] and not out["stopped_at_convergence"] else ""
    grad = out["final_gradient_error"]
    grad_text = "" if grad is None else f", gradient error {grad:.3g}"
    lines.append(f"after {out['final_iteration']} iterations{goes_on}: centre {r3(out['final_centre_enu'])}, "
                 f"{out['final_distance_m']:.3f} m from the true source{grad_text}")
    if goes_on:
        verdict = "passes" if out["converged_at_end"] else "does not pass"
        lines.append(f"  the test over the last {out['window']} iterations {verdict}; their mean is "
                     f"{out['final_window_error_m']:.3f} m from the true source")
    if out.get("region95_m") is not None:
        lines.append(f"the ste posterior at the end: estimate {r3(out['posterior_estimate_enu'])}, 95 % region "
                     f"{out['region95_m']:.3f} m, {out['posterior_error_m']:.3f} m from the true source (arrival "
                     f"{'yes' if out['posterior_arrival'] else 'no'}, misfit {'yes' if out['posterior_misfit'] else 'no'})")
    return lines
