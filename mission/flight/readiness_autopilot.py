"""The autopilots' own readiness: waited for in preflight, and arming retried while it is refused.

* :func:`wait_autopilots_ready` (preflight, also ``dry-run``): waits until every connected
  vehicle's autopilot says it is ready (:class:`mission.vehicle.prearm.PrearmStatus`: SYS_STATUS
  health and pre-arm bits, EKF / estimator position flags), at most
  ``[preflight] autopilot_ready_timeout_s``, printing progress every few seconds; records the
  ``autopilot`` check of each vehicle's readiness with the autopilot's own words.
* :func:`arm_and_takeoff` (takeoff): arms and takes off one vehicle. An arming refusal (e.g.
  ArduCopter's ``Arm: Need Position Estimate``) is shown to the operator and retried until the
  same timeout; ArduPilot's mode is set, confirmed by a heartbeat, and checked again right after
  arming (the RC input can force STABILIZE a few seconds after boot), and the takeoff command
  follows the arming at once (ArduCopter disarms when no takeoff follows within about 10 s).
"""
from __future__ import annotations

import asyncio

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mission.flight.services import Clock, Events
from mission.flight.state import MissionError, MissionState
from mission.vehicle.state import CommandError

__all__ = ["autopilot_problems", "wait_autopilots_ready", "arm_and_takeoff"]

_M = mavlink
_PROGRESS_EVERY_S = 5.0
_PROBE_EVERY_S = 10.0
_POLL_S = 0.25
_MODE_CONFIRM_S = 3.0
#: failures that are not arming refusals (no ACK, link errors) tolerated per takeoff
_MAX_OTHER_FAILURES = 3


def autopilot_problems(v, now_s: float) -> list[str]:
    """Why vehicle ``v``'s autopilot is not ready to arm (empty: ready)."""
    return v.prearm.problems(now_s)


async def _probe(v) -> None:
    """Ask an ArduPilot autopilot to run its pre-arm checks now (it reports failures as
    ``PreArm:`` STATUSTEXTs); any answer is fine, nothing is armed."""
    try:
        await v.command_long(_M.MAV_CMD_RUN_PREARM_CHECKS, timeout_s=1.0, retries=0,
                             accept=tuple(_M.enums["MAV_RESULT"]))
    except Exception:  # noqa: BLE001 - a probe only: its failure changes nothing, the wait goes on
        return


def _summary(waiting: dict[int, list[str]]) -> str:
    return "; ".join(f"vehicle {s}: {p[0]}" for s, p in sorted(waiting.items()))


async def wait_autopilots_ready(state: MissionState, vehicles: dict, clock: Clock, events: Events,
                                timeout_s: float) -> None:
    """Wait (at most ``timeout_s`` mission-clock seconds) until every connected vehicle's
    autopilot is ready (``vehicles``: by system id); then set the ``autopilot`` check of each
    vehicle's readiness in ``state``."""
    connected = vehicles
    start = clock.time()
    # a vehicle that already failed another check is not waited for (its autopilot is still judged)
    failed = {s for s in connected if (r := state.readiness.get(s)) is not None and not r.ready}
    vehicles = {s: v for s, v in connected.items() if s not in failed}
    last_progress = start
    last_probe: dict[int, float] = {}
    probes: set = set()
    while True:
        now = clock.time()
        waiting = {s: p for s, v in vehicles.items() if (p := autopilot_problems(v, now))}
        if not waiting or now - start >= timeout_s:
            break
        for s in waiting:
            v = vehicles[s]
            if v.flavour == "ardupilot" and now - last_probe.get(s, -1e18) >= _PROBE_EVERY_S:
                last_probe[s] = now
                task = asyncio.ensure_future(_probe(v))
                probes.add(task)
                task.add_done_callback(probes.discard)
        if now - last_progress >= _PROGRESS_EVERY_S:
            last_progress = now
            events.event(f"preflight: waiting for the autopilots' own readiness ({now - start:.0f} of "
                     f"{timeout_s:.0f} s): {_summary(waiting)}", waiting=sorted(waiting))
        await clock.sleep(_POLL_S)
    for task in list(probes):
        task.cancel()
    waited_s = clock.time() - start
    if not waiting and vehicles:
        events.event(f"preflight: every autopilot is ready (waited {waited_s:.1f} s)", waited_s=waited_s)
    now = clock.time()
    waiting.update({s: p for s in failed if (p := autopilot_problems(connected[s], now))})
    for s in connected:
        r = state.readiness.get(s)
        if r is None:
            continue
        r.checks["autopilot"] = s not in waiting
        r.warnings.extend(n for n in connected[s].prearm.notes() if n not in r.warnings)
        if s in waiting:
            waited = f"after {timeout_s:.0f} s" if s not in failed else "(not waited for)"
            r.problems.append(f"autopilot not ready {waited}: " + "; ".join(waiting[s]))
        state.set_readiness(r, "ready" if r.ready else "not ready: " + "; ".join(r.problems))


