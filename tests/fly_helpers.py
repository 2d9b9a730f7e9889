"""Shared by the whole-mission tests: fly one plan against a mock fleet with a mission log."""
from __future__ import annotations

from mission.coordinator import Coordinator
from mission.mission_log import MissionLog

__all__ = ["fly"]


async def fly(plan, fleet, log_dir):
    """Run a :class:`Coordinator` on ``plan`` with the fleet's clock; the mission log goes to
    ``log_dir / "mission.jsonl"``, the .tlog files to ``log_dir / "tlogs"``. Returns the result."""
    import zenoh

    session = zenoh.open(plan.zenoh.to_config())
    log = MissionLog(log_dir / "mission.jsonl", fleet.clock)
    try:
        return await Coordinator(plan, clock=fleet.clock, zenoh_session=session, log=log,
                                 tlog_dir=log_dir / "tlogs").run()
    finally:
        log.close()
        session.close()
