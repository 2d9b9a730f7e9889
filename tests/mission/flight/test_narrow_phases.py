"""The flight modules moved to narrow collaborators take no Coordinator (docs/architecture.md,
"How a phase gets what it uses"): no function or method in them has a first parameter ``co``."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]

#: every flight module but the builder (``coordinator``): its functions are handed the mission
#: state, the fleet, the gate... and never ``co``
FLIGHT = ROOT / "mission" / "flight"
NARROW = sorted(str(p.relative_to(FLIGHT).with_suffix("")) for p in FLIGHT.rglob("*.py") if p.name != "coordinator.py")


def _takes_co(path: Path) -> list[str]:
    out = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            names = [a.arg for a in node.args.posonlyargs + node.args.args]
            if names[:1] == ["co"] or names[:2] == ["self", "co"]:
                out.append(f"{path.name}:{node.lineno} {node.name}")
    return out


def test_the_narrow_modules_are_the_phases_the_faults_and_their_helpers():
    """Not vacuous: the list holds the phases, the fault responses and motion (not the builder)."""
    assert {"phases/seek", "phases/takeoff", "faults/loss", "faults/responses", "motion"} <= set(NARROW)
    assert "coordinator" not in NARROW


@pytest.mark.parametrize("module", NARROW)
def test_a_narrow_flight_module_takes_no_coordinator(module):
    path = FLIGHT / f"{module}.py"
    assert path.is_file(), path
    assert _takes_co(path) == []


def test_the_check_finds_a_function_taking_the_coordinator(tmp_path):
    sample = tmp_path / "sample.py"
    sample.write_text("def f(co, x):\n    return x\n\nclass C:\n    def g(self, co):\n        return co\n")
    assert _takes_co(sample) == ["sample.py:1 f", "sample.py:5 g"]


# ------------------------------------------------------------------ phases built without a Coordinator
import asyncio  # noqa: E402
from types import SimpleNamespace  # noqa: E402

import numpy as np  # noqa: E402

from mission.flight.services import Fleet  # noqa: E402
from mission.flight.state import MissionError, MissionState  # noqa: E402


class FakeClock:
    """A mission clock whose sleeps advance it at once (then yield to the loop)."""

    def __init__(self):
        self.t_s = 0.0

    def time(self) -> float:
        return self.t_s

    async def sleep(self, dt_s: float) -> None:
        self.t_s += max(float(dt_s), 0.0)
        await asyncio.sleep(0)


class FakeEvents:
    """Events and phases, recorded."""

    def __init__(self):
        self.events: list[tuple[str, str]] = []
        self.phases: list[str] = []

    def event(self, message, level="info", **fields):
        self.events.append((level, message))

    def set_phase(self, name, **fields):
        self.phases.append(name)


class FakeWaiter:
    """Polls on the fake clock; MissionError after the timeout."""

    def __init__(self, clock):
        self.clock = clock

    async def wait_until(self, predicate, timeout_s, what, poll_s=0.1):
        deadline = self.clock.time() + timeout_s
        while not predicate():
            if self.clock.time() > deadline:
                raise MissionError(f"timed out after {timeout_s:.0f} s waiting for {what}")
            await self.clock.sleep(poll_s)


class FakeGate:
    """The safety gate's bookkeeping: setpoints by sysid, goals reached at once."""

    def __init__(self, setpoints=None):
        self.points = {s: np.asarray(p, float) for s, p in (setpoints or {}).items()}
        self.started = False
        self.max_speed_m_s = self.max_vertical_speed_m_s = 5.0

    @property
    def sysids(self):
        return list(self.points)

    def start(self):
        self.started = True

    def add(self, sysid, p):
        self.points[sysid] = np.asarray(p, float)

    def remove(self, sysid):
        self.points.pop(sysid, None)

    def setpoint(self, sysid):
        return self.points[sysid]

    def set_goals(self, goals):
        self.points.update({s: np.asarray(g, float) for s, g in goals.items()})

    def at_goal(self, sysid):
        return True


class FakeVehicle:
    """A vehicle that is where it is told and lands (disarms) a few seconds after LAND / RTL."""

    def __init__(self, sysid, clock, position, flavour="px4", refuse_land=False):
        self.sysid, self.clock, self.flavour, self.refuse_land = sysid, clock, flavour, refuse_land
        self.position = np.asarray(position, float)
        self.state = SimpleNamespace(armed=True, landed=False, home=None, mode="OFFBOARD")
        self.commands: list[str] = []
        self._down_at = None

    def position_enu_m(self):
        if self._down_at is not None and self.clock.time() >= self._down_at:
            self.state.armed, self.state.landed = False, True
        return self.position

    async def _down(self, what):
        self.commands.append(what)
        if self.refuse_land:
            raise RuntimeError(f"{what} refused")
        self._down_at = self.clock.time() + 3.0

    async def land(self):
        await self._down("land")

    async def rtl(self):
        await self._down("rtl")


