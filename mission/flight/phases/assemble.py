"""The assembly: from the takeoff layers into the formation at the start point (a layered
transfer, clear of lost vehicles). Built by
:meth:`mission.flight.coordinator.Coordinator.assemble_phase`, run with ``await Assemble(...).run()``.
"""
from __future__ import annotations

from typing import Awaitable, Callable

from mission.core.plan_types import SeekingPlan
from mission.flight.control import OperatorStop
from mission.flight.services import PhaseEvents
from mission.flight.state import MissionError, MissionState
from mission.flight.faults.takeoff_loss import TakeoffLoss
from mission.safety.gate import SafetyGate

__all__ = ["Assemble", "FlyClear"]


#: ``fly_clear(sysids, goals, tol_m, what)``: fly ``sysids`` to ``goals`` by their layers, clear of
#: lost vehicles (:meth:`mission.flight.return_clear.ReturnClear.fly_clear`); MissionError when one is late
FlyClear = Callable[[list, dict, float, str], Awaitable[None]]


class Assemble:
    """The assembly: from the takeoff layers into the formation at the start point (layered transfer).

    The legs keep clear of lost vehicles still flying (``fly_clear``); a vehicle that cannot reach
    its slot in time is lost, the others go on (if 4 are left).

    Parameters
    ----------
    seeking : SeekingPlan
        The plan's ``[seeking]``: the start point and ``arrival_tol_m``.
    state : MissionState
    gate : SafetyGate
        The vehicles under setpoints.
    events : PhaseEvents
    fly_clear : FlyClear
    losses : TakeoffLoss
        The vehicles late at their slot are lost there.
    """

    def __init__(self, seeking: SeekingPlan, state: MissionState, gate: SafetyGate, events: PhaseEvents,
                 fly_clear: FlyClear, losses: TakeoffLoss) -> None:
        self.seeking, self.state, self.gate, self.events = seeking, state, gate, events
        self.fly_clear, self.losses = fly_clear, losses

    async def run(self) -> None:
        """Fly into the formation; MissionError when fewer than 4 vehicles are left."""
        self.events.set_phase("assemble")
        state, tol_m = self.state, self.seeking.arrival_tol_m
        sysids = sorted(s for s in self.gate.sysids if s not in state.lost)
        if len(sysids) < 4:
            raise MissionError(f"vehicles {sorted(state.lost)} lost before the formation was assembled: "
                               f"{len(sysids)} left, a formation needs 4")
        centre = self.seeking.start_point()
        # the layered legs, re-planned around lost vehicles still flying (e.g. one lost in takeoff)
        goals = {s: centre + state.slot_offsets[s] for s in sysids}
        try:
            await self.fly_clear(sysids, goals, tol_m, "assembly")
        except OperatorStop:
            raise  # the operator ended the mission: nobody failed
        except MissionError as exc:
            late = self.losses.laggards(sysids, tol_m)
            if not late:
                raise
            for s in late:
                self.losses.lose_failed(s, str(exc))
            sysids = [s for s in sysids if s not in state.lost]
            if len(sysids) < 4:
                raise MissionError(f"vehicles {sorted(state.lost)} lost during the assembly: {len(sysids)} left, "
                                   "a formation needs 4") from None
            await self.fly_clear(sysids, goals, tol_m, "assembly")
        state.move_centre(centre)
        for s in sysids:
            state.set_status(s, "in formation")
        self.events.event(f"formation assembled at ({centre[0]:.1f}, {centre[1]:.1f}, {centre[2]:.1f}) m")
