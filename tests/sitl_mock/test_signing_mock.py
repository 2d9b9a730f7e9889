"""MAVLink 2 signing of the mock autopilot: signed flying, forged / unsigned / replayed frames
change nothing and are counted, SETUP_SIGNING provisioning, the fleet and the CLI flag.

In-process tests drive one MockAutopilot by hand (no sockets, simulated time); one test flies a
MockFleet over UDP with a pymavlink client that has the key.
"""
from __future__ import annotations

import os
import socket
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav

from mission import cli
from mission.link.signing import (
    SignatureVerifier,
    apply_signing,
    disable_signing_message,
    setup_signing_message,
)
from mission.core.signing_config import SigningConfig
from sitl_mock.autopilot import MockAutopilot
from sitl_mock.dynamics_params import DynamicsParams
from sitl_mock.dynamics import Multicopter
from sitl_mock.fleet import MockFleet
from sitl_mock.transport import make_parser
from wire.signing import signing_timestamp
from tests.support.wait_helpers import wait_until

KEY = bytes(range(1, 33))
OTHER_KEY = bytes(range(101, 133))
ORIGIN = (45.19, 5.72, 230.0)
T0_S = 1_763_700_000.0
DT_S = 0.02
ARM = mav.MAV_CMD_COMPONENT_ARM_DISARM
REJECTIONS = ("rx_unsigned", "rx_bad_signature", "rx_replayed")


class Bench:
    """One mock autopilot stepped by hand, a ground-station encoder and a checked downlink."""

    def __init__(self, personality="ardupilot", vehicle_key=KEY, gcs_key=KEY):
        self.mc = Multicopter(DynamicsParams(), np.random.default_rng(2))
        self.ap = MockAutopilot(1, personality, self.mc, ORIGIN, T0_S, signing_key=vehicle_key)
        self.gcs = self.encoder(gcs_key)
        cfg = SigningConfig(KEY)
        self.verifier = SignatureVerifier(cfg, cfg.new_state(T0_S))
        self.uplink = make_parser()
        self.downlink = make_parser()
        self.t_s = T0_S
        self.received = []
        self.raw_downlink = []

    @staticmethod
    def encoder(key, sysid=255):
        enc = mav.MAVLink(None, srcSystem=sysid, srcComponent=190)
        if key is not None:
            apply_signing(enc, SigningConfig(key).new_state(T0_S))
        return enc

    def run(self, seconds):
        for _ in range(int(round(seconds / DT_S))):
            self.ap.step(self.t_s, DT_S)
            self.mc.step(DT_S)
            self.ap.send_telemetry(self.t_s)
            self.t_s += DT_S
            self._collect()

    def _collect(self):
        for frame in self.ap.drain_outbox():
            self.raw_downlink.append(frame)
            self.received += self.downlink.parse_buffer(frame) or []

    def inject(self, frame: bytes) -> list:
        """Hand raw bytes to the autopilot; returns the messages it sent back."""
        start = len(self.received)
        for msg in self.uplink.parse_buffer(frame) or []:
            self.ap.handle_message(msg, self.t_s)
        self._collect()
        return self.received[start:]

    def command_frame(self, enc, command, *params):
        p = list(params) + [0.0] * (7 - len(params))
        return enc.command_long_encode(1, 1, command, 0, *p).pack(enc)

    def mode_frame(self, enc, name):
        return self.command_frame(enc, mav.MAV_CMD_DO_SET_MODE, 1,
                                  self.ap.personality.custom_mode(name))

    @staticmethod
    def acks(replies):
        return [(m.command, m.result) for m in replies if m.get_type() == "COMMAND_ACK"]

    def rejections(self):
        return {k: self.ap.counters[k] for k in REJECTIONS if self.ap.counters[k]}


