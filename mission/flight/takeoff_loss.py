"""A vehicle that fails during takeoff or assembly is a lost vehicle, not the end of the mission.

Real firmware shows it (docs/faults.md): a PX4 SIH instance on a busy host whose barometer and
compass time out goes to its failsafe (blind land, then STABILIZED) and never reaches its layer;
a takeoff whose commands are never acknowledged. The vehicle is declared lost (reason
``failed``), taken off the setpoint stream and told to land (reported loudly if even that fails);
the others go on, and :func:`mission.flight.phases.assemble` ends the mission when fewer than 4
are left.
"""
from __future__ import annotations

import asyncio

import numpy as np

from mission.core.tasks import spawn
from mission.flight.state import VehicleLoss

__all__ = ["lose_failed", "laggards"]


def lose_failed(co, sysid: int, detail: str) -> None:
    """Declare ``sysid`` lost because it failed in this phase; command it to land (in the background)."""
    if sysid in co.state.lost:
        return
    now = co.clock.time()
    loss = VehicleLoss(sysid, "failed", detail, now, now, co.state.phase)
    if co.gate is not None and sysid in co.gate.sysids:
        loss.last_setpoint_enu = co.gate.setpoint(sysid)
        co.gate.remove(sysid)
    co.state.declare_lost(loss, f"lost (failed in {co.state.phase})")
    co.event(f"vehicle {sysid} lost: failed in {co.state.phase}: {detail}; the others go on, it is commanded to land",
             level="warning", sysid=sysid, reason="failed", detected_s=now, since_s=now)
    v = co.vehicles.get(sysid)
    if v is not None:
        spawn(_land_failed(co, sysid, v), f"landing failed vehicle {sysid}", co.task_failed)


async def _land_failed(co, sysid: int, v) -> None:
    try:
        await asyncio.wait_for(v.land(), timeout=30.0)
    except Exception as exc:  # noqa: BLE001 - CommandError, link, timeout: reported loudly
        armed = getattr(v.state, "armed", None)
        co.event(f"vehicle {sysid}: land after its failure was not acknowledged ({exc}); "
                 f"{'IT MAY STILL BE AIRBORNE (armed)' if armed else 'it reports disarmed'}",
                 level="error", sysid=sysid)


def laggards(co, sysids, tol_m: float) -> list[int]:
    """Vehicles of ``sysids`` (not lost) farther than ``tol_m`` from their setpoint, or without a position."""
    out = []
    for s in sysids:
        if s in co.state.lost or co.gate is None or s not in co.gate.sysids:
            continue
        p = co.telemetry_position(s)
        if p is None or float(np.linalg.norm(np.asarray(p) - co.gate.setpoint(s))) > tol_m:
            out.append(s)
    return out
