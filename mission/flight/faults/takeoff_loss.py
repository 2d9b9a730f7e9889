"""A vehicle that fails during takeoff or assembly is a lost vehicle, not the end of the mission.

Real firmware shows it (docs/faults.md): a PX4 SIH instance on a busy host whose barometer and
compass time out goes to its failsafe (blind land, then STABILIZED) and never reaches its layer;
a takeoff whose commands are never acknowledged. The vehicle is declared lost (reason
``failed``), taken off the setpoint stream and told to land (reported loudly if even that fails);
the others go on, and :class:`mission.flight.phases.assemble.Assemble` ends the mission when fewer than 4
are left.
"""
from __future__ import annotations

import asyncio

import numpy as np

from mission.core.tasks import spawn
from mission.flight.services import Clock, Events, Fleet
from mission.flight.state import MissionState, VehicleLoss
from mission.safety.gate import SafetyGate

__all__ = ["TakeoffLoss"]


class TakeoffLoss:
    """Vehicles that fail in the takeoff or the assembly: lost, off the gate, told to land.

    Parameters
    ----------
    state : MissionState
        Where the loss is declared (and the phase it happened in is read).
    fleet : Fleet
        The connected vehicles (the LAND command, their positions).
    gate : SafetyGate or None
        The safety gate a failed vehicle is taken off.
    clock : Clock
        The mission clock.
    events : Events
        Each loss is told as an event.
    report : callable
        ``report(message)``: a failed background LAND command (:func:`mission.core.tasks.spawn`).
    """

    def __init__(self, state: MissionState, fleet: Fleet, gate: SafetyGate | None, clock: Clock, events: Events,
                 report) -> None:
        self.state, self.fleet, self.gate, self.clock = state, fleet, gate, clock
        self.events, self.report = events, report

    def lose_failed(self, sysid: int, detail: str) -> None:
        """Declare ``sysid`` lost because it failed in this phase; command it to land (in the background)."""
        if sysid in self.state.lost:
            return
        now = self.clock.time()
        loss = VehicleLoss(sysid, "failed", detail, now, now, self.state.phase)
        if self.gate is not None and sysid in self.gate.sysids:
            loss.last_setpoint_enu = self.gate.setpoint(sysid)
            self.gate.remove(sysid)
        self.state.declare_lost(loss, f"lost (failed in {self.state.phase})")
        self.events.event(f"vehicle {sysid} lost: failed in {self.state.phase}: {detail}; the others go on, it is commanded to land",
                 level="warning", sysid=sysid, reason="failed", detected_s=now, since_s=now)
        v = self.fleet.vehicles.get(sysid)
        if v is not None:
            spawn(self._land_failed(sysid, v), f"landing failed vehicle {sysid}", self.report)

    async def _land_failed(self, sysid: int, v) -> None:
        try:
            await asyncio.wait_for(v.land(), timeout=30.0)
        except Exception as exc:  # noqa: BLE001 - CommandError, link, timeout: reported loudly
            armed = v.state.armed
            self.events.event(f"vehicle {sysid}: land after its failure was not acknowledged ({exc}); "
                     f"{'IT MAY STILL BE AIRBORNE (armed)' if armed else 'it reports disarmed'}",
                     level="error", sysid=sysid)

    def laggards(self, sysids, tol_m: float) -> list[int]:
        """Vehicles of ``sysids`` (not lost) farther than ``tol_m`` from their setpoint, or without a position."""
        out = []
        for s in sysids:
            if s in self.state.lost or self.gate is None or s not in self.gate.sysids:
                continue
            p = self.fleet.telemetry_position(s)
            if p is None or float(np.linalg.norm(np.asarray(p) - self.gate.setpoint(s))) > tol_m:
                out.append(s)
        return out