def _services(n=5):
    clock = FakeClock()
    state = MissionState(list(range(1, n + 1)), clock=clock)
    fleet = Fleet({s: f"v{s}" for s in range(1, n + 1)})
    for s in range(1, n + 1):
        fleet.add(FakeVehicle(s, clock, (3.0 * s, 0.0, 10.0)))
    return clock, state, fleet, FakeEvents(), FakeWaiter(clock)


def _return_phase(plan, state, fleet, gate, clock, events, waiter, fly_return):
    from mission.flight.control import MissionControl
    from mission.flight.phases.return_home import ReturnHome

    return ReturnHome(plan, state, fleet, gate, clock, events, waiter, MissionControl(clock), fly_return)


def test_return_phase_runs_on_narrow_services_and_lands_every_airborne_vehicle():
    clock, state, fleet, events, waiter = _services(5)
    for s in fleet.vehicles:
        state.set_airborne(s, "in formation")
    fleet.vehicles[5].refuse_land = True  # its LAND never goes through: told, the others still land
    gate = FakeGate({s: v.position for s, v in fleet.vehicles.items()})
    plan = SimpleNamespace(return_behaviour="rtl", stagger_s=1.0)
    flown = []

    async def fly_return(sysids):
        flown.append(list(sysids))
        return {2}  # vehicle 2's home is obstructed: it must LAND, not RTL

    asyncio.run(_return_phase(plan, state, fleet, gate, clock, events, waiter, fly_return).run())
    assert flown == [[1, 2, 3, 4, 5]]
    assert events.phases == ["return"]
    assert fleet.vehicles[2].commands == ["land"] and fleet.vehicles[1].commands == ["rtl"]
    assert fleet.vehicles[5].commands == ["rtl"] * 3  # three rounds, then reported
    assert any(lvl == "error" and "RTL of vehicle 5 failed after 3 rounds" in m for lvl, m in events.events)
    assert sorted(state.airborne) == [5] and gate.sysids == [5]
    assert {s: state.status[s] for s in (1, 2)} == {1: "landed", 2: "landed"}
    assert clock.time() >= 4 * plan.stagger_s  # staggered: one command after another


def test_return_phase_lands_where_they_are_on_land_all_now():
    clock, state, fleet, events, waiter = _services(4)
    for s in fleet.vehicles:
        state.set_airborne(s, "in formation")

    async def no_flight(sysids):
        raise AssertionError("land_all_now flies no return")

    plan = SimpleNamespace(return_behaviour="rtl", stagger_s=5.0)
    asyncio.run(_return_phase(plan, state, fleet, None, clock, events, waiter, no_flight).land_all_now())
    assert all(v.commands == ["land"] for v in fleet.vehicles.values())
    assert not state.airborne and events.phases == []


def test_assemble_phase_loses_a_late_vehicle_and_flies_the_others_into_formation():
    from mission.core.plan_types import SeekingPlan
    from mission.flight.phases.assemble import Assemble
    from mission.flight.faults.takeoff_loss import TakeoffLoss

    clock, state, fleet, events, waiter = _services(5)
    offsets = {s: np.array([float(s), 0.0, 0.0]) for s in fleet.vehicles}
    state.set_formation(offsets, layer_alt_m={s: 10.0 + s for s in fleet.vehicles})
    gate = FakeGate({s: v.position for s, v in fleet.vehicles.items()})
    seeking = SeekingPlan(start_enu_m=(1.0, 2.0, 9.0))
    calls = []

    async def fly_clear(sysids, goals, tol_m, what):
        calls.append(list(sysids))
        gate.set_goals({s: goals[s] for s in sysids})
        for s in sysids:
            if s != 4:  # vehicle 4 stays behind, far from its setpoint
                fleet.vehicles[s].position = goals[s]
        if len(calls) == 1:
            raise MissionError("timed out waiting for the assembly")

    losses = TakeoffLoss(state, fleet, gate, clock, events, report=lambda m: None)
    asyncio.run(Assemble(seeking, state, gate, events, fly_clear, losses).run())
    assert calls == [[1, 2, 3, 4, 5], [1, 2, 3, 5]]
    assert sorted(state.lost) == [4] and 4 not in gate.sysids
    assert np.allclose(state.centre_enu, seeking.start_point())
    assert all(state.status[s] == "in formation" for s in (1, 2, 3, 5))
    assert events.phases == ["assemble"] and events.events[-1][1].startswith("formation assembled at")


