"""Fake services for the fault-response objects of :mod:`mission.flight.faults` (no Coordinator):
a mission clock, an event recorder, vehicles, a safety gate and the motion primitives."""
from __future__ import annotations

import asyncio
from types import SimpleNamespace

import numpy as np

from mission.flight.services import Fleet
from mission.flight.state import MissionError, MissionState


class FakeClock:
    """A mission clock whose sleeps advance it at once (and yield to the loop)."""

    def __init__(self, t_s: float = 0.0) -> None:
        self.t = float(t_s)

    def time(self) -> float:
        return self.t

    async def sleep(self, dt_s: float) -> None:
        self.t += float(dt_s)
        await asyncio.sleep(0)


class Recorder:
    """Events (and background-task reports) kept as ``(level, message, fields)``."""

    def __init__(self) -> None:
        self.events: list[tuple[str, str, dict]] = []

    def event(self, message: str, level: str = "info", **fields) -> None:
        self.events.append((level, message, fields))

    def report(self, message: str) -> None:
        self.events.append(("error", message, {}))

    def messages(self, level: str | None = None) -> list[str]:
        return [m for lv, m, _ in self.events if level is None or lv == level]


class FakeWaiter:
    """Waits by checking once on its clock's time (a condition not met is a timeout)."""

    def __init__(self) -> None:
        self.waited: list[str] = []

    async def wait_until(self, predicate, timeout_s: float, what: str, poll_s: float = 0.1) -> None:
        self.waited.append(what)
        if not predicate():
            raise MissionError(f"timed out after {timeout_s:.0f} s waiting for {what}")


class FakeVehicle:
    """A vehicle link: state, link age, mode/land/rtl commands recorded."""

    def __init__(self, sysid: int, position_enu, flavour: str = "px4", mode: str = "OFFBOARD", armed: bool = True,
                 alt_m: float = 10.0, age_s: float = 0.0) -> None:
        self.sysid, self.flavour = sysid, flavour
        self.state = SimpleNamespace(mode=mode, armed=armed, relative_alt_m=alt_m, landed=False, last_heartbeat_s=None,
                                     system_status=0)  # VehicleState's: MAV_STATE_UNINIT until a HEARTBEAT says
        self.position = np.asarray(position_enu, dtype=float)
        self.age_s = age_s
        self.commands: list[str] = []
        self.status_heartbeats = 2
        self.status_since_s = None
        self.statustexts: list[tuple] = []  # (t_s, severity, text), as VehicleLink's

    def link_age_s(self) -> float:
        return self.age_s

    def position_enu_m(self) -> np.ndarray:
        return self.position.copy()

    async def set_mode(self, mode: str) -> None:
        self.commands.append(f"mode {mode}")
        self.state.mode = mode

    async def land(self) -> None:
        self.commands.append("land")
        self.state.mode = "AUTO.LAND"

    async def rtl(self) -> None:
        self.commands.append("rtl")
        self.state.mode = "AUTO.RTL"

    def request_heartbeat(self, min_interval_s: float = 0.0) -> None:
        self.commands.append("heartbeat?")


class FakeGate:
    """The safety gate's setpoints (goals are reached at once)."""

    max_speed_m_s = 3.0
    max_vertical_speed_m_s = 1.0

    def __init__(self, setpoints: dict) -> None:
        self.cmd = {s: np.asarray(p, dtype=float) for s, p in setpoints.items()}
        self.goal_batches: list[dict] = []
        self.pauses_s: dict[int, float] = {}  # the longest pause of each vehicle's stream (default 0.1 s)

    def stream_gap_s(self, sysid: int, since_s: float) -> float | None:
        return self.pauses_s.get(sysid, 0.1) if sysid in self.cmd else None

    @property
    def sysids(self) -> list[int]:
        return sorted(self.cmd)

    def setpoint(self, sysid: int) -> np.ndarray:
        return self.cmd[sysid].copy()

    def add(self, sysid: int, position_enu_m) -> None:
        self.cmd[sysid] = np.asarray(position_enu_m, dtype=float)

    def remove(self, sysid: int) -> None:
        self.cmd.pop(sysid, None)

    def set_goals(self, goals: dict) -> None:
        self.goal_batches.append(dict(goals))
        for s, g in goals.items():
            if s in self.cmd:
                self.cmd[s] = np.asarray(g, dtype=float)

    def at_goal(self, sysid: int) -> bool:
        return True


class FakeMotion:
    """The motion primitives (:class:`mission.flight.services.Motion`), recorded; ``transfer_to``
    adopts the slots in the mission state and moves the gate's setpoints there."""

    def __init__(self, state: MissionState, gate: FakeGate | None = None) -> None:
        self.state, self.gate = state, gate
        self.calls: list[tuple] = []

    async def move_and_wait(self, goals, tol_m, timeout_s=None, what="vehicles to reach their goals") -> None:
        self.calls.append(("move_and_wait", dict(goals), what))
        if self.gate is not None:
            self.gate.set_goals(goals)

    async def fly_timed(self, sysids, times_s, waypoints_enu) -> None:
        self.calls.append(("fly_timed", list(sysids)))

    async def transfer_to(self, sysids, new_offsets, centre_enu, what, lost_here) -> None:
        self.calls.append(("transfer_to", list(sysids), what))
        self.state.update_slots({s: new_offsets[s] for s in sysids})

    async def keep_out(self, sysid, v, why) -> None:
        self.calls.append(("keep_out", sysid, why))
        self.state.keep_out(sysid, "kept out: landing")

    def parked(self) -> list[int]:
        return sorted(s for s in self.state.retired if s not in self.state.lost
                      and self.gate is not None and s in self.gate.sysids)


def fleet_of(vehicles: list[FakeVehicle]) -> Fleet:
    """A :class:`Fleet` holding ``vehicles``."""
    fleet = Fleet({v.sysid: f"v{v.sysid}" for v in vehicles})
    for v in vehicles:
        fleet.add(v)
    return fleet


def ring(n: int, radius_m: float = 5.0) -> dict[int, np.ndarray]:
    """Slot offsets of ``n`` vehicles (sysids 1..n) on the sphere of ``radius_m``, alternately
    above and below the equator (a CVT needs generators off one great circle), ENU m."""
    a = 2 * np.pi * np.arange(n) / n
    el = np.where(np.arange(n) % 2 == 0, 0.5, -0.5)
    return {k + 1: radius_m * np.array([np.cos(el[k]) * np.cos(a[k]), np.cos(el[k]) * np.sin(a[k]), np.sin(el[k])])
            for k in range(n)}


def flying_state(n: int, clock: FakeClock, phase: str = "seek", kind: str = "cvt") -> MissionState:
    """A mission state of ``n`` airborne vehicles in a ring formation (of type ``kind``), in ``phase``."""
    state = MissionState(range(1, n + 1), clock=clock, formation_kind=kind)
    state.set_formation(ring(n), {s: 10.0 + s for s in range(1, n + 1)})
    for s in range(1, n + 1):
        state.set_airborne(s, "flying")
    state.set_phase(phase)
    return state
