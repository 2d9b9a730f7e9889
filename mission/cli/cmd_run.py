"""``swarmseek run``: fly the whole mission against an embedded mock fleet.

With no options: 8 PX4-personality mock vehicles, CVT formation of radius 4 m, the paper's
``sigma_2`` source somewhere in a box, the formation starting 25 m away, 10x speed-up (see
:mod:`mission.sim.embedded` for the defaults and the choice of ``eps``), the ``model`` seeker sampling
while moving (:mod:`mission.flight.phases.seek_moving`). Shows live progress, writes
the mission log (and one ``.tlog`` per vehicle) under ``--log-dir``; exits 0 when the mission
converged, 1 otherwise (stops by a signal or a failing mission log: as ``fly``, 129, 130, 141, 143,
74). The terminal is best effort (:mod:`mission.telemetry.terminal`).
"""
from __future__ import annotations

import argparse
import asyncio
import dataclasses
import sys
import time
from pathlib import Path

from estimator.seekers import MOVING_SEEKERS, SEEKERS
from experiments.sweep import add_sweep_arguments, sweep_flag_problem
from mission.cli.cmd_map import add_map_option, start_map_thread
from mission.cli.common import add_mission_outputs
from mission.link.forward import ForwardAddressError, forwarding, plan_with_outs, resolve_outs
# the mission's modules are imported with the command, before any event loop starts: a first import
# inside the loop is one callback of 0.3 s (tests/mission/sim/test_loop_debug.py)
from estimator.seekers import best_seeker
from mission.core.plan_types import SeekingPlan
from mission.core.zenoh_open import open_session
from mission.flight.coordinator import Coordinator
from mission.flight.operator_stop import run_until_stopped
from mission.flight.result import geodetic_point
from mission.sim.fleet_report import vehicle_rejections, world_errors_line
from mission.telemetry.mission_log import MissionLog
from mission.telemetry.state_pub import MAP_RATE_HZ, WALL_CLOCK_RATE_HZ
from mission.telemetry.terminal import best_effort_terminal, told_to
from mission.telemetry.watch_keys import with_keys

import numpy as np

from sitl_mock.cli_args import add_field_arguments, field_from_args, field_kind, probe_custom_field
from wire.cli_args import (fail, float_in_range, int_in_range, nonnegative_float, positive_float, source_enu,
                           usage_error)
from wire.zenoh_flags import add_endpoint_arguments

__all__ = ["configure", "main", "run_embedded"]