@pytest.mark.parametrize("personality", ["ardupilot", "px4"])
def test_signed_ground_station_flies_a_signed_mock(personality):
    b = Bench(personality)
    b.run(2.5)
    if personality == "ardupilot":
        assert b.acks(b.inject(b.mode_frame(b.gcs, "GUIDED"))) == [(mav.MAV_CMD_DO_SET_MODE, 0)]
        assert b.ap.mode_name == "GUIDED"
    assert b.acks(b.inject(b.command_frame(b.gcs, ARM, 1))) == [(ARM, mav.MAV_RESULT_ACCEPTED)]
    assert b.ap.armed
    b.run(0.5)
    assert b.rejections() == {}
    # everything the vehicle sent is signed with the key, timestamps increasing
    assert all(frame[2] & mav.MAVLINK_IFLAG_SIGNED for frame in b.raw_downlink)
    assert [b.verifier.check_frame(f) for f in b.raw_downlink] == [None] * len(b.raw_downlink)
    stamps = [int.from_bytes(f[-12:-6], "little") for f in b.raw_downlink]
    assert stamps == sorted(set(stamps))
    assert stamps[-1] >= signing_timestamp(b.t_s - 0.5)             # follows the vehicle's clock


@pytest.mark.parametrize("attack", ["unsigned", "wrong_key", "replayed"])
@pytest.mark.parametrize("what", ["arm", "mode"])
def test_forged_unsigned_and_replayed_commands_change_nothing(attack, what):
    b = Bench("ardupilot")
    b.run(2.5)
    first = b.mode_frame(b.gcs, "GUIDED") if what == "arm" else b.mode_frame(b.gcs, "LOITER")
    assert b.acks(b.inject(first))[0][1] == mav.MAV_RESULT_ACCEPTED
    if what == "arm":
        captured = b.command_frame(b.gcs, ARM, 1)
        assert b.acks(b.inject(captured)) == [(ARM, mav.MAV_RESULT_ACCEPTED)]
        assert b.acks(b.inject(b.command_frame(b.gcs, ARM, 0))) == [(ARM, mav.MAV_RESULT_ACCEPTED)]
        forge = lambda enc: b.command_frame(enc, ARM, 1)            # noqa: E731
    else:
        captured = b.mode_frame(b.gcs, "GUIDED")
        assert b.acks(b.inject(captured))[0][1] == mav.MAV_RESULT_ACCEPTED
        assert b.acks(b.inject(b.mode_frame(b.gcs, "LOITER")))[0][1] == mav.MAV_RESULT_ACCEPTED
        forge = lambda enc: b.mode_frame(enc, "GUIDED")             # noqa: E731
    before = (b.ap.armed, b.ap.mode_name, b.ap.counters["rx_frames"])
    frame = {"unsigned": lambda: forge(Bench.encoder(None)),
             "wrong_key": lambda: forge(Bench.encoder(OTHER_KEY)),
             "replayed": lambda: captured}[attack]()
    for _ in range(3):
        assert b.inject(frame) == []                                # no ACK, no reply at all
    b.run(0.5)
    assert (b.ap.armed, b.ap.mode_name, b.ap.counters["rx_frames"]) == before
    reason = {"unsigned": "rx_unsigned", "wrong_key": "rx_bad_signature", "replayed": "rx_replayed"}[attack]
    assert b.rejections() == {reason: 3}
    # the genuine ground station still commands the vehicle
    assert b.acks(b.inject(forge(b.gcs)))[0][1] == mav.MAV_RESULT_ACCEPTED


def test_forged_far_future_frame_does_not_lock_out_the_ground_station():
    b = Bench("ardupilot")
    b.run(2.5)
    forger = Bench.encoder(OTHER_KEY)
    forger.signing.timestamp += 10**12                              # far in the future
    assert b.inject(b.mode_frame(forger, "LAND")) == []
    assert b.acks(b.inject(b.mode_frame(b.gcs, "GUIDED")))[0][1] == mav.MAV_RESULT_ACCEPTED
    assert b.rejections() == {"rx_bad_signature": 1}


def test_unsigned_radio_status_accepted_unsigned_heartbeat_not():
    b = Bench("ardupilot")
    b.run(1.0)
    radio = Bench.encoder(None, sysid=51)
    b.inject(radio.radio_status_encode(200, 190, 90, 5, 3, 0, 0).pack(radio))
    assert b.ap.counters["rx_unsigned_accepted"] == 1
    hb = Bench.encoder(None)
    b.inject(hb.heartbeat_encode(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 4, 3).pack(hb))
    assert b.ap.last_gcs_heartbeat_s is None                        # a forged GCS heartbeat is ignored
    b.inject(b.gcs.heartbeat_encode(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 4, 3).pack(b.gcs))
    assert b.ap.last_gcs_heartbeat_s == pytest.approx(b.t_s)
    assert b.rejections() == {"rx_unsigned": 1}


