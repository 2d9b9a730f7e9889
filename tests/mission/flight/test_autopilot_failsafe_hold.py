"""A vehicle whose autopilot took over for a failsafe of its own is handed to it, never pulled back
into OFFBOARD/GUIDED (docs/faults.md: real PX4 holds in AUTO.LOITER for ``COM_FAIL_ACT_T`` before
its geofence action; the watchdog used to take that hold for its own setpoint pause and re-engage).

Unit level with the fakes of ``faults_fakes`` (the watchdog and the loss monitor on their own), then
a whole mission on the mock PX4 fleet, whose geofence now holds for ``COM_FAIL_ACT_T`` first as
real PX4 does.
"""
from __future__ import annotations

import asyncio
import threading
from types import SimpleNamespace

import numpy as np
import pytest
from tests.mission.flight.faults_fakes import FakeClock, FakeGate, FakeVehicle, Recorder, fleet_of, flying_state, ring
from tests.mission.flight.test_faults_objects import _monitor, _Status, _watch
from tests.support.wait_helpers import wait_until_async

from mission.core.plan_types import FaultsPlan
from mission.flight.faults.loss import (OWN_PAUSE_S, announced_failsafe, autopilot_failsafe, classify_loss,
                                       data_link_acts, offboard_loss_mode)
from mission.flight.state import VehicleReadiness
from mission.flight.faults.watchdog import Watchdog

_CRITICAL, _ACTIVE = 5, 4


def _hold(v: FakeVehicle, status: int, since_s: float = 0.0) -> FakeVehicle:
    v.state.mode, v.state.system_status, v.status_since_s = "AUTO.LOITER", status, since_s
    return v


@pytest.mark.parametrize("mode, status, gap_s, loss_mode, armed, expected", [
    ("AUTO.LOITER", _CRITICAL, 0.1, None, True, True),           # PX4's geofence hold, our stream steady
    ("AUTO.LOITER", _CRITICAL, OWN_PAUSE_S, None, True, False),  # our own pause may have caused it
    ("AUTO.LOITER", _CRITICAL, None, None, True, False),         # cannot tell: as before
    # its offboard loss gives POSCTL (COM_OBL_RC_ACT 0): a hold is its own failsafe, pause or not
    # (real PX4 SIH at load 18: battery critical, "Failsafe activated: entering Hold for 5 seconds",
    # while our stream had just paused 1.4 s; the watchdog re-engaged it and PX4 took OFFBOARD back)
    ("AUTO.LOITER", _CRITICAL, 1.4, "POSCTL", True, True),
    ("POSCTL", _CRITICAL, 1.4, "POSCTL", True, False),           # that is its offboard loss: re-engaged
    ("POSCTL", _CRITICAL, 0.1, "POSCTL", True, False),           # ... also after an uplink loss (sends steady)
    ("AUTO.LOITER", _CRITICAL, 0.1, "AUTO.LOITER", True, False),  # COM_OBL_RC_ACT 5: a hold is its offboard loss
    ("AUTO.LOITER", _ACTIVE, 0.1, "POSCTL", True, False),        # no failsafe announced
    ("POSCTL", 6, 0.0, None, True, True),                        # EMERGENCY too
    ("OFFBOARD", _CRITICAL, 0.1, None, True, False),             # still in the mission's mode
    ("AUTO.RTL", _CRITICAL, 0.1, None, True, False),             # RTL/LAND: "left" by the mode rule already
    ("AUTO.LOITER", _CRITICAL, 0.1, None, False, False),         # disarmed: another rule
])
def test_autopilot_failsafe_rule(mode, status, gap_s, loss_mode, armed, expected):
    v = SimpleNamespace(flavour="px4", state=SimpleNamespace(mode=mode, armed=armed, system_status=status),
                        status_since_s=None, statustexts=[])
    found = autopilot_failsafe(v, gap_s, loss_mode)
    assert (found is not None) == expected, found
    if expected:
        assert f"switched to {mode} in its own failsafe" in found


_HOLD_TEXT = "Failsafe activated: entering Hold for 5 seconds\t"  # PX4's words, its trailing tab too


