"""``swarmseek fly --plan plan.toml``: fly the mission against the vehicles named in a plan.

Readings come over zenoh (e.g. one ``swarmseek sensor`` per vehicle) on the plan's endpoints;
the mission clock is the wall clock. Exit status: 0 converged, 1 not converged or aborted
(also: not ready to seek, nothing armed), 2 invalid plan or options, 129 / 130 / 141 / 143
stopped by SIGHUP / SIGINT / SIGPIPE sent by another process / SIGTERM (the first brings the
vehicles home, a second lands them where they are), 74 the mission log could not be written (the
vehicles were brought home). The terminal is best effort (:mod:`mission.telemetry.terminal`): a
closed stdout or stderr never stops the mission. See docs/faults.md, "The ground station's own faults".
"""
from __future__ import annotations

import argparse
import asyncio
from pathlib import Path

from mission.cli.cmd_map import add_map_option, start_map_thread
from mission.cli.common import add_mission_outputs, add_plan_argument, load_plan_or_fail, run_or_fail, security_or_fail
# the mission's modules are imported with the command, before any event loop starts: a first import
# inside the loop is one callback of 0.3 s (tests/mission/sim/test_loop_debug.py)
from mission.core.clock import WallClock
from mission.core.zenoh_open import open_session
from mission.flight.coordinator import Coordinator
from mission.telemetry.state_pub import MAP_RATE_HZ, WALL_CLOCK_RATE_HZ
from mission.flight.operator_stop import run_until_stopped
from mission.link.forward import ForwardAddressError, forwarding, plan_with_outs, resolve_outs
from mission.telemetry.mission_log import MissionLog
from mission.telemetry.terminal import best_effort_terminal, told_to
from mission.telemetry.watch_keys import with_keys
from wire.cli_args import fail, usage_error

__all__ = ["configure", "main", "fly", "fly_logged"]

_PROG = "swarmseek fly"


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``fly`` options."""
    add_plan_argument(parser)
    add_mission_outputs(parser, "fly")
    add_map_option(parser)


async def fly(plan, *, clock=None, log_dir: Path, display=None, tlog: bool = True, forward_addresses=None,
              terminal=None, map_thread=None, world=None):
    """Open the plan's zenoh session, fly the mission, close; returns the MissionResult.

    ``forward_addresses``: the plan's ``[forward] out`` resolved before the loop started
    (:func:`mission.link.forward.resolve_outs`; any missing are resolved before connecting).
    ``terminal``: the :class:`~mission.telemetry.terminal.Terminal` whose losses the mission log tells.
    ``map_thread``: ``--map``'s :class:`~mission.telemetry.map_live.MapThread` (see :func:`fly_logged`).
    ``world``: a lock-step run's world, handed the reading store (see :func:`fly_logged`).
    """
    clock = clock or WallClock()
    return await fly_logged(plan, MissionLog(Path(log_dir) / "mission.jsonl", clock), clock=clock,
                            display=display, tlog_dir=Path(log_dir) / "tlogs" if tlog else None,
                            forward_addresses=forward_addresses, terminal=terminal, map_thread=map_thread,
                            world=world)


async def fly_logged(plan, log, *, clock, display=None, tlog_dir=None, forward_addresses=None, terminal=None,
                     resume_state=None, map_thread=None, world=None):
    """Open the plan's zenoh session, fly the mission into ``log`` (closed at the end) with the
    operator's stop handlers (:func:`mission.flight.operator_stop.run_until_stopped`; from
    ``resume_state`` when resuming), its keys on a terminal and the ``--out`` forwarding; close.
    Returns the MissionResult. ``fly`` and ``resume`` both fly this way.

    ``map_thread`` (``--map``, already serving): handed this session once open (the map reads the
    state publication and sends the page's commands through it; the state is published at
    ``MAP_RATE_HZ`` then), and stopped before the session closes (its pages keep the outcome).

    ``world`` (a lock-step run's :class:`~mission.sim.embedded_world.EmbeddedWorld`, on the mission's
    :class:`~mission.sim.lockstep.VirtualClock`): given the coordinator's reading store, so that
    simulated time waits for every reading in flight (without it, time runs ahead of zenoh's
    delivery on a loaded host and the run depends on the wall clock)."""
    session = None
    try:
        with told_to(terminal, log):
            session = await open_session(plan.zenoh)  # off the loop
            if map_thread is not None:
                map_thread.attach(session)
            co = Coordinator(plan, clock=clock, zenoh_session=session, log=log, display=display, tlog_dir=tlog_dir,
                             state_rate_hz=WALL_CLOCK_RATE_HZ if map_thread is None else MAP_RATE_HZ)
            if world is not None:
                world.store = co.store
            mission = run_until_stopped(co.run(resume_state), co.state, co.log)
            work = with_keys(co.command, co.say, display, mission)  # keys on a terminal
            return await forwarding(work, plan.forward, [v.sysid for v in plan.vehicles], co.event,  # --out
                                    co.watch_endpoints, forward_addresses)
    finally:
        if map_thread is not None:
            await map_thread.detach()  # the map shows the outcome and lets go of the session
        log.close()
        if session is not None:
            session.close()


def main(args) -> int:
    """Load the plan and fly it (the terminal best effort: :mod:`mission.telemetry.terminal`)."""
    with best_effort_terminal() as terminal:
        return _main(args, terminal)


def _main(args, terminal) -> int:
    from mission.telemetry.display import Display, report_result

    plan, status = load_plan_or_fail(args.plan, _PROG)
    if plan is None:
        return status
    plan = plan_with_outs(plan, args.out)
    if not plan.zenoh.listen and not plan.zenoh.connect:
        return fail(_PROG, "the plan's [zenoh] section has no listen or connect endpoint: "
                           "no reading could arrive (multicast scouting is off)")
    from mission.cli.paths import announce_log, mission_log_dir, summary_log_line

    try:
        addresses = resolve_outs(plan.forward.out)  # once, before any vehicle is contacted
    except ForwardAddressError as exc:
        return usage_error(_PROG, f"{exc}; nothing armed")
    log_dir, problem = mission_log_dir(args.log_dir, "fly")
    if problem:
        return usage_error(_PROG, problem)
    from mission.core.zenoh_errors import zenoh_open_message

    status = security_or_fail(plan, _PROG)  # warns on every start (the plan's refusals came with it)
    if status is not None:
        return status
    map_thread, status = start_map_thread(args, plan.fleet, _PROG)  # a port in use: nothing armed
    if status is not None:
        return status
    announce_log("fly", log_dir / "mission.jsonl", args.json)
    display = Display(quiet=args.json)
    try:
        result, status = run_or_fail(
            _PROG, lambda: asyncio.run(fly(plan, log_dir=log_dir, display=display, tlog=not args.no_tlog,
                                           forward_addresses=addresses, terminal=terminal, map_thread=map_thread)),
            lambda exc: f"{zenoh_open_message(exc, plan.zenoh)}; nothing armed")
    finally:
        if map_thread is not None:
            map_thread.stop()
    if result is None:
        return status
    status = report_result(result, display, args.json)
    summary_log_line(log_dir / "mission.jsonl", args.json)
    return status