_PROG = "swarmseek run"
#: wall seconds of silence from a vehicle ``run --speedup`` tolerates (:func:`link_timeout_for_speedup`)
WALL_STALL_S = 0.5


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``run`` options."""
    parser.add_argument("--n", type=int, default=8, help="number of vehicles (4..254; default 8)")
    parser.add_argument("--formation", choices=("cvt", "symmetric"), default="cvt")
    parser.add_argument("--radius", type=positive_float, default=None,
                        help="formation radius D, m (default 4; 1.5 n^(1/3) above 18 vehicles)")
    add_field_arguments(parser, "sigma2")
    parser.add_argument("--noise", type=nonnegative_float, default=0.01,
                        help="sensor noise standard deviation, signal units (default 0.01)")
    parser.add_argument("--personality", choices=("px4", "ardupilot"), default="px4")
    parser.add_argument("--realtime", action="store_true",
                        help="run the fleet and the ground station on the wall clock (threads, real time "
                             "unless --speedup) instead of the default lock-step simulated clock")
    parser.add_argument("--speedup", type=positive_float, default=None,
                        help="with the wall clock: simulated seconds per wall second (implies --realtime; "
                             "the default lock-step clock runs as fast as the CPU allows)")
    seed = parser.add_mutually_exclusive_group()
    seed.add_argument("--seed", type=int_in_range(0, None, "--seed"), default=0, help="seed of the source position, noise, fleet")
    add_sweep_arguments(parser, seed, "mission")
    parser.add_argument("--source", type=source_enu, default=None, metavar="E,N,U",
                        help="source position, ENU m (default: drawn from the seed in a box)")
    parser.add_argument("--start", type=source_enu, default=None, metavar="E,N,U",
                        help="formation start, ENU m (default: 25 m from the source)")
    parser.add_argument("--eps", type=positive_float, default=None,
                        help="step gain (default 1/(2 A lambda_max(S)) of the field; paper: 1)")
    parser.add_argument("--gamma", type=positive_float, default=None,
                        help="largest step, m (default 1 for the gradient seeker, 20 for the others; paper 0.1)")
    parser.add_argument("--seeker", choices=SEEKERS, default=None,
                        help="how the centre moves: a log-quadratic model fit in a trust region (default), "
                             "a Newton trust-region step, the paper's gradient ascent, the plume seeker "
                             "(surge up the plume, cast when lost) or ste (source-term estimation: a posterior "
                             "over the release; the default with --field plume/intermittent; docs/seekers.md)")
    parser.add_argument("--plume-mode", choices=("steady", "intermittent"), default=None,
                        help="the plume and ste seekers' variant: steady (plume: surge, cast, passes, hold; ste: "
                             "the mean field's likelihood) or intermittent (plume: follow the upwind edge of the "
                             "detections; ste: hits and misses; default with --field intermittent)")
    parser.add_argument("--seek-wind-from", type=float_in_range(0.0, 360.0), default=None, metavar="DEG",
                        help="the wind direction the ground station gives the plume or ste seeker (where it "
                             "comes from, degrees clockwise from north, e.g. the --wind-from of the simulated "
                             "plume: an anemometer); default: the seeker estimates the plume's axis")
    parser.add_argument("--sampling", choices=("stop_and_go", "moving"), default=None,
                        help="stop_and_go: fly to each new centre, settle, read, estimate; moving: estimate "
                             "while flying from every reading since the last estimate (newton/model/ste only; "
                             "default: moving for those, stop_and_go for gradient and plume; docs/seekers.md)")
    parser.add_argument("--replan-fraction", type=positive_float, default=None, metavar="F",
                        help="with --sampling moving: re-plan once this fraction of a move is flown (0-1, "
                             "default 0.5)")
    parser.add_argument("--sensor-lag", type=nonnegative_float, default=None, metavar="S",
                        help="the mission's knowledge of the sensor's time constant, s: with --sampling moving "
                             "a reading is placed where its vehicle was S earlier (default: the simulated "
                             "sensor's --sensor-tau)")
    parser.add_argument("--estimator", choices=("cvt", "symmetric", "robust"), default=None,
                        help="gradient estimator (default: the formation's)")
    parser.add_argument("--faulty-sensor", choices=("retire", "keep", "off"), default="retire",
                        help="faulty-sensor handling, with every seeker and estimator: the robust estimator's "
                             "detection leaves a stuck/biased/spiking sensor's readings out of the seeker's input; "
                             "retire (default): a sensor named stuck or noisy for 20 iterations is retired (its "
                             "vehicle parked at the formation centre); keep: detection only; off: none (docs/faults.md)")
    parser.add_argument("--fence-side", type=positive_float, default=None, metavar="M",
                        help="the embedded plan's geofence: a square of this side (m), placed at random from the "
                             "seed to hold the source, the start and the takeoff area (the side grows where it "
                             "cannot; default: the 300 m square)")
    parser.add_argument("--prior-box", choices=("fence", "none"), default=None,
                        help="the ste seeker's [seeking] prior_box: fence bounds its prior by the geofence's box "
                             "(default: the plan's default, fence; docs/seekers.md, Round 6)")
    parser.add_argument("--max-iterations", type=int, default=300)
    parser.add_argument("--return", dest="return_behaviour", choices=("land", "rtl"), default="land")
    add_mission_outputs(parser, "run")
    add_map_option(parser)
    add_endpoint_arguments(
        parser, listen_help="the ground station also listens here, for `swarmseek watch` / `ctl` (repeatable)")
    # set later, before the mission flies: the simulated sensor's response (_field_setup) and the
    # ``--out`` hosts resolved before any loop starts (_resolve_outs, run_embedded)
    parser.set_defaults(sensor_response=None, forward_addresses=None)


#: ``--seeker`` when not given, by ``--field``: the best measured in whole missions there
#: (docs/seekers.md, "ste in missions"; README, "Seeking faster"); ``model`` for the others
def _resolve_seeker(args) -> str:
    """``--seeker``, or when not given the best measured for the field (as a plan's default:
    :func:`estimator.seekers.best_seeker`)."""
    if args.seeker is None:
        args.seeker = best_seeker(args.field)
    return args.seeker


def _check_args(args) -> str | None:
    from mission.sim.embedded import MAX_VEHICLES

    _resolve_seeker(args)
    if args.n < 4:
        return f"--n must be at least 4 (a formation needs 4 vehicles), got {args.n}"
    if args.n > MAX_VEHICLES:
        return (f"--n must be at most {MAX_VEHICLES} (MAVLink system ids 1..254; 255 is the ground station's), "
                f"got {args.n}")
    if args.formation == "symmetric" and args.n % 2:
        return f"--formation symmetric needs an even --n, got {args.n}"
    if args.sampling == "moving" and args.seeker not in MOVING_SEEKERS:
        return (f"--sampling moving needs --seeker model, newton or ste, got {args.seeker}: the paper's gradient seeker "
                "estimates from the formation's shape at rest (Theorem 2) and the plume seeker compares readings "
                "taken at rest; both sample stop and go")
    if args.replan_fraction is not None and not 0 < args.replan_fraction <= 1:
        return f"--replan-fraction must be in (0, 1], got {args.replan_fraction:g}"
    if args.max_iterations < 1:
        return f"--max-iterations must be >= 1, got {args.max_iterations}"
    problem = _inapplicable_option(args)
    if problem:
        return problem
    try:
        field, source, start = _field_setup(args)
        _probe_field(args, field, source, start)
    except ValueError as exc:
        return str(exc)
    _warn_ignored_options(args)  # valid options: say which of them this mission does not use
    return None


def _sampling(args) -> str:
    """``--sampling``, or the seeker's default: moving for newton/model, stop and go otherwise."""
    if args.sampling is not None:
        return args.sampling
    return "moving" if _resolve_seeker(args) in MOVING_SEEKERS else "stop_and_go"