@pytest.mark.parametrize("setup_signed", [False, True])
def test_setup_signing_from_the_ground_station_turns_signing_on(setup_signed):
    b = Bench("px4", vehicle_key=None)
    b.run(2.5)
    assert not b.ap.signing.enabled
    assert not any(f[2] & mav.MAVLINK_IFLAG_SIGNED for f in b.raw_downlink)
    enc = b.gcs if setup_signed else Bench.encoder(None)
    state = SigningConfig(KEY).new_state(b.t_s)
    b.inject(setup_signing_message(1, KEY, state.timestamp).pack(enc))
    assert b.ap.signing.enabled and b.ap.counters["signing_setup_accepted"] == 1
    assert b.ap.signing.timestamp >= state.timestamp
    b.raw_downlink.clear()
    b.run(1.0)
    assert b.raw_downlink
    assert [b.verifier.check_frame(f) for f in b.raw_downlink] == [None] * len(b.raw_downlink)
    assert b.inject(b.command_frame(Bench.encoder(None), ARM, 1)) == []
    assert not b.ap.armed and b.rejections() == {"rx_unsigned": 1}
    assert b.acks(b.inject(b.command_frame(b.gcs, ARM, 1))) == [(ARM, mav.MAV_RESULT_ACCEPTED)]


def test_setup_signing_refused_while_armed():
    b = Bench("ardupilot", vehicle_key=None, gcs_key=None)
    b.run(2.5)
    b.inject(b.mode_frame(b.gcs, "GUIDED"))
    assert b.acks(b.inject(b.command_frame(b.gcs, ARM, 1))) == [(ARM, mav.MAV_RESULT_ACCEPTED)]
    replies = b.inject(setup_signing_message(1, KEY, signing_timestamp(b.t_s)).pack(b.gcs))
    texts = [m.text for m in replies if m.get_type() == "STATUSTEXT"]
    assert texts == ["ERROR: Won't setup signing when armed"]
    assert not b.ap.signing.enabled and b.ap.counters["signing_setup_refused_armed"] == 1


def test_new_key_needs_the_current_key_and_zero_key_turns_signing_off():
    b = Bench("ardupilot")
    b.run(1.0)
    stamp = signing_timestamp(b.t_s)
    assert b.inject(setup_signing_message(1, OTHER_KEY, stamp).pack(Bench.encoder(None))) == []
    assert b.inject(setup_signing_message(1, OTHER_KEY, stamp).pack(Bench.encoder(OTHER_KEY))) == []
    assert b.rejections() == {"rx_unsigned": 1, "rx_bad_signature": 1}
    assert b.ap.counters["signing_setup_accepted"] == 0
    b.inject(disable_signing_message(1).pack(b.gcs))
    assert not b.ap.signing.enabled and b.ap.counters["signing_disabled"] == 1
    b.raw_downlink.clear()
    b.run(0.5)
    assert b.raw_downlink and not any(f[2] & mav.MAVLINK_IFLAG_SIGNED for f in b.raw_downlink)
    b.inject(b.mode_frame(Bench.encoder(None), "GUIDED"))
    assert b.ap.mode_name == "GUIDED"


def test_set_signing_key_checks_its_argument():
    b = Bench("px4", vehicle_key=None)
    with pytest.raises(ValueError, match="32 bytes"):
        b.ap.set_signing_key(b"short")
    b.ap.set_signing_key(KEY)
    assert b.ap.signing.enabled and b.ap.signing.timestamp == signing_timestamp(T0_S)
    b.ap.set_signing_key(None)
    assert not b.ap.signing.enabled


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.binary(min_size=1, max_size=80), max_size=4), st.integers(0, 255))
def test_signed_receive_path_never_raises_and_counts_everything(chunks, flip):
    b = Bench("ardupilot")
    good = bytearray(b.command_frame(b.gcs, ARM, 1))
    good[flip % len(good)] ^= 0xFF                                  # one corrupted byte
    before = b.ap.counters.copy()
    b.inject(b"".join(chunks) + bytes(good))
    assert not b.ap.armed and b.ap.counters["rx_frames"] == before["rx_frames"]
    if b.uplink.buf_len() == 0:                                     # no frame left pending
        assert sum(b.ap.counters.values()) > sum(before.values())