async def _confirm_mode(v, mode: str) -> None:
    """Set ``mode`` and wait for a heartbeat that reports it (CommandError if none does)."""
    await v.set_mode(mode)
    if v.state.mode != mode:
        v.request_heartbeat(min_interval_s=0.0)
        await v.wait_for(lambda st: st.mode == mode, _MODE_CONFIRM_S, f"mode {mode} in its heartbeat")


async def _ardupilot_takeoff(v, rel_alt_m: float, before_takeoff, events: Events) -> None:
    """GUIDED (confirmed), arm, GUIDED again if the RC changed it, takeoff at once."""
    await _confirm_mode(v, "GUIDED")
    await v.arm()
    if v.state.mode != "GUIDED":
        events.event(f"vehicle {v.sysid}: mode {v.state.mode} after arming; setting GUIDED again",
                     level="warning", sysid=v.sysid)
        await v.set_mode("GUIDED")
    before_takeoff()
    await v.command_long(_M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, float(rel_alt_m), timeout_s=2.0)


async def arm_and_takeoff(sysid: int, v, rel_alt_m: float, clock: Clock, events: Events, timeout_s: float,
                          before_takeoff=lambda: None, pause=None) -> None:
    """Arm vehicle ``v`` and command its takeoff to ``rel_alt_m`` above home.

    ``clock``: the mission clock; ``events``: each new refusal reason is told there; ``timeout_s``:
    the plan's ``[preflight] autopilot_ready_timeout_s``.

    ``before_takeoff()`` is called right before the takeoff command of each attempt (PX4: right
    before ``v.takeoff``, which starts holding where the vehicle is), with no await in between.

    ``pause(delay_s)`` (a coroutine function; default ``clock.sleep``) is awaited between two
    attempts: the takeoff phase's raises to give the arming up (an operator's stop, a formation
    that can no longer be flown: :class:`mission.flight.phases.takeoff.Takeoff`); what it raises
    goes through unchanged.

    Arming refusals are retried (every second) until ``timeout_s`` after the first attempt, each new reason shown (and logged) with the autopilot's own words;
    other failures (no ACK, link errors) are retried :data:`_MAX_OTHER_FAILURES` times.

    Raises
    ------
    MissionError
        Still refused at the timeout, or too many other failures.
    """
    deadline = clock.time() + timeout_s
    other = 0
    shown: str | None = None
    while True:
        try:
            if v.flavour == "ardupilot":
                await _ardupilot_takeoff(v, rel_alt_m, before_takeoff, events)
            else:
                before_takeoff()
                await v.takeoff(rel_alt_m)
            return
        except Exception as exc:  # noqa: BLE001 - CommandError, LinkError: retried or reported
            refused = (isinstance(exc, CommandError) and exc.command == _M.MAV_CMD_COMPONENT_ARM_DISARM
                       and exc.result is not None)
            other += not refused
            now = clock.time()
            if other >= _MAX_OTHER_FAILURES or now >= deadline:
                why = f"(arming refused for {timeout_s:.0f} s)" if refused else f"after {other} rounds of retries"
                raise MissionError(f"takeoff of vehicle {sysid} failed {why}: {exc}") from None
            says = v.prearm.autopilot_says(now)
            reason = says or str(exc)
            if reason != shown:
                shown = reason
                events.event(f"vehicle {sysid}: {'arming refused' if refused else 'takeoff failed'}: {reason}; "
                             f"retrying for up to {deadline - now:.0f} s", level="warning", sysid=sysid,
                             autopilot_says=says)
            await (pause or clock.sleep)(1.0 if refused else 0.5)
