"""MockFleet over real sockets: pymavlink over UDP and TCP, link faults, crash, ports, the CLI."""
from __future__ import annotations

import socket
import subprocess
import sys
import time

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav

from mission.sim.embedded import free_port_block
from sitl_mock.fleet import MockFleet
from sitl_mock.transport import PortInUseError
from tests.support.wait_helpers import wait_until

SPEEDUP = 5.0


def _free_base(count: int, step: int = 1, kind=socket.SOCK_DGRAM) -> int:
    """A port base such that base + step*i (i < count) are all free right now."""
    return free_port_block(count, step, ("udp",) if kind == socket.SOCK_DGRAM else ("tcp",))


def _fleet(n=2, personality="ardupilot", **kw):
    return MockFleet(n, personality=personality, speedup=SPEEDUP,
                     udp_base_port=_free_base(n), udp_bind_base_port=_free_base(n),
                     tcp_base_port=_free_base(n, 10, socket.SOCK_STREAM), **kw)


def _ack(conn, command, timeout_s=10.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        m = conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.5)
        if m is not None and m.command == command:
            return m.result
    raise AssertionError(f"no COMMAND_ACK for {command}")


def _connect(url, sysid=255):
    conn = mavutil.mavlink_connection(url, source_system=sysid, source_component=190)
    assert conn.wait_heartbeat(timeout=10) is not None
    return conn


@pytest.mark.parametrize("personality", ["ardupilot", "px4"])
def test_pymavlink_flies_each_personality_over_udp(personality):
    fleet = _fleet(2, personality)
    with fleet:
        v = fleet.vehicles[1]
        conn = _connect(f"udpin:127.0.0.1:{v.udp_send_port}")
        try:
            assert conn.target_system == 2
            wait_until(lambda: v.autopilot.position_ready(fleet.clock.time()), what="position estimate")
            if personality == "ardupilot":
                conn.mav.command_long_send(2, 1, mav.MAV_CMD_DO_SET_MODE, 0, 1, 4, 0, 0, 0, 0, 0)
                assert _ack(conn, mav.MAV_CMD_DO_SET_MODE) == mav.MAV_RESULT_ACCEPTED
            conn.mav.command_long_send(2, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
            assert _ack(conn, mav.MAV_CMD_COMPONENT_ARM_DISARM) == mav.MAV_RESULT_ACCEPTED
            alt = v.home_geodetic[2] + 8.0 if personality == "px4" else 8.0
            conn.mav.command_long_send(2, 1, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, alt)
            assert _ack(conn, mav.MAV_CMD_NAV_TAKEOFF) == mav.MAV_RESULT_ACCEPTED
            wait_until(lambda: v.true_position_ned()[2] < -7.5, what="takeoff")
            if personality == "px4":
                conn.mav.set_position_target_local_ned_send(0, 2, 1, 1, 0b110111111000, 10, 5, -8,
                                                            0, 0, 0, 0, 0, 0, 0, 0)
                conn.mav.command_long_send(2, 1, mav.MAV_CMD_DO_SET_MODE, 0, 1, 6, 0, 0, 0, 0, 0)
                assert _ack(conn, mav.MAV_CMD_DO_SET_MODE) == mav.MAV_RESULT_ACCEPTED

            def converged():
                conn.mav.set_position_target_local_ned_send(0, 2, 1, 1, 0b110111111000, 10, 5, -8,
                                                            0, 0, 0, 0, 0, 0, 0, 0)
                m = conn.recv_match(type="LOCAL_POSITION_NED", blocking=True, timeout=0.5)
                return m is not None and abs(m.x - 10) < 0.3 and abs(m.y - 5) < 0.3
            wait_until(converged, 30.0, "LOCAL_POSITION_NED to converge")
            conn.mav.command_long_send(2, 1, mav.MAV_CMD_NAV_LAND, 0, 0, 0, 0, 0, 0, 0, 0)
            assert _ack(conn, mav.MAV_CMD_NAV_LAND) == mav.MAV_RESULT_ACCEPTED
            wait_until(lambda: not v.armed, 30.0, "landing and disarm")
            assert v.dynamics.landed
            assert fleet.vehicles[0].true_position_ned()[2] == 0.0  # the other vehicle stayed put
        finally:
            conn.close()
    assert fleet.errors == []


def test_several_tcp_clients_and_true_position_in_mission_frame():
    fleet = _fleet(2, "ardupilot", home_offsets_enu=[(0, 0, 0), (30.0, -10.0, 0.0)])
    with fleet:
        v = fleet.vehicles[1]
        a = _connect(f"tcp:127.0.0.1:{v.tcp_port}")
        b = _connect(f"tcp:127.0.0.1:{v.tcp_port}", sysid=254)
        try:
            for conn in (a, b):
                m = conn.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=10)
                assert m is not None and m.get_srcSystem() == 2
            assert v.links.tcp_clients == 2
            assert v.true_position_enu() == pytest.approx((30.0, -10.0, 0.0), abs=1e-6)
        finally:
            a.close()
            b.close()