@pytest.mark.parametrize("texts, mode, loss_mode, gap_s, expected", [
    # COM_OBL_RC_ACT 5: PX4's hold before a geofence / battery / data-link action is AUTO.LOITER like
    # its offboard loss; its words tell them apart
    ([(9.5, _HOLD_TEXT)], "AUTO.LOITER", "AUTO.LOITER", 0.1, True),
    ([(9.5, _HOLD_TEXT)], "AUTO.LOITER", "AUTO.LOITER", 1.4, True),     # even after a pause of ours
    ([(9.5, _HOLD_TEXT)], "AUTO.LOITER", None, 1.4, True),              # offboard-loss mode unknown
    ([(9.5, "Failsafe activated\t")], "AUTO.LOITER", "AUTO.LOITER", 0.1, False),  # the offboard loss itself
    ([(5.0, _HOLD_TEXT)], "AUTO.LOITER", "AUTO.LOITER", 0.1, False),    # said long before this mode began
    ([(9.5, _HOLD_TEXT), (9.8, "Failsafe activated")], "AUTO.LOITER", "AUTO.LOITER", 0.1, True),
    ([], "AUTO.LOITER", "AUTO.LOITER", 0.1, False),
])
def test_an_announced_hold_before_a_failsafe_action_is_the_autopilots_own(texts, mode, loss_mode, gap_s, expected):
    """The mode was first reported at t = 10 s; what PX4 said from 3 s before counts."""
    v = SimpleNamespace(flavour="px4", state=SimpleNamespace(mode=mode, armed=True, system_status=_CRITICAL),
                        status_since_s=10.0, statustexts=[(t, 2, text) for t, text in texts])
    found = autopilot_failsafe(v, gap_s, loss_mode)
    assert (found is not None) == expected, found
    if expected:
        assert "it said 'Failsafe activated: entering Hold for 5 seconds'" in found
        assert announced_failsafe(v) == "Failsafe activated: entering Hold for 5 seconds"


#: what real PX4 v1.16 SIH said (tests/conformance/test_conformance_px4_hold_failsafes.py), its tabs too
_GEOFENCE = ["Geofence: exceeding maximum altitude above Home\t", "Failsafe activated\t"]
_DATA_LINK = ["Connection to ground station lost\t", "Preflight Fail: No connection to the ground contro",
              "Failsafe activated\t", "GCS connection regained\t"]


@pytest.mark.parametrize("texts, dll_acts, said", [
    # COM_OBL_RC_ACT 5 and a failsafe whose action is Hold itself (GF_ACTION 2, NAV_DLL_ACT 1): no
    # "entering Hold" (nothing is delayed), the same AUTO.LOITER and "Failsafe activated" as the
    # offboard loss; PX4's check names the cause
    (_GEOFENCE, True, "Geofence: exceeding maximum altitude above Home"),
    (["Geofence: exceeding maximum distance to Home"], True, "Geofence: exceeding maximum distance to Home"),
    (["Geofence: approaching or outside geofence"], True, "Geofence: approaching or outside geofence"),
    (_DATA_LINK, True, "Connection to ground station lost"),
    (_DATA_LINK, False, None),                                  # NAV_DLL_ACT 0: the data-link loss does nothing
    (["Critical battery\t", "Failsafe activated\t"], True, "Critical battery"),
    (["Emergency battery level\t"], True, "Emergency battery level"),
    (["Low battery\t", "Failsafe activated\t"], True, None),   # only a warning: PX4 takes no action on it
    (["Failsafe activated\t"], True, None),                     # the offboard loss: re-engaged
])
def test_px4s_words_tell_its_own_failsafe_from_an_offboard_loss(texts, dll_acts, said):
    """With ``COM_OBL_RC_ACT`` 5 every case below is AUTO.LOITER, CRITICAL: only the words differ
    (heard 0.2 s before the mode was first reported at t = 10 s, or, for the data link, after it: PX4
    holds its STATUSTEXTs while it hears no ground station)."""
    t0 = 9.8 if texts is not _DATA_LINK else 14.0
    v = SimpleNamespace(flavour="px4", state=SimpleNamespace(mode="AUTO.LOITER", armed=True, system_status=_CRITICAL),
                        status_since_s=10.0, statustexts=[(t0 + 0.05 * k, 2, t) for k, t in enumerate(texts)])
    assert announced_failsafe(v, dll_acts) == said
    found = autopilot_failsafe(v, 0.1, "AUTO.LOITER", dll_acts)
    assert (found is None) == (said is None), found
    if said is not None:
        assert f"it said {said!r}" in found
    v.flavour = "ardupilot"                                     # PX4's words only
    assert announced_failsafe(v, dll_acts) is None