def _inapplicable_option(args) -> str | None:
    """Why an option given cannot apply to this mission's seeker or sampling (docs/seekers.md,
    "Options that do not apply"), or None. An option of another seeker or sampling mode asks
    for a behaviour the mission would not have: refused, never ignored."""
    seeker, sampling = _resolve_seeker(args), _sampling(args)
    if seeker not in ("plume", "ste"):
        for flag, value in (("--plume-mode", args.plume_mode), ("--seek-wind-from", args.seek_wind_from)):
            if value is not None:
                return (f"{flag} applies to the plume and ste seekers only (--seeker plume, or --seeker ste, "
                        f"the default with --field plume/intermittent); this mission's seeker is {seeker}")
    if seeker != "ste" and args.prior_box is not None:
        return f"--prior-box applies to the ste seeker only; this mission's seeker is {seeker}"
    if sampling != "moving":
        for flag, value in (("--replan-fraction", args.replan_fraction), ("--sensor-lag", args.sensor_lag)):
            if value is not None:
                return (f"{flag} applies to sampling while moving only (--sampling moving, the default of "
                        f"the model, newton and ste seekers); this mission samples {sampling} ({seeker} seeker)")
    return None


def _warn_ignored_options(args, prog: str = "swarmseek run") -> list[str]:
    """Print (once, on stderr) a warning for each harmless option this mission does not use:
    ``--eps`` is the step gain of the gradient seeker only. Returns the warnings."""
    warnings = []
    if args.eps is not None and _resolve_seeker(args) != "gradient":
        warnings.append(f"{prog}: warning: --eps is the gradient seeker's step gain; the {args.seeker} seeker "
                        "does not use it (its step is bounded by --gamma)")
    for line in warnings:
        print(line, file=sys.stderr)
    return warnings


def _field_setup(args):
    """The field, its source and the formation's start (``args.field_name``, ``args.sensor_response``
    set; ``args.field`` too for a built-in field). A plug-in or grid field's source is its
    ``source_enu()``; ``--source`` reaches a plug-in as its table's ``source_enu_m``."""
    from mission.sim.embedded import FENCE_MIN_ALT_M, default_radius_m, default_source_and_start, downwind_en

    radius_m = args.radius if args.radius is not None else default_radius_m(args.n)
    d_source, _ = default_source_and_start(args.seed)
    if field_kind(args) == "builtin":
        source = d_source if args.source is None else np.asarray(args.source, dtype=float)
        args.field, field, args.sensor_response = field_from_args(args, source)
        args.field_name = args.field
    else:
        args.field_name, field, args.sensor_response = field_from_args(args, args.source)
        source = field.source_enu()
    d_source, d_start = default_source_and_start(args.seed, downwind=downwind_en(field))
    if args.start is None:
        start = source + (d_start - d_source)
        start[2] = max(start[2], FENCE_MIN_ALT_M + radius_m + 1.0)  # the lowest slot 1 m inside the fence
    else:
        start = np.asarray(args.start, dtype=float)
    return field, source, start