@pytest.mark.parametrize("fault", ["link_cut", "crashed"])
def test_link_cut_and_crash_silence_the_vehicle(fault):
    fleet = _fleet(1, "px4")
    with fleet:
        v = fleet.vehicles[0]
        conn = _connect(f"udpin:127.0.0.1:{v.udp_send_port}")
        try:
            fleet.set_fault(1, fault, True)
            # every frame sent before the fault is in our socket once the physics has ticked past
            # now (a later loop of the fleet reads the fault before it sends), then drain them
            assert fleet.wait_for_sim_time(fleet.clock.time() + 0.05)
            while conn.recv_match(blocking=False) is not None:
                pass
            assert conn.recv_match(type="HEARTBEAT", blocking=True, timeout=1.0) is None
            if fault == "crashed":
                assert v.dynamics.crashed
            else:
                wait_until(lambda: v.counters.get("tx_dropped_link", 0) > 0, what="dropped frames counted")
                fleet.set_fault(1, fault, False)
                assert conn.recv_match(type="HEARTBEAT", blocking=True, timeout=5.0) is not None
        finally:
            conn.close()


def test_uplink_loss_drops_and_counts():
    fleet = _fleet(1, "px4")
    with fleet:
        v = fleet.vehicles[0]
        conn = _connect(f"udpin:127.0.0.1:{v.udp_send_port}")
        try:
            fleet.set_fault(1, "loss_uplink", 1.0)
            for _ in range(20):
                conn.mav.param_request_read_send(1, 1, b"MAV_SYS_ID", -1)
            wait_until(lambda: v.counters.get("rx_dropped_loss", 0) == 20, what="20 dropped frames")
        finally:
            conn.close()


def test_port_in_use_is_a_clear_error():
    tcp_base = _free_base(1, 10, socket.SOCK_STREAM)
    blocker = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    blocker.bind(("127.0.0.1", tcp_base))
    blocker.listen()
    try:
        fleet = MockFleet(1, udp_base_port=0, udp_bind_base_port=0, tcp_base_port=tcp_base)
        with pytest.raises(PortInUseError, match=f"TCP port 127.0.0.1:{tcp_base} .* already in use"):
            fleet.start()
        assert not fleet.running
    finally:
        blocker.close()


@pytest.mark.parametrize("kwargs,match", [
    ({"n": 0}, "n must be"),
    ({"n": 2, "personality": ["px4"]}, "1 personalities given for 2"),
    ({"n": 2, "personality": "inav"}, "unknown personality"),
    ({"n": 2, "home_offsets_enu": [(0, 0, 0)]}, "home_offsets_enu"),
    ({"n": 2, "sensor_rate_hz": 0}, "sensor_rate_hz"),
    ({"n": 2, "zenoh_listen": ["tcp/127.0.0.1:7447"]}, "no field"),
])
def test_bad_fleet_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        MockFleet(udp_base_port=0, tcp_base_port=0, **kwargs)


def test_set_fault_checks_names_and_sysids():
    fleet = MockFleet(2, udp_base_port=0, tcp_base_port=0)
    with pytest.raises(KeyError, match="no vehicle with sysid 7"):
        fleet.set_fault(7, "link_cut", True)
    with pytest.raises(ValueError, match="unknown fault"):
        fleet.set_fault(1, "warp_drive", True)
    fleet.set_fault(2, "loss_downlink", "0.25")
    assert fleet.vehicles[1].faults.loss_downlink == 0.25