@pytest.mark.parametrize("params, expected", [({"NAV_DLL_ACT": 0}, False), ({"NAV_DLL_ACT": 3}, True), ({}, True)])
def test_data_link_acts_comes_from_the_preflight_parameters(params, expected):
    state = flying_state(2, FakeClock())
    state.set_readiness(VehicleReadiness(1, "v1", "udpin:x", failsafe_params=params), "ready")
    assert data_link_acts(state, 1, "px4") == expected
    assert data_link_acts(state, 2, "px4") is True             # not read (e.g. after a resume): it may act


@pytest.mark.parametrize("flavour, params, expected", [
    ("px4", {"COM_OBL_RC_ACT": 0, "NAV_DLL_ACT": 3}, "POSCTL"),
    ("px4", {"COM_OBL_RC_ACT": 5.0}, "AUTO.LOITER"),
    ("px4", {"COM_OBL_RC_ACT": 6}, None),            # terminate: no mode
    ("px4", {}, None),                               # not read
    ("ardupilot", {"FS_GCS_ENABLE": 5}, None),
])
def test_offboard_loss_mode_comes_from_the_preflight_parameters(flavour, params, expected):
    state = flying_state(2, FakeClock())
    state.set_readiness(VehicleReadiness(1, "v1", "udpin:x", failsafe_params=params), "ready")
    assert offboard_loss_mode(state, 1, flavour) == expected
    assert offboard_loss_mode(state, 2, flavour) is None     # no preflight record


def test_classify_loss_calls_an_autopilot_failsafe_hold_left_once_corroborated():
    v = _hold(FakeVehicle(1, np.zeros(3)), _CRITICAL)
    assert classify_loss(v, 10.0, 1.0, commanded=False, stream_gap_s=0.1)[0] == "left"
    assert classify_loss(v, 10.0, 1.0, commanded=False, stream_gap_s=1.5) is None   # ours: re-engaged instead
    assert classify_loss(v, 10.0, 1.0, commanded=False) is None                     # unknown stream: as before
    v.status_heartbeats = 1
    assert classify_loss(v, 10.0, 1.0, commanded=False, stream_gap_s=0.1)[0] == "unconfirmed"


def test_the_watchdog_leaves_an_autopilot_failsafe_hold_alone_and_reengages_its_own_pause():
    clock = FakeClock()
    state = flying_state(4, clock)
    vehicles = [FakeVehicle(s, ring(4)[s]) for s in range(1, 5)]
    _hold(vehicles[0], _CRITICAL)            # PX4's geofence hold (COM_FAIL_ACT_T): its own failsafe
    _hold(vehicles[1], _CRITICAL)            # offboard loss after a 1.2 s pause of our stream: ours
    _hold(vehicles[2], _ACTIVE)              # hold without a failsafe (e.g. a pilot's switch): as before
    _hold(vehicles[3], _CRITICAL)            # a hold after a 1.4 s pause, but its offboard loss gives POSCTL
    gate = FakeGate({s: ring(4)[s] for s in range(1, 5)})
    gate.pauses_s[2] = gate.pauses_s[4] = 1.4
    state.set_readiness(VehicleReadiness(4, "v4", "udpin:x", failsafe_params={"COM_OBL_RC_ACT": 0}), "ready")
    rec, status = Recorder(), _Status()
    dog = Watchdog(state, fleet_of(vehicles), lambda: gate, clock, FaultsPlan(), status, None, 1.0, rec, rec.report)

    async def main():
        task = asyncio.create_task(dog.run(period_s=0.01))
        try:
            await wait_until_async(lambda: state.reengaged.get(2) and state.reengaged.get(3), 10.0,
                                   "vehicles 2 and 3 re-engaged", poll_s=0.01)
            for _ in range(20):              # and some more rounds: vehicle 1 is still left alone
                await asyncio.sleep(0.01)
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)

    asyncio.run(main())
    assert vehicles[0].commands == [] and 1 not in state.reengaged
    assert vehicles[1].commands == ["mode OFFBOARD"] and vehicles[2].commands == ["mode OFFBOARD"]
    assert vehicles[3].commands == [] and 4 not in state.reengaged