class FakeLinks:
    """Where the connect phase puts its endpoints (none open here)."""

    def __init__(self):
        self.endpoints: dict = {}
        self.poller = None

    def add_endpoint(self, uri, endpoint):
        self.endpoints[uri] = endpoint

    def use_poller(self, poller):
        self.poller = poller


def _plan(n=2, connection=None):
    import dataclasses

    from mission.sim.embedded import embedded_plan

    plan = embedded_plan(n, {"udp_base_port": 14550, "tcp_base_port": 5760, "zenoh_port": 7447})
    if connection is not None:
        plan = dataclasses.replace(plan, vehicles=tuple(dataclasses.replace(v, connection=connection)
                                                        for v in plan.vehicles))
    return plan


@pytest.mark.parametrize("required", [True, False])
def test_connect_phase_runs_on_narrow_services_and_reports_a_link_that_cannot_open(required):
    from mission.flight.phases.connect import Connect

    plan = _plan(2, connection="bogus:nowhere")
    clock = FakeClock()
    state = MissionState([1, 2], clock=clock)
    fleet, events, links = Fleet({1: "a", 2: "b"}), FakeEvents(), FakeLinks()
    phase = Connect(plan, state, fleet, links, clock, events)

    async def go():
        if required:
            with pytest.raises(MissionError, match="connect failed: bogus:nowhere"):
                await phase.run(required=True)
        else:
            await phase.run(required=False)

    asyncio.run(go())
    assert events.phases == ["connect"] and not links.endpoints and not fleet.vehicles
    assert {s: state.status[s] for s in (1, 2)} == {1: "no link", 2: "no link"}
    assert all(not r.ready and "cannot open bogus:nowhere" in r.problems[0] for r in state.readiness.values())
    errors = [m for lvl, m in events.events if lvl == "error"]
    assert errors == ([] if required else [errors[0]]) and (required or "bogus:nowhere" in errors[0])


class ReadyPrearm:
    """An autopilot's pre-arm status that reports nothing against arming."""

    def problems(self, now_s):
        return []

    def notes(self):
        return []

    def autopilot_says(self, now_s):
        return None

    def prearm_check_fails(self):
        return False


class FakePreflightVehicle:
    """What the preflight reads of a vehicle: link age, state, home, a ready pre-arm status; no
    parameters to read."""

    flavour = "px4"

    def __init__(self, battery_pct, armed=False):
        self.state = SimpleNamespace(position_ok=True, battery_remaining_pct=battery_pct, armed=armed,
                                     system_status=3)
        self.prearm, self.uid = ReadyPrearm(), None

    def link_age_s(self):
        return 0.2

    async def wait_home(self, timeout_s):
        from mission.sim.embedded import DEFAULT_ORIGIN

        return DEFAULT_ORIGIN


def test_preflight_phase_runs_on_narrow_services_and_judges_each_vehicle():
    from mission.flight.phases.connect import Preflight

    plan = _plan(3)
    clock = FakeClock()
    state = MissionState([1, 2, 3], clock=clock)
    fleet, events = Fleet({1: "a", 2: "b", 3: "c"}), FakeEvents()
    for sysid, v in ((1, FakePreflightVehicle(80.0)), (2, FakePreflightVehicle(10.0)),
                     (3, FakePreflightVehicle(90.0, armed=True))):
        v.sysid = sysid
        fleet.add(v)
    checked = []

    class Checks:
        async def check(self):
            checked.append(sorted(state.readiness))

    envelope = asyncio.run(Preflight(plan, state, fleet, clock, events, Checks).run(timeout_s=2.0))
    assert envelope is not None and envelope.fence.contains(np.array([0.0, 0.0, 10.0]))
    assert checked == [[1, 2, 3]] and events.phases == ["preflight"]
    r = state.readiness
    assert r[1].ready and r[1].checks["home_in_fence"]
    assert not r[2].ready and r[2].problems == ["battery 10 % below 30 %"]
    assert not r[3].ready and r[3].problems[0].startswith("already armed")
    assert any(m == "vehicle 1 (px41): ready" for _, m in events.events)