def _probe_field(args, field, source, start) -> None:
    """A plug-in or grid field read at the fence's corners and centre, the start and the source, at
    the mission's first time and later (:func:`sitl_mock.cli_args.probe_custom_field`).

    Raises
    ------
    FieldPluginError
        One line naming the plug-in or file.
    """
    from mission.sim.embedded import FENCE_MAX_ALT_M, FENCE_MIN_ALT_M, FENCE_POLYGON_EN_M
    from mission.sim.lockstep import LOCKSTEP_T0_S
    from sitl_mock.fields_plugin import probe_points_enu

    t0_s = time.time() if (args.realtime or args.speedup is not None) else LOCKSTEP_T0_S
    points = probe_points_enu(FENCE_POLYGON_EN_M, FENCE_MIN_ALT_M, FENCE_MAX_ALT_M, extra=[start, source])
    probe_custom_field(field, t0_s, points)


def _mission_setup(args):
    """The plan, field, source and start of the embedded mission ``args`` describe."""
    from mission.sim.embedded import (DEFAULT_ORIGIN, default_eps, default_radius_m, embedded_plan, fleet_ports,
                                      search_fence_en_m)
    from mission.core.plan_types import replace_plan

    radius_m = args.radius if args.radius is not None else default_radius_m(args.n)
    field, source, start = _field_setup(args)
    eps = args.eps if args.eps is not None else default_eps(field)
    ports = fleet_ports(args.n, args.personality)
    if args.gamma is None:
        args.gamma = 1.0 if args.seeker == "gradient" else 20.0
    plan = embedded_plan(args.n, ports, personality=args.personality, formation=args.formation,
                         radius_m=radius_m, start_enu_m=start, eps=eps, gamma_m=args.gamma,
                         estimator=args.estimator, max_iterations=args.max_iterations,
                         return_behaviour=args.return_behaviour, origin=DEFAULT_ORIGIN)
    plan = plan_with_outs(plan, args.out)
    faulty = args.faulty_sensor or plan.faults.faulty_sensor
    plan = dataclasses.replace(plan, faults=dataclasses.replace(
        plan.faults, faulty_sensor=faulty, link_timeout_s=link_timeout_for_speedup(plan.faults.link_timeout_s,
                                                                                   args.speedup)))
    if args.zenoh_listen:  # reachable by `swarmseek watch` / `ctl`
        plan = replace_plan(plan, zenoh=dataclasses.replace(plan.zenoh, listen=tuple(args.zenoh_listen)))
    plan = dataclasses.replace(plan, seeking=dataclasses.replace(plan.seeking, **_seeking_options(args)))
    if args.fence_side is not None:
        plan = replace_plan(plan, geofence=dataclasses.replace(plan.geofence, polygon_en_m=search_fence_en_m(
            args.fence_side, [source[:2], start[:2], (0.0, 0.0)], radius_m + 5.0, args.seed)))
    return plan, ports, field, source, start, eps


def link_timeout_for_speedup(link_timeout_s: float, speedup: float | None) -> float:
    """The loss timeout, simulated s, of a mission flown on the wall clock ``speedup`` times faster
    than real time: at least :data:`WALL_STALL_S` of wall clock (``speedup`` None: lock-step or
    real time, ``link_timeout_s`` unchanged).

    The fleet and the ground station share the host: a stall of ``t`` wall seconds (a loaded
    machine) is ``speedup * t`` simulated seconds of silence from every vehicle at once, which at
    10x and the plan's 1 s took a 0.1 s stall for the loss of the whole fleet. A vehicle that
    really stops talking is still declared lost, :data:`WALL_STALL_S` of wall clock later.
    """
    if speedup is None:
        return link_timeout_s
    return max(link_timeout_s, WALL_STALL_S * speedup)


def _seeking_options(args) -> dict:
    """The ``[seeking]`` keys the ``run`` options set: the seeker, its sampling and re-plan fraction."""
    sampling = _sampling(args)  # moving pays for the seekers that can use it (docs/seekers.md)
    mode = args.plume_mode or ("intermittent" if args.field == "intermittent"
                                                  else "steady")
    out = {"seeker": args.seeker, "sampling": sampling, "wind_from_deg": args.seek_wind_from,
           "plume_mode": mode}
    if args.replan_fraction is not None:
        out["replan_fraction"] = args.replan_fraction
    lag_s = args.sensor_lag
    if lag_s is None:  # the operator knows the sensor: the simulated one's time constant
        lag_s = (args.sensor_response or {}).get("time_constant_s", 0.0)
    out["sensor_lag_s"] = float(lag_s)
    if args.seeker == "ste":
        out.update(_ste_sensor(args))
        if args.prior_box is not None:
            out["prior_box"] = args.prior_box
    return out