def test_the_loss_monitor_declares_an_autopilot_failsafe_hold_left_and_commands_nothing():
    clock, state, vehicles, gate, rec, motion, monitor = _monitor(5)
    _hold(vehicles[2], _CRITICAL, since_s=clock.time())
    _watch(monitor, lambda: 3 in state.lost, "vehicle 3 lost")
    assert state.lost[3].reason == "left" and "in its own failsafe" in state.lost[3].detail
    assert 3 not in gate.sysids                              # off the setpoint stream
    assert [c for c in vehicles[2].commands if c != "heartbeat?"] == []   # no land/RTL/mode: PX4's failsafe flies it


def _fly_beside(fleet, plan, log_path, watch, done: threading.Event):
    """Fly ``plan`` in lock-step with ``watch()`` running in a thread beside it (it acts on the fleet
    until ``done`` is set); then set ``done``, join it and stop the fleet. Returns the result."""
    from tests.support.fly_helpers import fly, run_fleet

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    try:
        return run_fleet(fleet, lambda world: fly(plan, fleet, log_path, world=world))
    finally:
        done.set()
        watcher.join(timeout=30)
        fleet.stop()


# ------------------------------------------------------------------------------- the mock fleet
@pytest.mark.slow
@pytest.mark.timeout(600)
@pytest.mark.parametrize("obl_act", [0, 5])
def test_mock_px4_geofence_hold_is_not_fought(tmp_path, obl_act):
    """Five mock PX4 vehicles (GF_ACTION 5: land, COM_FAIL_ACT_T 5 s); after seek iteration 3 the
    fence ceiling of vehicle 3 is lowered under it: PX4 holds (AUTO.LOITER, system status CRITICAL)
    for 5 s then lands. The ground station calls it "left" in its own failsafe, never re-engages it,
    re-forms for 4 and goes on; vehicle 3 lands by itself (AUTO.LAND, disarmed). With
    ``COM_OBL_RC_ACT`` 5 its offboard loss is AUTO.LOITER too: only PX4's STATUSTEXT ("Failsafe
    activated: entering Hold for 5 seconds") tells the hold apart (before it was read, the hold was
    re-engaged, which PX4 takes as the user taking over: the land never came)."""
    from mission.sim.embedded import default_eps, embedded_plan, fleet_ports
    from mission.telemetry.mission_log import read_mission_log
    from sitl_mock.fields_gaussian import sigma2
    from tests.mission.flight.test_resilience import _fleet

    n = 5
    ports = fleet_ports(n, "px4")
    source = np.array([6.0, -4.0, 13.0])
    fleet = _fleet(n, ports, source)
    for s in range(1, n + 1):
        fleet.vehicle(s).params.set("GF_ACTION", 5)
        fleet.vehicle(s).params.set("COM_OBL_RC_ACT", obl_act)
    plan = embedded_plan(n, ports, start_enu_m=(0.0, 0.0, 11.0), eps=default_eps(sigma2(source)), max_iterations=80)
    log_path = tmp_path / "m.jsonl"
    modes: list[tuple[float, str, bool]] = []
    done = threading.Event()

    def lower_the_ceiling():
        deadline = fleet.clock.time() + 900.0
        while not done.is_set() and fleet.clock.time() < deadline:
            if log_path.exists() and log_path.read_text().count('"type":"iteration"') >= 3:
                fleet.vehicle(3).params.set("GF_MAX_VER_DIST", 5.0)   # it flies 9-13 m above home
                break
            fleet.clock.sleep_blocking(0.2)
        while not done.is_set() and fleet.clock.time() < deadline:   # vehicle 3's modes from then on
            v = fleet.vehicle(3)
            if not modes or modes[-1][1:] != (v.mode_name, v.armed):
                modes.append((fleet.clock.time(), v.mode_name, v.armed))
            fleet.clock.sleep_blocking(0.1)

    result = _fly_beside(fleet, plan, log_path, lower_the_ceiling, done)
    events = [r for r in read_mission_log(log_path) if r["type"] == "event"]
    messages = [e["message"] for e in events]
    lost = {x["sysid"]: x for x in result.lost}
    assert 3 in lost and lost[3]["reason"] == "left", (result.lost, messages[-15:])
    lost_message = next(m for m in messages if m.startswith("vehicle 3 lost"))
    assert "in its own failsafe" in lost_message, messages
    if obl_act == 5:
        assert "it said 'Failsafe activated: entering Hold for 5 seconds'" in lost_message
    assert not any(m.startswith("vehicle 3 left OFFBOARD") for m in messages), messages   # never re-engaged
    assert ("AUTO.LOITER", True) in [m[1:] for m in modes], modes                          # PX4's hold first
    after_hold = [m[1:] for m in modes[[m[1] for m in modes].index("AUTO.LOITER"):]]
    assert ("OFFBOARD", True) not in after_hold, modes
    assert after_hold[-1] == ("AUTO.LAND", False), modes                                  # landed by itself
    assert any(m.startswith("re-forming for 4 vehicles") for m in messages)
    assert result.outcome == "converged", (result.message, messages[-10:])


