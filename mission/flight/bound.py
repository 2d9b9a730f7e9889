"""The coordinator's services bound to it: what the fault responses and the seek are handed.

* :class:`BoundMotion`: :mod:`mission.flight.motion`'s primitives (they still take the
  coordinator) flown on its gate, the :class:`mission.flight.services.Motion` of
  :mod:`mission.flight.faults` and :mod:`mission.flight.return_clear`;
* :class:`BoundSeekFormation`: the seek's :class:`mission.flight.services.SeekFormation`, the fault
  responses built by the coordinator's builders (``reformation()``, ``rejoin()``,
  ``retirement()``) over its vehicles and gate at each call.

Built by :class:`mission.flight.coordinator.Coordinator` (``motion()``, ``seek_phase()``) only, with
itself (not imported here: the coordinator imports this module).
"""
from __future__ import annotations

from mission.flight import motion
from mission.flight.faults.rejoin import pending_readmissions

__all__ = ["BoundMotion", "BoundSeekFormation"]


class BoundMotion:
    """:mod:`mission.flight.motion`'s primitives bound to one coordinator: the
    :class:`~mission.flight.services.Motion` the fault responses are handed."""

    def __init__(self, coordinator) -> None:
        self.co = coordinator

    async def move_and_wait(self, goals, tol_m: float, timeout_s: float | None = None,
                            what: str = "vehicles to reach their goals") -> None:
        """:func:`mission.flight.motion.move_and_wait`."""
        await motion.move_and_wait(self.co, goals, tol_m, timeout_s, what)

    async def fly_timed(self, sysids, times_s, waypoints_enu) -> None:
        """:func:`mission.flight.motion.fly_timed`."""
        await motion.fly_timed(self.co, sysids, times_s, waypoints_enu)

    async def transfer_to(self, sysids, new_offsets, centre_enu, what: str, lost_here) -> None:
        """:func:`mission.flight.motion.transfer_to`."""
        await motion.transfer_to(self.co, sysids, new_offsets, centre_enu, what, lost_here)

    async def keep_out(self, sysid: int, v, why: str) -> None:
        """:func:`mission.flight.motion.keep_out`."""
        await motion.keep_out(self.co, sysid, v, why)

    def parked(self) -> list[int]:
        """:func:`mission.flight.motion.parked`."""
        return motion.parked(self.co)


class BoundSeekFormation:
    """The seek's :class:`mission.flight.services.SeekFormation`: the fault responses
    (:mod:`mission.flight.faults`) and the motion primitives, built by the coordinator's builders over
    its vehicles and gate at each call."""

    def __init__(self, coordinator) -> None:
        self._co = coordinator

    async def reform(self, centre_enu, sysids):
        """:meth:`mission.flight.faults.loss.Reformation.reform`."""
        return await self._co.reformation().reform(centre_enu, sysids)

    def pending_readmissions(self):
        """:func:`mission.flight.faults.rejoin.pending_readmissions`."""
        return pending_readmissions(self._co.state, self._co.plan.faults)

    async def keep_out_retired(self, returning):
        """:meth:`mission.flight.faults.retire.Retirement.keep_out_retired`."""
        return await self._co.retirement().keep_out_retired(returning)

    async def readmit(self, centre_enu, sysids, returning):
        """:meth:`mission.flight.faults.rejoin.Rejoin.readmit`."""
        return await self._co.rejoin().readmit(centre_enu, sysids, returning)

    def clear_goals(self, centre_enu, sysids):
        """:meth:`mission.flight.faults.rejoin.Rejoin.clear_goals`."""
        return self._co.rejoin().clear_goals(centre_enu, sysids)

    async def fly_rotation(self, centre_enu, sysids, before):
        """:meth:`mission.flight.faults.rejoin.Rejoin.fly_rotation`."""
        await self._co.rejoin().fly_rotation(centre_enu, sysids, before)

    def formation_goals(self, centre_enu, sysids):
        """:meth:`mission.flight.faults.retire.Retirement.formation_goals`."""
        return self._co.retirement().formation_goals(centre_enu, sysids)

    def make_watch(self, check, sysids):
        """:meth:`mission.flight.faults.retire.Retirement.make_watch`."""
        return self._co.retirement().make_watch(check, sysids)

    async def retire_sensor(self, centre_enu, sysids, info):
        """:meth:`mission.flight.faults.retire.Retirement.retire_sensor`."""
        return await self._co.retirement().retire_sensor(centre_enu, sysids, info)

    async def move_and_wait(self, goals, tol_m, timeout_s=None, what="vehicles to reach their goals"):
        """:func:`mission.flight.motion.move_and_wait`."""
        await self._co.motion().move_and_wait(goals, tol_m, timeout_s=timeout_s, what=what)

    def parked(self):
        """:func:`mission.flight.motion.parked`."""
        return self._co.motion().parked()