@pytest.mark.parametrize("argv,code,text", [
    (["--vehicles", "0"], 2, "--vehicles must be 1..255"),
    (["--personality", "inav"], 2, "invalid choice"),
    (["--fault", "1:loss_uplink=2"], 2, "probability"),
    (["--origin", "95,0,0"], 2, "latitude"),
    (["--zenoh-listen", "garbage"], 2, "PROTO/ADDRESS"),
    (["--speedup", "-3"], 2, "positive"),
    (["--fault", "9:link_cut=1", "--vehicles", "2"], 2, "only 2 vehicles"),
])
def test_cli_rejects_bad_flags(argv, code, text):
    r = subprocess.run([sys.executable, "-m", "mission", "mock", *argv], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == code
    assert text in r.stderr


def test_cli_runs_prints_ports_and_reports_port_in_use():
    udp, bind = _free_base(2), _free_base(2)
    tcp = _free_base(2, 10, socket.SOCK_STREAM)
    args = [sys.executable, "-m", "mission", "mock", "--vehicles", "2", "--duration", "1",
            "--udp-base-port", str(udp), "--udp-bind-base-port", str(bind),
            "--tcp-base-port", str(tcp), "--fault", "2:loss_uplink=0.5"]
    r = subprocess.run(args, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("vehicle ")]
    assert len(lines) == 2
    assert f"127.0.0.1:{bind + 1} -> 127.0.0.1:{udp + 1}" in lines[1] and f"tcp 127.0.0.1:{tcp + 10}" in lines[1]
    blocker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    blocker.bind(("127.0.0.1", bind))
    try:
        r = subprocess.run(args, capture_output=True, text=True, timeout=60)
    finally:
        blocker.close()
    assert r.returncode == 1
    assert f"UDP port 127.0.0.1:{bind}" in r.stderr and "Traceback" not in r.stderr


def test_cli_stops_cleanly_on_ctrl_c():
    """SIGINT: the mock stops with status 0 and no traceback. Once in a fresh-clone suite it did not
    stop in 30 s (not reproduced in 65 tries, idle or beside three CPU hogs): if it hangs again,
    SIGABRT makes Python's fault handler print every thread's stack into the failure message."""
    import os
    import signal
    args = [sys.executable, "-m", "mission", "mock", "--vehicles", "1", "--tcp-base-port", "0",
            "--udp-base-port", str(_free_base(1)), "--udp-bind-base-port", str(_free_base(1))]
    p = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         env=dict(os.environ, PYTHONFAULTHANDLER="1"))
    try:
        assert p.stdout.readline().startswith("mock fleet")
        assert p.stdout.readline().startswith("vehicle sysid=1")
        p.send_signal(signal.SIGINT)
        try:
            _out, err = p.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            p.send_signal(signal.SIGABRT)
            _out, err = p.communicate(timeout=30)
            pytest.fail(f"swarmseek mock still ran 30 s after SIGINT; its threads:\n{err[-6000:]}")
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0, err
    assert "Traceback" not in err


def test_catching_up_sends_each_steps_frames_before_the_next_step():
    """A fleet behind its clock (a starved host) runs up to 25 steps in one go; the frames of
    each step leave before the next step runs, so a ground station never hears the whole fleet
    fall silent for the length of a catch-up (it declared every vehicle lost under load)."""
    from mission.sim.lockstep import VirtualClock

    base = free_port_block(4, kinds=("udp",))
    clock = VirtualClock(t0_s=0.0)
    fleet = MockFleet(2, personality="px4", clock=clock, udp_base_port=base, udp_bind_base_port=base + 2,
                      tcp_base_port=0)
    pending_before_tick = []
    tick = fleet._tick

    def recording_tick(t_s, dt, sample_dt):
        pending_before_tick.append(sum(len(v.autopilot._outbox) for v in fleet.vehicles))
        tick(t_s, dt, sample_dt)

    fleet._tick = recording_tick
    fleet.start(thread=False)
    try:
        clock.advance_to(0.5)
        steps = fleet.step_until(clock.time())
        produced = sum(len(v.autopilot._outbox) for v in fleet.vehicles)
    finally:
        fleet.stop()
    assert steps >= 20 and len(pending_before_tick) == steps
    assert pending_before_tick == [0] * steps      # nothing waited behind a later step
    assert produced == 0                           # and the last step's frames went too