def test_the_streamer_measures_its_own_pauses():
    from mission.vehicle.streamer import SetpointStreamer

    clock = FakeClock(100.0)
    sent = []
    v = SimpleNamespace(sysid=1, send_position_enu=lambda p, yaw=None: sent.append(p))
    streamer = SetpointStreamer([v], rate_hz=10.0, clock=clock)
    streamer.set_target(1, np.zeros(3))
    for dt_s in [0.1] * 10 + [1.3] + [0.1] * 10:      # a 1.3 s pause in the middle
        clock.t += dt_s
        streamer.tick()
    now = clock.time()
    assert streamer.longest_gap_s(1, now - 0.5) == pytest.approx(0.1)    # steady since then
    assert streamer.longest_gap_s(1, now - 1.5) == pytest.approx(1.3)    # the pause is in the window
    assert streamer.longest_gap_s(1, 90.0) == float("inf")                # before the stream began
    assert streamer.longest_gap_s(2, now) is None                         # not streamed
    clock.t += 0.8
    assert streamer.longest_gap_s(1, now - 0.5) == pytest.approx(0.8)    # the pause going on now


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_mock_px4_geofence_hold_and_offboard_loss_told_apart_by_px4s_words(tmp_path):
    """Six mock PX4 vehicles with ``COM_OBL_RC_ACT`` 5 and ``GF_ACTION`` 2: both the offboard loss and
    the geofence failsafe are Hold itself (AUTO.LOITER, CRITICAL, "Failsafe activated", no hold before
    an action). After seek iteration 3 the fence ceiling of vehicle 3 is lowered under it, and
    vehicle 1's uplink is cut until it leaves OFFBOARD (its offboard loss), then restored. PX4's
    geofence check says "Geofence: exceeding maximum altitude above Home" (real PX4 v1.16 SIH,
    tests/conformance/test_conformance_px4_hold_failsafes.py): vehicle 3 is "left" in its own
    failsafe and never re-engaged; vehicle 1, which said only "Failsafe activated", is re-engaged.
    Before the geofence words were read, both were re-engaged (docs/faults.md)."""
    from mission.sim.embedded import default_eps, embedded_plan, fleet_ports
    from mission.telemetry.mission_log import read_mission_log
    from sitl_mock.fields_gaussian import sigma2
    from tests.mission.flight.test_resilience import _fleet

    n = 6
    ports = fleet_ports(n, "px4")
    source = np.array([6.0, -4.0, 13.0])
    fleet = _fleet(n, ports, source)
    for s in range(1, n + 1):
        fleet.vehicle(s).params.set("GF_ACTION", 2)
        fleet.vehicle(s).params.set("COM_OBL_RC_ACT", 5)
    plan = embedded_plan(n, ports, start_enu_m=(0.0, 0.0, 11.0), eps=default_eps(sigma2(source)), max_iterations=80)
    log_path = tmp_path / "m.jsonl"
    modes: dict[int, list] = {1: [], 3: []}
    done = threading.Event()

    def note_modes():
        for s, seen in modes.items():
            v = fleet.vehicle(s)
            if not seen or seen[-1] != (v.mode_name, v.armed):
                seen.append((v.mode_name, v.armed))

    def faults():
        deadline = fleet.clock.time() + 900.0
        while not done.is_set() and fleet.clock.time() < deadline:
            if log_path.exists() and log_path.read_text().count('"type":"iteration"') >= 3:
                fleet.vehicle(3).params.set("GF_MAX_VER_DIST", 5.0)   # it flies 9-13 m above home
                fleet.set_fault(1, "loss_uplink", 1.0)
                break
            fleet.clock.sleep_blocking(0.2)
        cut_until = None
        while not done.is_set() and fleet.clock.time() < deadline:
            note_modes()
            if cut_until is None and fleet.vehicle(1).mode_name != "OFFBOARD":
                cut_until = fleet.clock.time() + 1.0                   # its offboard loss: one more second
            if cut_until is not None and fleet.clock.time() >= cut_until:
                fleet.set_fault(1, "loss_uplink", 0.0)
            fleet.clock.sleep_blocking(0.1)

    result = _fly_beside(fleet, plan, log_path, faults, done)
    messages = [r["message"] for r in read_mission_log(log_path) if r["type"] == "event"]
    lost = {x["sysid"]: x for x in result.lost}
    assert 3 in lost and lost[3]["reason"] == "left", (result.lost, messages[-15:])
    lost_message = next(m for m in messages if m.startswith("vehicle 3 lost"))
    assert "it said 'Geofence: exceeding maximum altitude above Home'" in lost_message, lost_message
    assert not any(m.startswith("vehicle 3 left OFFBOARD") for m in messages), messages   # never re-engaged
    held = [m for m in modes[3] if m == ("AUTO.LOITER", True)]
    assert held and ("OFFBOARD", True) not in modes[3][modes[3].index(held[0]):], modes[3]
    assert ("AUTO.LOITER", True) in modes[1], modes[1]                                    # its offboard loss
    assert 1 not in lost and result.reengaged.get(1, 0) >= 1, (result.lost, result.reengaged, messages[-15:])
    assert any(m.startswith("vehicle 1 left OFFBOARD") for m in messages), messages
    assert result.outcome == "converged", (result.message, messages[-10:])
    print("\nvehicle 3:", lost_message, "| modes 3:", modes[3], "| modes 1:", modes[1], "| outcome", result.outcome,
          "| still armed", getattr(result, "still_armed", None), "| airborne_left", result.airborne_left)