def _ste_sensor(args) -> dict:
    """The ``ste`` seeker's sensor keys: what the operator knows of the simulated sensor (its
    datasheet: ``--noise``, ``--detection-floor``); the wind, the stability class and the
    release are not given (the seeker's priors)."""
    floor = (args.sensor_response or {}).get("detection_floor", 0.0)
    noise = float(args.noise) if args.noise > 0 else SeekingPlan.sensor_noise_std  # no sensor is noise-free
    return {"sensor_noise_std": noise, "sensor_detection_floor": float(floor or 0.0)}


def _make_fleet(args, plan, ports, field, clock):
    from mission.sim.embedded import DEFAULT_ORIGIN
    from sitl_mock.fleet import MockFleet
    from sitl_mock.sensor_response import set_fleet_response

    fleet = MockFleet(n=args.n, personality=args.personality, field=field, origin=DEFAULT_ORIGIN,
                     clock=clock, seed=args.seed, udp_base_port=ports["udp_base_port"],
                     udp_bind_base_port=ports["udp_bind_base_port"], tcp_base_port=ports["tcp_base_port"],
                     fleet_name=plan.fleet, sensor_noise_std=args.noise,
                     zenoh_listen=[f"tcp/127.0.0.1:{ports['zenoh_port']}"])
    set_fleet_response(fleet, **args.sensor_response)
    return fleet


async def _fly(args, plan, fleet, setup, display, world=None, terminal=None, map_thread=None):
    """Fly ``plan`` against the started ``fleet`` (``args.log_dir`` created, ``args.forward_addresses``
    resolved: :func:`main`); returns the MissionResult (``terminal``: see :func:`mission.cli.cmd_fly.fly`;
    ``map_thread``: ``--map``'s, handed the mission's zenoh session, stopped before it closes)."""
    source, start, eps = setup
    log_dir = Path(args.log_dir)
    session = None
    log = MissionLog(log_dir / "mission.jsonl", fleet.clock)
    try:
        with told_to(terminal, log):
            session = await open_session(plan.zenoh)  # off the loop
            if map_thread is not None:
                map_thread.attach(session)
            log.event("embedded mock fleet", personality=args.personality, n=args.n, field=args.field_name,
                      field_model=repr(fleet.field), sensor_response=args.sensor_response,
                      source_enu=source, start_enu=start, noise=args.noise,
                      clock="lockstep" if world is not None else f"realtime x{fleet.clock.speedup:g}",
                      eps=eps, gamma_m=args.gamma, seeker=args.seeker, sampling=plan.seeking.sampling, seed=args.seed)
            co = Coordinator(plan, clock=fleet.clock, zenoh_session=session, log=log, display=display,
                             tlog_dir=None if args.no_tlog else log_dir / "tlogs", simulated_fleet=True,
                             state_rate_hz=_state_rate_hz(args, world))
            if world is not None:
                world.store = co.store
            mission = run_until_stopped(co.run(), co.state, co.log)
            work = with_keys(co.command, co.say, display, mission)  # keys on a terminal
            result = await forwarding(work, plan.forward, [v.sysid for v in plan.vehicles], co.event,  # --out
                                      co.watch_endpoints, args.forward_addresses)
            result.true_source_enu = [float(x) for x in source]
            result.true_source_geodetic = geodetic_point(plan.origin, source)
            if result.estimate_enu is not None:
                result.error_m = float(np.linalg.norm(np.asarray(result.estimate_enu) - source))
            result.vehicle_rejections = vehicle_rejections(fleet)
            log.write("truth", sync=True, source_enu=source, source_geodetic=result.true_source_geodetic,
                      error_m=result.error_m,
                      vehicle_rejections=result.vehicle_rejections)
            return result
    finally:
        if map_thread is not None:
            await map_thread.detach()  # the map shows the outcome and lets go of the session
        log.close()
        if session is not None:
            session.close()


def _state_rate_hz(args, world) -> float:
    """The state publication's rate: on the wall clock 10 Hz with ``--map``, 5 Hz without; on the
    lock-step clock 2 Hz of simulated time, many per wall second (a ``--map`` leaves a lock-step
    mission unchanged, record for record)."""
    if world is not None:
        return 2.0
    return MAP_RATE_HZ if args.map is not None else WALL_CLOCK_RATE_HZ