class FakeGuard:
    """The never-abandon check: records what it was asked."""

    def __init__(self, calls, left=()):
        self.calls, self.left = calls, list(left)

    async def secure(self, why, land=True):
        self.calls.append(("secure", why, land))
        return self.left, False

    async def land_now(self):
        self.calls.append(("land_now",))


def _mission_end(calls, return_home, return_on_interrupt=True, left=()):
    from mission.flight.phases.mission_end import MissionEnd

    clock = FakeClock()
    state, events = MissionState([1, 2, 3, 4], clock=clock), FakeEvents()

    async def stop_background():
        calls.append(("stop",))

    def result(outcome, message):
        calls.append(("result", outcome, message))
        return SimpleNamespace(outcome=outcome, message=message)

    end = MissionEnd(state, events, return_home, lambda: FakeGuard(calls, left), stop_background, result,
                     None, return_on_interrupt)
    return end, state, events


def test_mission_end_runs_on_narrow_services_return_secure_stop_summary_in_order():
    calls = []

    async def return_home():
        calls.append(("return",))

    end, state, events = _mission_end(calls, return_home, left=[3])
    result = asyncio.run(end.run("converged", "converged after 4 iterations"))
    assert calls == [("return",), ("secure", "mission converged after 4 iterations", True), ("stop",),
                     ("result", "converged", "converged after 4 iterations")]
    assert result.airborne_left == [3] and result.interrupted_by == [] and state.final_result is result
    assert state.ending["outcome"] == "converged" and events.phases == ["done"]


@pytest.mark.parametrize("return_on_interrupt", [True, False])
def test_mission_end_of_an_interrupted_mission_lands_at_the_next_interrupt_and_goes_on_cancelling(
        return_on_interrupt):
    calls = []

    async def return_home():
        calls.append(("return",))
        raise asyncio.CancelledError()  # another interrupt during the return

    end, state, events = _mission_end(calls, return_home, return_on_interrupt)

    async def go():
        with pytest.raises(asyncio.CancelledError):
            await end.run("interrupted", "interrupted (SIGINT)", interrupted=True)

    asyncio.run(go())
    if return_on_interrupt:  # the return, cut by the second interrupt: every vehicle lands where it is
        assert calls[:3] == [("return",), ("land_now",), ("secure", "mission interrupted (SIGINT)", True)]
        assert any("LANDING every airborne vehicle" in m for _, m in events.events)
    else:  # a ground station told to just stop: no return, no landing
        assert calls[0] == ("secure", "mission interrupted (SIGINT)", False)
    assert calls[-2:] == [("stop",), ("result", "interrupted", "interrupted (SIGINT)")]
    assert events.phases == ["aborted", "done"] and state.final_result is not None


def test_run_until_stopped_takes_the_mission_coroutine_its_state_and_log():
    from mission.flight.operator_stop import run_until_stopped

    clock = FakeClock()
    state = MissionState([1], clock=clock)

    async def mission():
        return "the result"

    async def stopped():
        task = asyncio.current_task()
        state.note_interrupt("SIGTERM")
        state.finish(SimpleNamespace(outcome="interrupted"))
        task.get_loop().call_soon(task.cancel)
        await asyncio.sleep(10)

    assert asyncio.run(run_until_stopped(mission(), state)) == "the result"
    # a cancellation after a counted stop returns the result the mission left in its state
    assert asyncio.run(run_until_stopped(stopped(), state)).outcome == "interrupted"


class FakeFlyingVehicle(FakeVehicle):
    """A vehicle found at resume: its home is the origin, its mode set when asked."""

    def __init__(self, sysid, clock, position, armed=True, mode="POSCTL", rel_alt_m=10.0):
        super().__init__(sysid, clock, position)
        self.state = SimpleNamespace(armed=armed, landed=False, home=None, mode=mode, position_ok=True,
                                     relative_alt_m=rel_alt_m)

    async def wait_home(self, timeout_s):
        from mission.sim.embedded import DEFAULT_ORIGIN

        return DEFAULT_ORIGIN

    async def set_mode(self, mode):
        self.commands.append(mode)
        self.state.mode = mode