def test_a_vehicle_back_from_a_link_loss_in_its_own_failsafe_is_not_readmitted():
    """``readmit = true``: vehicle 1, heard again after its link loss, holds in AUTO.LOITER. PX4's
    words, sent once it hears the ground station again, say its data-link loss holds before its
    Return: kept out (commanded nothing more than the keep-out), not re-admitted; vehicle 2, heard
    again in the same hold with only "Failsafe activated" (its offboard loss), is re-admitted."""
    clock, state, vehicles, gate, rec, motion, monitor = _monitor(5, readmit=True)
    state.set_phase("seek")
    vehicles[0].age_s = vehicles[1].age_s = 3.0
    _watch(monitor, lambda: {1, 2} <= set(state.lost), "vehicles 1 and 2 lost")
    for v, words in ((vehicles[0], ["Connection to ground station lost", "Failsafe activated: entering Hold for 5 seconds"]),
                     (vehicles[1], ["Failsafe activated"])):
        v.age_s = 0.0
        v.state.mode, v.state.system_status, v.status_since_s = "AUTO.LOITER", _CRITICAL, clock.time()
        v.state.last_heartbeat_s = clock.time()
        v.statustexts = [(clock.time(), 2, w) for w in words]
    _watch(monitor, lambda: all(state.lost[s].came_back_s is not None for s in (1, 2)), "both heard again")
    assert not state.lost[1].readmit_pending and state.lost[2].readmit_pending
    assert [c[:2] for c in motion.calls] == [("keep_out", 1)]
    assert "in its own failsafe: it said 'Failsafe activated: entering Hold for 5 seconds'" in motion.calls[0][2]