def run_embedded(args, display=None, terminal=None, map_thread=None):
    """Start the mock fleet, fly the mission, stop everything; returns the MissionResult.

    ``args`` as :func:`main` leaves them: with ``log_dir`` (created by
    :func:`mission.cli.paths.mission_log_dir` when None) and, for ``--out``, ``forward_addresses``
    (:func:`mission.link.forward.resolve_outs`, resolved before any loop starts).

    Lock-step by default (:mod:`mission.sim.lockstep`): one simulated clock for the fleet and
    the ground station, as fast as the CPU allows, reproducible for a seed. With
    ``args.realtime`` (or a ``--speedup``) the fleet runs on its own thread against the wall
    clock, ``speedup`` times faster than real time.
    """
    from mission.sim.embedded_world import EmbeddedWorld
    from mission.sim.lockstep import VirtualClock, run_lockstep
    from sitl_mock.clock import SimClock

    plan, ports, field, source, start, eps = _mission_setup(args)
    if map_thread is not None:
        map_thread.set_truth(source)
    if args.log_dir is None:
        from mission.cli.paths import DEFAULT_LOG_ROOT, new_log_dir

        args.log_dir = new_log_dir(DEFAULT_LOG_ROOT, "run")
    if plan.forward.out and args.forward_addresses is None:
        args.forward_addresses = resolve_outs(plan.forward.out)  # once, before the loop (ForwardAddressError)
    realtime = args.realtime or args.speedup is not None
    clock = SimClock(args.speedup or 1.0) if realtime else VirtualClock()
    fleet = _make_fleet(args, plan, ports, field, clock)
    fleet.start(thread=realtime)
    try:
        if realtime:
            return asyncio.run(_fly(args, plan, fleet, (source, start, eps), display, terminal=terminal,
                                    map_thread=map_thread))
        world = EmbeddedWorld(fleet)
        result = run_lockstep(lambda: _fly(args, plan, fleet, (source, start, eps), display, world, terminal,
                                           map_thread), clock, world)
        if world.stalls:
            print(f"swarmseek run: warning: {world.stalls} lock-step waits for zenoh ran out "
                  "(a reading was lost; this run may not be reproducible)", file=sys.stderr)
        return result
    finally:
        fleet.stop()
        errors = world_errors_line(fleet)
        if errors:
            print(f"swarmseek run: warning: {errors}", file=sys.stderr)


def _resolve_outs(args) -> str | None:
    """Resolve every ``--out`` host once, before anything starts (``args.forward_addresses``);
    the reason when one is invalid or does not resolve."""
    try:
        args.forward_addresses = resolve_outs(args.out or ())
    except ForwardAddressError as exc:
        return str(exc)
    return None


def main(args) -> int:
    """Run the embedded mission; 0 if it converged, 1 if not, 2 for bad options (stops: as ``fly``).
    With ``--seeds``: one mission per seed (:func:`mission.cli.run_sweep.sweep_main`)."""
    problem = sweep_flag_problem(args)
    if problem:
        return usage_error(_PROG, problem)
    with best_effort_terminal() as terminal:
        return _main(args, terminal)


def _sweep(args) -> int:
    """``--seeds``: the options checked once (with the first seed), then one mission per seed."""
    from mission.cli.run_sweep import sweep_main, sweep_problem

    args.seed = args.seeds[0]
    problem = sweep_problem(args) or _check_args(args)
    if problem:
        return usage_error(_PROG, problem)
    return sweep_main(args, _PROG, run_embedded)


def _main(args, terminal) -> int:
    from mission.telemetry.display import Display, report_result

    from mission.cli.paths import announce_log, mission_log_dir, summary_log_line

    if args.seeds is not None:
        return _sweep(args)
    problem = _check_args(args) or _resolve_outs(args)
    if not problem:
        args.log_dir, problem = mission_log_dir(args.log_dir, "run")
    if problem:
        return usage_error(_PROG, problem)
    import zenoh

    map_thread, status = start_map_thread(args, "swarmseek", _PROG)
    if status is not None:
        return status
    announce_log("run", args.log_dir / "mission.jsonl", args.json)
    display = Display(quiet=args.json)
    try:
        result = run_embedded(args, display=display, terminal=terminal, map_thread=map_thread)
    except (OSError, zenoh.ZError) as exc:
        return fail(_PROG, f"cannot start the embedded fleet or zenoh: {exc}", 1)
    finally:
        if map_thread is not None:
            map_thread.stop()
    status = report_result(result, display, args.json)
    if result.log_path:
        summary_log_line(Path(result.log_path), args.json)
    return status
