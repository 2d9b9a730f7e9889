"""The return phase keeps clear of lost vehicles still flying (``mission.flight.return_clear``): the
planning (layers, detours, transfers, landing spots), the flight and its events against a fake
coordinator, then one whole mission against the mock fleet with a vehicle hovering on a
survivor's return path."""
from __future__ import annotations

import asyncio
import dataclasses
import json
import threading
from types import SimpleNamespace

import numpy as np
import pytest

from mission.flight.obstacles import OBSTACLE_MARGIN_M
from mission.flight.return_plan import landing_spots, path_clearance, plan_clear_return
from mission.safety.fence import Geofence
from mission.flight.targets import layered_transfer
from tests.support.fly_helpers import fly, run_fleet

pytestmark = pytest.mark.timeout(300)

SEP_M = 1.5
CLEAR_M = SEP_M + OBSTACLE_MARGIN_M
# three vehicles in formation about (0, 0, 11), homes 20 m east, layers 1.25 * SEP_M apart
START = np.array([[0.0, 0.0, 10.0], [-2.0, 3.0, 12.0], [-2.0, -3.0, 13.0]])
HOMES = np.array([[20.0, 0.0, 0.0], [20.0, 5.0, 0.0], [20.0, -5.0, 0.0]])
LAYERS = np.array([8.0, 9.875, 11.75])
GOAL = np.c_[HOMES[:, :2], LAYERS]


def _straight(start=START, goal=GOAL, layers=LAYERS):
    return np.stack([start, *layered_transfer(start, goal, layers)])


# ------------------------------------------------------------------------------ planning
@pytest.mark.parametrize("obstacle, strategy", [
    ([10.0, 0.0, 8.3], "layered+detour"),        # on vehicle 1's horizontal leg at its layer
    ([10.0, 5.0, 9.5], "layered+detour"),        # between two layers, on vehicle 2's leg
    ([-2.0, -3.0, 10.5], "transfer"),             # under vehicle 3, on its way down to its layer
])
def test_plan_keeps_clear_of_an_obstacle_on_a_straight_return_path(obstacle, strategy):
    obs = np.array([obstacle])
    assert path_clearance(_straight(), obs) < SEP_M          # the usual legs would pass too close
    plan = plan_clear_return(START, GOAL, LAYERS, obs, SEP_M, CLEAR_M, 3.0)
    assert plan.clear and plan.strategy.startswith(strategy)
    wps = plan.waypoints_enu
    assert np.allclose(wps[0], START) and np.allclose(wps[-1], GOAL)
    assert path_clearance(wps, obs) >= CLEAR_M - 1e-9
    assert plan.clearance_m == pytest.approx(path_clearance(wps, obs))
    if plan.times_s is None:   # batch by batch, vehicles not in step: paths pairwise apart
        from mission.flight.return_plan import _batch_separation

        assert _batch_separation(wps[1:]) >= SEP_M
    else:
        from mission.safety.transfer import leg_separation

        assert np.all(np.diff(plan.times_s) >= 0)
        assert min(leg_separation(a, b) for a, b in zip(wps[:-1], wps[1:])) >= SEP_M - 1e-9


def test_detour_round_a_wall_takes_two_turns():
    wall = np.array([[2.5, y, 8.0] for y in np.arange(-3.0, 3.01, 1.5)])   # across the path, close
    start, goal = np.array([[0.0, 0.0, 8.0]]), np.array([[5.0, 0.0, 8.0]])
    assert path_clearance(np.stack([start, goal]), wall) < SEP_M
    plan = plan_clear_return(start, goal, [8.0], wall, SEP_M, CLEAR_M, 3.0)
    assert plan.clear and plan.strategy == "layered+detour"
    assert len(plan.waypoints_enu) == 6                   # start, layer, two turns, across, goal
    assert path_clearance(plan.waypoints_enu, wall) >= CLEAR_M - 1e-9


