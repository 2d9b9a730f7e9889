"""The sensor's (companion's) own heartbeat is never taken for a ground station's by either
autopilot: ArduPilot counts heartbeats from system id ``MAV_GCS_SYSID`` (255), PX4 those of type
MAV_TYPE_GCS, as the ground station's. A sensor that sent 255 / GCS on the vehicle's second port
kept ArduCopter SITL's ``FS_GCS_ENABLE`` failsafe from ever firing when the ground station's link
was cut (tests/sitl/test_sitl_faults_ardupilot_link.py, docs/faults.md). The frame is the one
``companion.autopilot`` really sends (over UDP), judged by the mock autopilots' rule for each
personality (``sitl_mock.ap_receive``, the rule of the real firmware); a ground station's
heartbeat is judged a ground station's by the same rule."""
from __future__ import annotations

import socket
from types import SimpleNamespace

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.autopilot import COMPANION_SYSID, close_mavlink, open_mavlink, send_heartbeat
from sitl_mock.ap_receive import dispatch


def _sent_heartbeat():
    """The HEARTBEAT frame ``send_heartbeat`` puts on the wire, parsed."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx:
        rx.bind(("127.0.0.1", 0))
        rx.settimeout(10.0)
        conn = open_mavlink(f"udpout:127.0.0.1:{rx.getsockname()[1]}", retries=0)
        try:
            send_heartbeat(conn)
            data = rx.recv(1024)
        finally:
            close_mavlink(conn)
    msgs = mav.MAVLink(None).parse_buffer(data)
    assert len(msgs) == 1 and msgs[0].get_type() == "HEARTBEAT"
    return msgs[0]


def _gcs_time(personality: str, msg) -> float | None:
    ap = SimpleNamespace(personality=SimpleNamespace(name=personality), params={"MAV_GCS_SYSID": 255},
                         last_gcs_heartbeat_s=None, flush_statustexts=lambda t_s: None)
    dispatch(ap, msg, 5.0)
    return ap.last_gcs_heartbeat_s


@pytest.mark.parametrize("personality", ["ardupilot", "px4"])
def test_the_sensors_heartbeat_is_not_a_ground_stations(personality):
    hb = _sent_heartbeat()
    assert hb.get_srcSystem() == COMPANION_SYSID != 255
    assert hb.type == mav.MAV_TYPE_ONBOARD_CONTROLLER and hb.autopilot == mav.MAV_AUTOPILOT_INVALID
    assert _gcs_time(personality, hb) is None
    gcs = mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)
    gcs.pack(mav.MAVLink(None, srcSystem=255, srcComponent=190))
    assert _gcs_time(personality, gcs) == 5.0  # the rule does see a ground station's
