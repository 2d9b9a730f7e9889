"""The seek's fault responses and moves in one object: :class:`FaultResponses`.

The seek (:class:`mission.flight.phases.seek.Seek`) is handed a :class:`mission.flight.services.SeekFormation`;
this is the mission's: vehicle losses (:class:`mission.flight.faults.loss.Reformation`), re-admission
(:class:`mission.flight.faults.rejoin.Rejoin`), sensor retirement
(:class:`mission.flight.faults.retire.Retirement`) and the moves (a :class:`mission.flight.services.Motion`),
each built over the gate the seek flies on.
"""
from __future__ import annotations

from mission.core.plan_types import FaultsPlan
from mission.flight.faults.loss import Reformation
from mission.flight.faults.rejoin import Rejoin, pending_readmissions
from mission.flight.faults.retire import Retirement
from mission.flight.services import Motion
from mission.flight.state import MissionState

__all__ = ["FaultResponses"]


class FaultResponses:
    """The seek's :class:`~mission.flight.services.SeekFormation`: each call goes to the one fault
    response (or the motion) that owns it.

    Parameters
    ----------
    state : MissionState
    faults : FaultsPlan
        The plan's ``faults`` section (re-admission is pending only when it allows it).
    reformation : Reformation
    rejoin : Rejoin
    retirement : Retirement
    motion : Motion
    """

    def __init__(self, state: MissionState, faults: FaultsPlan, reformation: Reformation, rejoin: Rejoin,
                 retirement: Retirement, motion: Motion) -> None:
        self.state, self.faults = state, faults
        self.reformation, self.rejoin, self.retirement, self.motion = reformation, rejoin, retirement, motion

    async def reform(self, centre_enu, sysids):
        """:meth:`mission.flight.faults.loss.Reformation.reform`."""
        return await self.reformation.reform(centre_enu, sysids)

    def pending_readmissions(self):
        """:func:`mission.flight.faults.rejoin.pending_readmissions`."""
        return pending_readmissions(self.state, self.faults)

    async def keep_out_retired(self, returning):
        """:meth:`mission.flight.faults.retire.Retirement.keep_out_retired`."""
        return await self.retirement.keep_out_retired(returning)

    async def readmit(self, centre_enu, sysids, returning):
        """:meth:`mission.flight.faults.rejoin.Rejoin.readmit`."""
        return await self.rejoin.readmit(centre_enu, sysids, returning)

    def clear_goals(self, centre_enu, sysids):
        """:meth:`mission.flight.faults.rejoin.Rejoin.clear_goals`."""
        return self.rejoin.clear_goals(centre_enu, sysids)

    async def fly_rotation(self, centre_enu, sysids, before):
        """:meth:`mission.flight.faults.rejoin.Rejoin.fly_rotation`."""
        await self.rejoin.fly_rotation(centre_enu, sysids, before)

    def formation_goals(self, centre_enu, sysids):
        """:meth:`mission.flight.faults.retire.Retirement.formation_goals`."""
        return self.retirement.formation_goals(centre_enu, sysids)

    def make_watch(self, check, sysids):
        """:meth:`mission.flight.faults.retire.Retirement.make_watch`."""
        return self.retirement.make_watch(check, sysids)

    async def retire_sensor(self, centre_enu, sysids, info):
        """:meth:`mission.flight.faults.retire.Retirement.retire_sensor`."""
        return await self.retirement.retire_sensor(centre_enu, sysids, info)

    async def move_and_wait(self, goals, tol_m, timeout_s=None, what="vehicles to reach their goals"):
        """:meth:`mission.flight.motion.GateMotion.move_and_wait`."""
        await self.motion.move_and_wait(goals, tol_m, timeout_s=timeout_s, what=what)

    def parked(self):
        """:meth:`mission.flight.motion.GateMotion.parked`."""
        return self.motion.parked()