def test_plan_without_obstacles_is_the_usual_layered_return():
    plan = plan_clear_return(START, GOAL, LAYERS, np.zeros((0, 3)), SEP_M, CLEAR_M, 3.0)
    assert plan.strategy == "layered" and plan.clear and plan.times_s is None
    assert np.array_equal(plan.waypoints_enu, _straight())
    assert plan.clearance_m == np.inf


def test_detour_stays_inside_the_fence():
    fence = Geofence(np.array([[-10.0, -10.0], [30.0, -10.0], [30.0, 1.5], [-10.0, 1.5]]), 2.0, 40.0)
    start, goal, layers = START[[0, 2]], GOAL[[0, 2]], LAYERS[[0, 2]]
    obs = np.array([[10.0, 0.0, 8.0]])                  # north of it: the fence, 1.5 m away
    plan = plan_clear_return(start, goal, layers, obs, SEP_M, CLEAR_M, 3.0, fence=fence)
    assert plan.clear
    wps = plan.waypoints_enu
    assert np.all(fence.contains(wps[1:].reshape(-1, 3)))
    assert np.min(wps[..., 1]) < -CLEAR_M + 1e-6       # it went round by the south


def test_no_clear_plan_returns_the_best_without_raising():
    obs = np.array([START[1] + [0.0, 0.0, 0.5]])        # hovering right on top of a vehicle
    plan = plan_clear_return(START, GOAL, LAYERS, obs, SEP_M, CLEAR_M, 3.0)
    assert not plan.clear
    assert np.allclose(plan.waypoints_enu[0], START) and np.allclose(plan.waypoints_enu[-1], GOAL)
    assert plan.clearance_m >= path_clearance(_straight(), obs)


@pytest.mark.parametrize("bad, match", [
    (dict(layer_alt_m=LAYERS[:2]), "must be"),
    (dict(obstacle_points=[[np.nan, 0.0, 0.0]]), "finite"),
])
def test_plan_rejects_bad_input(bad, match):
    args = dict(start=START, goal=GOAL, layer_alt_m=LAYERS, obstacle_points=np.zeros((0, 3)),
                min_separation_m=SEP_M, clearance_m=CLEAR_M, max_speed_m_s=3.0) | bad
    with pytest.raises(ValueError, match=match):
        plan_clear_return(**args)


@pytest.mark.parametrize("obstacle, rtl, moved", [
    ([20.0, 0.3, 4.0], False, True),      # on vehicle 1's descent column
    ([20.0, 0.3, 30.0], False, False),    # above its layer: a landing does not pass it
    ([20.0, 0.3, 30.0], True, True),      # ... but RTL flies its own way over home: land beside
    ([25.0, 30.0, 4.0], True, False),     # far away
])
def test_landing_spots_move_off_an_obstructed_home(obstacle, rtl, moved):
    obs = np.array([obstacle])
    spots, was_moved, ok = landing_spots(HOMES, LAYERS, obs, CLEAR_M, SEP_M, rtl=rtl)
    assert ok.all() and was_moved.tolist() == [moved, False, False]
    assert np.array_equal(spots[1:], HOMES[1:]) and spots[0, 2] == HOMES[0, 2]
    top = np.c_[spots[:, :2], LAYERS]
    assert path_clearance(np.stack([top, spots]), obs) >= CLEAR_M - 1e-9
    assert np.min(np.linalg.norm(spots[0, :2] - spots[1:, :2], axis=1)) >= SEP_M
    if moved:
        assert 0 < np.linalg.norm(spots[0] - HOMES[0]) <= CLEAR_M + 0.5


# ------------------------------------------------------------ flight against a fake coordinator
class _FakeClock:
    """Mission clock that advances on ``sleep`` and steps the ramp (no wall time)."""

    def __init__(self):
        self.t = 1000.0
        self.gate = None
        self.speedup = 1.0
        self.on_tick = None

    def time(self):
        return self.t

    async def sleep(self, dt_s):
        steps = max(1, int(round(dt_s / 0.1)))
        for _ in range(steps):
            self.t += dt_s / steps
            if self.gate is not None:
                self.gate.step(dt_s / steps)
            if self.on_tick is not None:
                self.on_tick(self.t)
        await asyncio.sleep(0)