@pytest.mark.parametrize("go_on", [True, False])
def test_resume_phase_runs_on_narrow_services_and_reengages_the_vehicles_still_flying(go_on):
    from mission.flight.phases.resume import Resume, ResumeState

    clock, state, fleet, events, waiter = _services(6)
    fleet.vehicles[5] = FakeFlyingVehicle(5, clock, (0.0, 0.0, 0.0), armed=False, rel_alt_m=0.0)
    fleet.vehicles[6] = FakeFlyingVehicle(6, clock, (0.0, 6.0, 10.0), mode="AUTO.RTL")
    for s in range(1, 5):
        fleet.vehicles[s] = FakeFlyingVehicle(s, clock, (3.0 * s, 0.0, 10.0))
    plan = _plan(6)
    resume = ResumeState(plan, 7, np.array([1.0, 2.0, 10.0]), centres=[np.array([1.0, 2.0, 10.0])],
                         slot_offsets={s: np.array([float(s), 0.0, 0.0]) for s in range(1, 7)},
                         layer_alt_m={s: 10.0 for s in range(1, 7)}, go_on=go_on, ending="cut")
    gate, calls = FakeGate(), []

    async def connect():
        calls.append("connect")

    async def seek(**resumed):
        calls.append(("seek", resumed["start_iteration"], len(resumed["history"])))
        return "converged", "converged"

    phase = Resume(plan, state, fleet, clock, events, waiter, connect, lambda e: calls.append(("envelope", e is not None)),
                   lambda vehicles: calls.append(("setpoints", sorted(v.sysid for v in vehicles))) or gate,
                   lambda records: calls.append(("retired", records)), seek)
    outcome = asyncio.run(phase.run(resume))
    assert calls[:3] == ["connect", ("envelope", True), ("setpoints", [1, 2, 3, 4])]
    assert gate.started and sorted(gate.sysids) == [1, 2, 3, 4] and sorted(state.airborne) == [1, 2, 3, 4]
    assert all(fleet.vehicles[s].commands == ["OFFBOARD"] for s in range(1, 5))
    assert sorted(state.lost) == [5, 6] and state.iteration == 7
    assert "on the ground (disarmed)" in state.status[5] and "AUTO.RTL" in state.status[6]
    if go_on:
        assert outcome == ("converged", "converged") and calls[-1] == ("seek", 7, 1)
    else:
        assert outcome[0] == "recovered" and "[1, 2, 3, 4] flying: bringing them home" in outcome[1]


class FakeSeekFormation:
    """The seek's formation keepers for a formation that loses nobody: moves land at once."""

    def __init__(self, fleet, gate, state):
        self.fleet, self.gate, self.state, self.moves = fleet, gate, state, 0

    async def reform(self, centre_enu, sysids):
        raise AssertionError("nobody is lost")

    def pending_readmissions(self):
        return []

    async def keep_out_retired(self, returning):
        return list(returning)

    async def readmit(self, centre_enu, sysids, returning):
        raise AssertionError("nobody returns")

    def clear_goals(self, centre_enu, sysids):
        return False

    async def fly_rotation(self, centre_enu, sysids, before):
        return None

    def formation_goals(self, centre_enu, sysids):
        return {s: np.asarray(centre_enu, float) + self.state.slot_offsets[s] for s in sysids}

    def make_watch(self, check, sysids):
        return None

    async def retire_sensor(self, centre_enu, sysids, info):
        raise AssertionError("no sensor is retired")

    async def move_and_wait(self, goals, tol_m, timeout_s=None, what=""):
        self.moves += 1
        self.gate.set_goals(goals)
        for s, g in goals.items():
            self.fleet.vehicles[s].position = np.asarray(g, float)

    def parked(self):
        return []


class FakeReadingStore:
    """Readings of a concave field taken where the vehicles are, at the clock's time."""

    def __init__(self, fleet, clock, source):
        self.fleet, self.clock, self.source = fleet, clock, np.asarray(source, float)

    def latest(self, sysid):
        p = self.fleet.vehicles[sysid].position
        return SimpleNamespace(sysid=sysid, time_s=self.clock.time(), position_enu_m=p,
                               value=-float(np.sum((p - self.source) ** 2)), seq=0)

    def aligned(self, t_s, window_s, sysids):
        return {s: self.latest(s) for s in sysids}

    def counts(self):
        return {"accepted": 0, "rejected": {}}


def _gradient_seek(max_iterations: int):
    """Four vehicles in a CVT formation at (0, 0, 12) m, the source 10 m east, the gradient seeker
    with ``gamma_m`` 1 m: the services, the plan and what a :class:`Seek` is built from."""
    import dataclasses

    from mission.flight.targets import formation_offsets

    clock, state, fleet, events, waiter = _services(4)
    plan = _plan(4)
    plan = dataclasses.replace(plan, seeking=dataclasses.replace(plan.seeking, seeker="gradient", estimator="cvt",
                                                                 max_iterations=max_iterations, gamma_m=1.0, eps=0.1))
    offsets = formation_offsets("cvt", 4, plan.formation.radius_m)
    centre, source = np.array([0.0, 0.0, 12.0]), np.array([10.0, 0.0, 12.0])
    state.set_formation({s: offsets[s - 1] for s in range(1, 5)})
    state.move_centre(centre)
    gate = FakeGate({s: centre + offsets[s - 1] for s in range(1, 5)})
    formation = FakeSeekFormation(fleet, gate, state)
    return clock, state, fleet, events, waiter, plan, centre, source, gate, formation


