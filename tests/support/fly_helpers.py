"""Shared by the whole-mission tests: fly one plan against a mock fleet with a mission log."""
from __future__ import annotations

import asyncio

from mission.flight.coordinator import Coordinator
from mission.flight.result import MissionResult, mission_exit_status
from mission.sim.embedded_world import EmbeddedWorld
from mission.sim.lockstep import VirtualClock, run_lockstep
from mission.telemetry.mission_log import MissionLog

from tests.support.invariants import check_never_abandoned

__all__ = ["fly", "run_fleet", "run_with_saboteur", "summary_exit_status"]


async def fly(plan, fleet, log_path, tlog_dir=None, world=None, coordinators=None):
    """Run a :class:`Coordinator` on ``plan`` with the fleet's clock, its mission log at
    ``log_path`` and the .tlog files in ``tlog_dir`` (None: none). Returns the result.

    ``world``: the :class:`~mission.sim.embedded_world.EmbeddedWorld` of a lock-step run (it is
    told where the coordinator's readings arrive). ``coordinators``: a list the coordinator is
    appended to (a test reads its endpoints' counters, also from a saboteur thread)."""
    import zenoh

    session = zenoh.open(plan.zenoh.to_config())
    log = MissionLog(log_path, fleet.clock)
    try:
        co = Coordinator(plan, clock=fleet.clock, zenoh_session=session, log=log, tlog_dir=tlog_dir)
        if coordinators is not None:
            coordinators.append(co)
        if world is not None:
            world.store = co.store
        return await co.run()
    finally:
        log.close()
        session.close()


def run_fleet(fleet, make_main):
    """Run ``make_main(world)`` (a coroutine) against ``fleet``, starting the fleet if needed.

    A fleet on a :class:`~mission.sim.lockstep.VirtualClock` runs in lock-step: no fleet thread,
    ``world`` is its :class:`~mission.sim.embedded_world.EmbeddedWorld`. Any other fleet runs
    on its thread against the wall clock and ``world`` is None. The caller stops the fleet.

    When ``make_main`` returns a mission result (or a coordinator), the never-abandon invariant
    is checked against the fleet (:func:`invariants.check_never_abandoned`).
    """
    lockstep = isinstance(fleet.clock, VirtualClock)
    if not fleet.started:
        fleet.start(thread=not lockstep)
    if not lockstep:
        result = asyncio.run(make_main(None))
    else:
        world = EmbeddedWorld(fleet)
        result = run_lockstep(lambda: make_main(world), fleet.clock, world)
    if isinstance(result, (MissionResult, Coordinator)):
        check_never_abandoned(fleet, _log_path(result))
    return result


def _log_path(result):
    """The mission log of a MissionResult or a Coordinator (None: no log)."""
    if getattr(result, "log_path", None):
        return result.log_path
    log = getattr(result, "log", None)
    return getattr(log, "path", None)


def run_with_saboteur(plan, fleet, log_dir, saboteur=None, coordinators=None):
    """Start ``fleet`` (and the ``saboteur`` thread, which sets faults as the mission log grows:
    it has a ``done`` event), fly ``plan`` (:func:`fly`: log ``log_dir / "mission.jsonl"``, .tlog
    files in ``log_dir / "tlogs"``), stop both; returns the result.

    A fleet on a :class:`~mission.sim.lockstep.VirtualClock` flies in lock-step (no fleet
    thread; the saboteur thread still acts on what the log shows). ``coordinators``: see :func:`fly`."""
    if saboteur:
        saboteur.start()
    try:
        return run_fleet(fleet, lambda world: fly(plan, fleet, log_dir / "mission.jsonl", log_dir / "tlogs",
                                                  world, coordinators))
    finally:
        if saboteur:
            saboteur.done.set()
            saboteur.join(timeout=30)
        fleet.stop()


def summary_exit_status(summary: dict) -> int:
    """The exit status a command must have given for its ``--json`` summary (or the mission log's
    ``summary`` record), recomputed from the summary's own fields, and checked against the
    summary's ``exit_status``."""
    status = mission_exit_status(summary["outcome"], lost=summary.get("lost", []),
                                 airborne_left=summary.get("airborne_left", []),
                                 still_armed=summary.get("still_armed", []),
                                 interrupted_by=summary.get("interrupted_by", []))
    assert summary.get("exit_status") == status, (summary.get("exit_status"), status)
    return status