class _FakeCoordinator:
    def __init__(self, start, homes, layers, return_behaviour="land"):
        from mission.safety.gate import SafetyGate

        self.clock = _FakeClock()
        streamer = SimpleNamespace(set_target=lambda s, p: None, remove=lambda s: None)
        self.gate = SafetyGate(streamer, self.clock, 3.0, rate_hz=10.0)
        self.clock.gate = self.gate
        self.sysids = list(range(1, len(start) + 1))
        for s, p in zip(self.sysids, start):
            self.gate.add(s, p)
        self.state = SimpleNamespace(home_enu=dict(zip(self.sysids, homes)),
                                     layer_alt_m=dict(zip(self.sysids, layers)), phase="return", lost={},
                                     status={})
        self.plan = SimpleNamespace(min_separation_m=SEP_M, return_behaviour=return_behaviour,
                                    seeking=SimpleNamespace(arrival_tol_m=0.35))
        self.envelope = None
        self.fleet = SimpleNamespace(vehicles={}, telemetry_position=self.telemetry_position)
        self.state.add_positions = lambda positions: self.update_odometry()  # the track, at each poll
        self.events: list = []
        self.track: list = []

    def event(self, message, level="info", **fields):
        self.events.append((level, message))

    def update_odometry(self):
        self.track.append(np.array([self.gate.setpoint(s) for s in self.gate.sysids]))

    def telemetry_position(self, sysid):
        return self.gate.setpoint(sysid)

    async def wait_until(self, predicate, timeout_s, what, poll_s=0.1):
        from mission.flight.state import MissionError

        deadline = self.clock.time() + timeout_s
        while not predicate():
            if self.clock.time() > deadline:
                raise MissionError(f"timed out after {timeout_s:.0f} s waiting for {what}")
            await self.clock.sleep(poll_s)

    def return_clear(self):
        """The :class:`~mission.flight.return_clear.ReturnClear` over this fake: its gate, state and
        clock, the mission's own moves (:class:`mission.flight.motion.GateMotion`) flown on them."""
        from mission.flight.motion import GateMotion
        from mission.flight.return_clear import ReturnClear

        moves = GateMotion(self.state, self.fleet, lambda: self.gate, lambda: None, self.clock, self, self,
                           return_behaviour=self.plan.return_behaviour, min_separation_m=SEP_M, max_speed_m_s=3.0,
                           arrival_tol_m=0.35)
        return ReturnClear(self.state, self.fleet, self.gate, self.clock, SEP_M, 0.35, 30.0,
                           self.plan.return_behaviour, None, moves, self)


@pytest.mark.parametrize("obstacle, level, land_here", [
    (None, None, set()),
    ([10.0, 0.0, 8.3], "info", set()),
    ([20.0, 0.3, 4.0], "info", {1}),
    ([0.0, 0.0, 10.4], "warning", set()),       # on top of vehicle 1: nothing keeps clear
])
def test_fly_return_flies_clear_and_says_so(monkeypatch, obstacle, level, land_here):
    from mission.flight import return_clear

    obs = np.zeros((0, 3)) if obstacle is None else np.array([obstacle])
    monkeypatch.setattr(return_clear, "obstacles", lambda lost, fleet, now_s: obs)
    co = _FakeCoordinator(START, HOMES, LAYERS)
    got = asyncio.run(co.return_clear().fly_return(co.sysids))
    assert got == land_here
    end = np.array([co.gate.setpoint(s) for s in co.sysids])
    assert np.allclose(end[:, 2], LAYERS, atol=1e-6)                      # above the spots at the layers
    assert [lv for lv, m in co.events if "return" in m] == ([] if level is None else [level])
    if level == "info":
        track = np.array(co.track)                                        # setpoints every 0.1 s
        d = np.linalg.norm(track - obs[0], axis=-1)
        assert d.min() >= CLEAR_M - 0.05