def test_seek_phase_runs_on_narrow_services_and_climbs_the_field():
    from mission.flight.phases.seek import Seek

    clock, state, fleet, events, waiter, plan, centre, source, gate, formation = _gradient_seek(3)
    checkpoints = []

    async def checkpoint():
        checkpoints.append(clock.time())

    seek = Seek(plan, state, fleet, gate, clock, events, waiter, FakeReadingStore(fleet, clock, source), None, None,
                formation, checkpoint, lambda: [])
    outcome, message = asyncio.run(seek.run())
    assert (outcome, message) == ("max_iterations", "not converged after 3 iterations")
    assert events.phases == ["seek"] and len(checkpoints) == 3 and formation.moves == 3
    assert state.iteration == 3
    # the gradient points at the source (+x): three capped steps of gamma_m = 1 m towards it
    np.testing.assert_allclose(state.centre_enu, centre + [3.0, 0.0, 0.0], atol=1e-6)


class GappyReadingStore(FakeReadingStore):
    """Readings as :class:`FakeReadingStore`, but the ``gap``-th estimate gets only 3 aligned readings
    (one vehicle's reading lost, as a starved zenoh delivery does under load)."""

    def __init__(self, fleet, clock, source, gap):
        super().__init__(fleet, clock, source)
        self.gap, self.calls = gap, 0

    def aligned(self, t_s, window_s, sysids):
        self.calls += 1
        readings = super().aligned(t_s, window_s, sysids)
        return dict(list(readings.items())[:3]) if self.calls == self.gap else readings


class RecordingLog:
    """A mission log that keeps what is written, ``(type, fields)``."""

    def __init__(self):
        self.records = []

    def write(self, kind, **fields):
        self.records.append((kind, fields))


def test_a_seek_try_without_an_estimate_is_made_again_under_the_same_number():
    """Iteration 2 gets 3 aligned readings (no estimate): it is tried again as iteration 2, so the
    log's iterations are numbered 1, 2, 3 without a gap (before: 1, 3, iteration 2 never written);
    the try counts towards ``max_iterations``."""
    from mission.flight.phases.seek import Seek

    clock, state, fleet, events, waiter, plan, centre, source, gate, formation = _gradient_seek(4)
    log = RecordingLog()

    async def checkpoint():
        pass

    seek = Seek(plan, state, fleet, gate, clock, events, waiter, GappyReadingStore(fleet, clock, source, gap=2),
                None, log, formation, checkpoint, lambda: [])
    outcome, message = asyncio.run(seek.run())
    assert [f["k"] for kind, f in log.records if kind == "iteration"] == [1, 2, 3]
    assert any("iteration 2: only 3 aligned readings" in m for _level, m in events.events), events.events
    assert (outcome, message) == ("max_iterations", "not converged after 3 iterations (1 more tried without an "
                                                    "estimate)")
    assert state.iteration == 3 and formation.moves == 4
    np.testing.assert_allclose(state.centre_enu, centre + [3.0, 0.0, 0.0], atol=1e-6)


def test_the_seek_checkpoint_holds_the_gate_while_paused_on_narrow_services():
    from mission.flight.control import MissionControl

    clock, state, fleet, events, waiter = _services(4)
    state.set_phase("seek")
    gate = FakeGate({s: v.position for s, v in fleet.vehicles.items()})
    control = MissionControl(clock)
    assert control.submit("pause", "operator", "seek").accepted

    async def go():
        held = asyncio.ensure_future(control.checkpoint(state, gate, events, clock, waiter))
        while clock.time() < 3.0:
            await clock.sleep(0.1)
            assert not held.done()  # holds while paused
        assert control.holding
        assert control.submit("continue", "operator", "seek").accepted
        await asyncio.wait_for(held, timeout=10.0)

    asyncio.run(go())
    assert events.events[0][1] == "paused by operator: the formation holds at iteration 0"
    assert events.events[-1][1].startswith("continued after ") and not control.holding