# ------------------------------------------------------------------ over sockets
def _free_udp_ports(count: int) -> list[int]:
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(count)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def _ack(conn, command, timeout_s=10.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        m = conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.5)
        if m is not None and m.command == command:
            return m.result
    return None


def test_pymavlink_client_with_the_key_flies_a_signed_fleet_over_udp():
    gcs_port, bind_port = _free_udp_ports(2)
    fleet = MockFleet(1, personality="ardupilot", speedup=5.0, udp_base_port=gcs_port,
                      udp_bind_base_port=bind_port, tcp_base_port=0, signing_key=KEY)
    with fleet:
        v = fleet.vehicles[0]
        conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs_port}", source_system=255,
                                          source_component=190)
        try:
            # mavutil replaces conn.mav (losing its signing setup) when it switches to
            # MAVLink 2 on the first frame: set the key up after the first heartbeat
            assert conn.wait_heartbeat(timeout=10) is not None
            conn.setup_signing(KEY, sign_outgoing=True, link_id=1)
            assert conn.wait_heartbeat(timeout=10).get_signed()
            assert conn.mav.signing.goodsig_count > 0 and conn.mav.signing.badsig_count == 0
            wait_until(lambda: v.autopilot.position_ready(fleet.clock.time()), what="position estimate")
            conn.mav.command_long_send(1, 1, mav.MAV_CMD_DO_SET_MODE, 0, 1, 4, 0, 0, 0, 0, 0)
            assert _ack(conn, mav.MAV_CMD_DO_SET_MODE) == mav.MAV_RESULT_ACCEPTED
            arm = conn.mav.command_long_encode(1, 1, ARM, 0, 1, 0, 0, 0, 0, 0, 0).pack(conn.mav)
            conn.write(arm)
            assert _ack(conn, ARM) == mav.MAV_RESULT_ACCEPTED
            conn.mav.command_long_send(1, 1, ARM, 0, 0, 0, 0, 0, 0, 0, 0)
            assert _ack(conn, ARM) == mav.MAV_RESULT_ACCEPTED and not v.armed
            intruder = mav.MAVLink(None, srcSystem=255, srcComponent=190)
            apply_signing(intruder, SigningConfig(OTHER_KEY).new_state(fleet.clock.time()))
            conn.write(arm)                                          # replayed bytes
            conn.write(intruder.command_long_encode(1, 1, ARM, 0, 1, 0, 0, 0, 0, 0, 0).pack(intruder))
            conn.write(mav.MAVLink(None, 255, 190).command_long_encode(
                1, 1, ARM, 0, 1, 0, 0, 0, 0, 0, 0).pack(mav.MAVLink(None, 255, 190)))
            wait_until(lambda: sum(v.counters.get(k, 0) for k in REJECTIONS) == 3, what="3 rejections")
            assert {k: v.counters.get(k, 0) for k in REJECTIONS} == dict.fromkeys(REJECTIONS, 1)
            assert _ack(conn, ARM, timeout_s=1.0) is None and not v.armed
        finally:
            conn.close()
    assert fleet.errors == []


def test_cli_signing_key_file(tmp_path, capsys):
    key_file = tmp_path / "fleet.key"
    key_file.write_text(KEY.hex() + "\n")
    os.chmod(key_file, 0o644)
    argv = ["mock", "--vehicles", "1", "--udp-base-port", "0", "--tcp-base-port", "0",
            "--duration", "0.2", "--signing-key-file", str(key_file)]
    assert cli.main(argv) == 2
    assert "world-readable" in capsys.readouterr().err
    os.chmod(key_file, 0o600)
    assert cli.main(argv) == 0
    assert "signing on" in capsys.readouterr().out