def test_fly_clear_assembles_round_a_vehicle_lost_during_the_takeoff(monkeypatch):
    from mission.flight import return_clear

    above_homes = np.c_[HOMES[:, :2], LAYERS]                   # after the takeoff
    obs = np.array([[10.0, 0.2, 8.0]])                           # lost climbing, on vehicle 1's way
    monkeypatch.setattr(return_clear, "obstacles", lambda lost, fleet, now_s: obs)
    co = _FakeCoordinator(above_homes, HOMES, LAYERS)
    co.state.phase = "assemble"
    asyncio.run(co.return_clear().fly_clear(co.sysids, dict(zip(co.sysids, START)), 0.35))
    assert np.allclose([co.gate.setpoint(s) for s in co.sysids], START, atol=1e-6)
    assert [(lv, m.split(":")[0]) for lv, m in co.events] == [
        ("info", "assembly re-planned around 1 position(s) of lost vehicles still flying")]
    assert np.linalg.norm(np.array(co.track) - obs[0], axis=-1).min() >= CLEAR_M - 0.05
    assert co.state.status[1] == "assemble: slots"


def test_fly_return_replans_after_a_loss_on_the_way(monkeypatch):
    from mission.flight import return_clear

    co = _FakeCoordinator(START, HOMES, LAYERS)
    t_loss = co.clock.t + 4.0
    hovering = []

    def _tick(t):
        if t >= t_loss and 3 not in co.state.lost:              # vehicle 3 falls silent mid-way and hovers
            hovering.append(co.gate.setpoint(3))
            co.state.lost[3] = object()
            co.gate.remove(3)

    co.clock.on_tick = _tick
    monkeypatch.setattr(return_clear, "obstacles", lambda lost, fleet, now_s: np.array(hovering).reshape(-1, 3))
    asyncio.run(co.return_clear().fly_return(co.sysids))
    warnings = [m for lv, m in co.events if lv == "warning"]
    assert warnings == ["return: a vehicle was lost on the way; re-planning from where the others are"]
    assert hovering and hovering[0][0] > START[2, 0]                 # it was on its way home
    end = np.array([co.gate.setpoint(s) for s in (1, 2)])
    assert np.allclose(end, GOAL[:2], atol=1e-6)


# ------------------------------------------------------------------------ against the mock
def _blocking_pick(homes, layers_by_sysid):
    """Cut the vehicle that sits closest to another's straight return path (``layered_transfer``)."""
    def pick(fleet):
        pos = {v.sysid: np.asarray(v.true_position_enu(), dtype=float) for v in fleet.vehicles}
        best, best_d = None, np.inf
        for cut in pos:
            others = sorted(s for s in pos if s != cut)
            start = np.array([pos[s] for s in others])
            lay = np.array([layers_by_sysid()[s] for s in others])
            goal = np.c_[np.array([homes[s - 1] for s in others])[:, :2], lay]
            d = path_clearance(_straight(start, goal, lay), [pos[cut]])
            if d < best_d:
                best, best_d = cut, d
        return best
    return pick


class _Watcher(threading.Thread):
    """Cuts the link of ``pick(fleet)`` at the first iteration, then samples every vehicle's true
    position (fleet clock) for the closest approach of a survivor to it."""

    def __init__(self, fleet, log_path, pick):
        super().__init__(daemon=True)
        self.fleet, self.log_path, self.pick = fleet, log_path, pick
        self.cut = None
        self.closest_m = np.inf
        self.done = threading.Event()

    def run(self):
        deadline = self.fleet.clock.time() + 900.0
        while not self.done.is_set() and self.fleet.clock.time() < deadline:
            text = self.log_path.read_text() if self.log_path.exists() else ""
            if self.cut is None and '"type":"iteration"' in text:
                self.cut = self.pick(self.fleet)
                self.fleet.set_fault(self.cut, "link_cut", True)
            if self.cut is not None:
                pos = {v.sysid: np.asarray(v.true_position_enu(), dtype=float) for v in self.fleet.vehicles}
                if pos[self.cut][2] > 3.0:
                    others = np.array([p for s, p in pos.items() if s != self.cut and p[2] > 0.3])
                    if len(others):
                        d = np.linalg.norm(others - pos[self.cut], axis=1)
                        self.closest_m = min(self.closest_m, float(np.min(d)))
            self.fleet.clock.sleep_blocking(0.05)


