"""Receive path of a mock autopilot after its gate: dispatch, parameter protocol, GCS heartbeat.

:meth:`sitl_mock.autopilot.MockAutopilot.handle_message` rejects undecodable, badly signed and
misaddressed frames (:func:`classify_bad_frame` names the counter of an undecodable one) and
hands the rest to :func:`dispatch`, which routes each message type to its handler: commands
and modes (:mod:`sitl_mock.ap_commands`), setpoints (:mod:`sitl_mock.ap_setpoints`), the
parameter protocol (:func:`handle_param`), TIMESYNC, SETUP_SIGNING and the mission protocol.
Functions act on a :class:`~sitl_mock.autopilot.MockAutopilot` (``ap``).
"""
from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sitl_mock import ap_commands
from sitl_mock.ap_params import ParamError
from sitl_mock.ap_setpoints import handle_setpoint

__all__ = ["classify_bad_frame", "dispatch", "handle_param", "send_param"]

_MAV_TYPE_GCS = mavlink2.MAV_TYPE_GCS


def classify_bad_frame(reason: str) -> str:
    """Counter name for a frame pymavlink could not decode (from its error text)."""
    low = reason.lower()
    if "crc" in low:
        return "rx_bad_crc"
    if "unknown mavlink message id" in low:
        return "rx_unknown_msg"
    return "rx_malformed"


def dispatch(ap, msg, t_s: float) -> None:
    """Hand an accepted message addressed to this vehicle to its handler (may raise)."""
    kind = msg.get_type()
    if kind == "HEARTBEAT":
        _on_heartbeat(ap, msg, t_s)
    elif kind in ("COMMAND_LONG", "COMMAND_INT"):
        ap_commands.handle_command(ap, msg, t_s)
    elif kind == "SET_MODE":
        ap_commands.handle_set_mode(ap, msg, t_s)
    elif kind in ("SET_POSITION_TARGET_LOCAL_NED", "SET_POSITION_TARGET_GLOBAL_INT"):
        handle_setpoint(ap, msg, t_s)
    elif kind.startswith("PARAM_"):
        handle_param(ap, msg, kind)
    elif kind == "TIMESYNC":
        if msg.tc1 == 0:
            ap.emit(ap.mav.timesync_encode(int(t_s * 1e9), msg.ts1))
    elif kind == "REQUEST_DATA_STREAM":
        ap_commands.handle_request_data_stream(ap, msg, t_s)
    elif kind == "SETUP_SIGNING":
        if ap.signing.handle_setup(msg, ap.armed) == "signing_setup_refused_armed":
            ap.statustext("ERROR: Won't setup signing when armed", mavlink2.MAV_SEVERITY_WARNING)
    elif not ap.missions.handle(msg, t_s):
        ap.counters["rx_unhandled"] += 1


def _on_heartbeat(ap, msg, t_s: float) -> None:
    """Note the time of the GCS's heartbeat (ArduPilot: MAV_GCS_SYSID; PX4: a GCS type)."""
    if ap.personality.name == "ardupilot":
        is_gcs = msg.get_srcSystem() == ap.params["MAV_GCS_SYSID"]
    else:
        is_gcs = msg.type == _MAV_TYPE_GCS
    if is_gcs:
        ap.last_gcs_heartbeat_s = t_s
        ap.flush_statustexts(t_s)


def handle_param(ap, msg, kind: str) -> None:
    """PARAM_REQUEST_LIST / PARAM_REQUEST_READ / PARAM_SET: answer with PARAM_VALUE."""
    params = ap.params
    if kind == "PARAM_REQUEST_LIST":
        for name in params.names():
            send_param(ap, name)
    elif kind == "PARAM_REQUEST_READ":
        if msg.param_index >= 0:
            if msg.param_index >= len(params):
                ap.counters["param_unknown"] += 1
                return
            name = params.name_at(msg.param_index)
        else:
            name = msg.param_id
        if name not in params:
            ap.counters["param_unknown"] += 1
            return
        send_param(ap, name)
    elif kind == "PARAM_SET":
        name = msg.param_id
        if name not in params:
            ap.counters["param_unknown"] += 1
            return
        try:
            params.set(name, params.decode_wire(name, msg.param_value))
        except ParamError:
            ap.counters["param_rejected"] += 1
        else:
            ap.apply_params()
        send_param(ap, name)  # the current value tells the GCS whether it took
    else:
        ap.counters["rx_unhandled"] += 1


def send_param(ap, name: str) -> None:
    """Send PARAM_VALUE for parameter ``name``."""
    p = ap.params
    ap.emit(ap.mav.param_value_encode(name.encode(), p.encode_wire(name), p.ptype(name),
                                      len(p), p.index_of(name)))