def _whole_mission(tmp_path, keep_clear, monkeypatch):
    from mission.flight import return_clear
    from mission.sim.embedded import DEFAULT_ORIGIN, embedded_plan, fleet_ports
    from mission.telemetry.mission_log import read_mission_log
    from sitl_mock.fields_gaussian import sigma2
    from mission.sim.lockstep import VirtualClock
    from sitl_mock.fleet import MockFleet

    if not keep_clear:
        monkeypatch.setattr(return_clear, "obstacles", lambda lost, fleet, now_s: np.zeros((0, 3)))
    n = 4                                    # one lost: 3 left, the seek ends and they return
    # a row of homes west-north-west (found by search with the shared
    # layers of mission.flight.layers): a survivor flies home at its layer straight through the slot of
    # the vehicle cut at the first iteration (closest approach about 0.1 m)
    homes = np.array([[-11.6, 4.7, 0.0], [-16.0, 7.2, 0.0], [-20.3, 9.7, 0.0], [-24.6, 12.2, 0.0]])
    source = np.array([-20.0, 0.0, 12.0])
    ports = fleet_ports(n, "px4")
    fleet = MockFleet(n=n, personality="px4", field=sigma2(source), origin=DEFAULT_ORIGIN, clock=VirtualClock(),
                      seed=5, home_offsets_enu=homes, udp_base_port=ports["udp_base_port"],
                      udp_bind_base_port=ports["udp_bind_base_port"], tcp_base_port=0, fleet_name="swarmseek",
                      zenoh_listen=[f"tcp/127.0.0.1:{ports['zenoh_port']}"], sensor_noise_std=0.005,
                      params={"COM_OBL_RC_ACT": 5})  # the cut vehicle hovers (hold); the default 0 descends
    plan = embedded_plan(n, ports, start_enu_m=(0.0, 0.0, 11.0), max_iterations=20)
    plan = dataclasses.replace(plan, takeoff_alt_m=6.0)
    log_path = tmp_path / "m.jsonl"
    layers: dict = {}

    def _layers():
        for line in log_path.read_text().splitlines():
            if not layers and '"layers"' in line:      # the formation event, written at the takeoff
                layers.update({int(k): float(v) for k, v in json.loads(line)["layers"].items()})
        return layers

    # the fleet's origin is the plan's: homes are mission ENU
    watcher = _Watcher(fleet, log_path, _blocking_pick(homes, _layers))

    watcher.start()
    try:
        result = run_fleet(fleet, lambda world: fly(plan, fleet, log_path, world=world))
    finally:
        watcher.done.set()
        watcher.join(timeout=30)
        fleet.stop()
    return plan, result, watcher, read_mission_log(log_path)


@pytest.mark.slow
@pytest.mark.parametrize("keep_clear", [True, False])
def test_survivors_return_clear_of_a_vehicle_hovering_on_their_path(tmp_path, monkeypatch, keep_clear):
    plan, result, w, records = _whole_mission(tmp_path, keep_clear, monkeypatch)
    messages = [r["message"] for r in records if r["type"] == "event"]
    print(f"\nreturn, keep-clear {'on' if keep_clear else 'off'}: outcome {result.outcome}, cut {w.cut}, "
          f"closest approach of a survivor to it {w.closest_m:.2f} m")
    assert w.cut is not None and result.outcome == "too_few_vehicles", (result.message, messages[-10:])
    assert np.isfinite(w.closest_m)
    landed = [m for m in messages if m.endswith("landed")]
    assert len(landed) == 3, messages[-10:]
    if keep_clear:
        assert any(m.startswith("return re-planned around") for m in messages), messages[-10:]
        assert w.closest_m >= plan.min_separation_m, (w.closest_m, messages[-10:])
    else:  # the scenario is a real conflict: the straight return passes within the separation
        assert w.closest_m < plan.min_separation_m, w.closest_m
