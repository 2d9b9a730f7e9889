"""PX4's failsafes whose action is Hold, with ``COM_OBL_RC_ACT`` 5 (Hold): what PX4 says.

With the offboard-loss action Hold, a geofence breach with ``GF_ACTION`` 2 (Hold), a data-link
loss with ``NAV_DLL_ACT`` 1 (Hold) and the offboard loss itself all end in AUTO.LOITER with the
heartbeat CRITICAL: only PX4's STATUSTEXTs tell them apart. :func:`run_hold_failsafes` (plain
pymavlink, :class:`~conformance.client.Client`) takes off, enters OFFBOARD and, one after the other,
each time from OFFBOARD with the setpoint stream steady unless said:

* ``geofence``: ``GF_MAX_VER_DIST`` set below the vehicle (then 0 again, and OFFBOARD re-entered);
* ``data_link``: ``COM_DL_LOSS_T`` :data:`DL_LOSS_T_S`, the session's GCS heartbeats stopped (the
  setpoints go on), then resumed;
* ``offboard_loss``: the setpoint stream stopped;

and records for each the first mode after OFFBOARD, its delay, and every STATUSTEXT from the
step's start until :data:`AFTER_S` autopilot seconds after that mode (``data_link``: until 2 s after
the heartbeats resumed, and ``texts_unheard``: how many came while they were stopped) in
``details[step]``. Then it lands.
:func:`observe` runs it against one mock PX4 or one real PX4 SIH instance.
"""
from __future__ import annotations

import struct

from tests.conformance.client import Client, ConformanceError, Observation
from tests.conformance.px4_failsafes import _offboard, _takeoff
from tests.conformance.script import FLAVOUR
from tests.conformance.targets import on_mock, on_sitl

__all__ = ["AFTER_S", "DL_LOSS_T_S", "HOLD_STEPS", "differences", "observe", "run_hold_failsafes", "said"]

_CUSTOM = FLAVOUR["px4"]["custom"]
_MODES = FLAVOUR["px4"]["modes"]
_INT32, _REAL32 = 6, 9
#: autopilot seconds of STATUSTEXTs recorded after the failsafe's mode was first heard
AFTER_S = 3.0
#: PX4's data-link-loss timeout in the ``data_link`` step (s)
DL_LOSS_T_S = 5
#: the steps, in order
HOLD_STEPS = ("geofence", "data_link", "offboard_loss")
_RATES_HZ = {"LOCAL_POSITION_NED": 10.0, "HOME_POSITION": 0.5, "EXTENDED_SYS_STATE": 2.0}


def _set(c: Client, name: str, value: float, ptype: int) -> None:
    """PARAM_SET of a PX4 parameter (an INT32 encoded bytewise, as PX4 does); raise unless echoed."""
    wire = struct.unpack("<f", struct.pack("<i", int(value)))[0] if ptype == _INT32 else float(value)
    answer = c.set_param(name, name, wire, ptype, wall_s=6.0)
    if answer is None or abs(answer[1] - value) > 1e-3:
        raise ConformanceError(f"step {c.step}: {name} = {value} not taken (answer {answer})")


def _until_failsafe(c: Client, target, stream: bool) -> dict:
    """Wait (streaming ``target`` if ``stream``) for a mode other than OFFBOARD; then record
    :data:`AFTER_S` autopilot seconds more. Returns the step's figures."""
    start_s = c.boot_s
    while c.custom_mode == _CUSTOM["offboard"]:
        if c.boot_s - start_s > 30.0:
            raise ConformanceError(f"step {c.step}: still in OFFBOARD 30 s on")
        if stream:
            c.send_local_target(*target)
        c.settle(0.1)
    mode_s, mode = c.boot_s, c.custom_mode
    while c.boot_s - mode_s < AFTER_S:
        if stream:
            c.send_local_target(*target)
        c.settle(0.1)
    return {"mode": mode, "reaction_s": round(mode_s - start_s, 2)}


def _texts(c: Client, step: str) -> list[str]:
    return [t for s, _, t in c.obs.statustexts if s == step]


def _geofence(c: Client, target) -> None:
    c.step = "geofence"
    _set(c, "GF_ACTION", 2, _INT32)
    _set(c, "GF_MAX_VER_DIST", round(max(2.0, c.rel_alt_m() - 4.0), 1), _REAL32)
    c.obs.details["geofence"] = _until_failsafe(c, target, stream=True)
    _set(c, "GF_MAX_VER_DIST", 0.0, _REAL32)
    c.settle(1.0)


def _data_link(c: Client, target) -> None:
    c.step = "data_link"
    _set(c, "NAV_DLL_ACT", 1, _INT32)
    _set(c, "COM_DL_LOSS_T", DL_LOSS_T_S, _INT32)
    c.heartbeats = False
    try:
        c.obs.details["data_link"] = _until_failsafe(c, target, stream=True)
    finally:
        c.heartbeats = True
    c.obs.details["data_link"]["texts_unheard"] = len(_texts(c, "data_link"))  # said while it heard no GCS
    for _ in range(20):  # 2 s more with our heartbeats, the setpoints going on
        c.send_local_target(*target)
        c.settle(0.1)
    _set(c, "NAV_DLL_ACT", 0, _INT32)


def run_hold_failsafes(uri: str, sysid: int, wall_scale: float = 1.0) -> Observation:
    """The whole sequence against one PX4; ``details[step]`` for each of :data:`HOLD_STEPS`."""
    c = Client(uri, sysid, "px4", wall_scale)
    try:
        c.connect(_RATES_HZ, 60.0, 90.0)
        _set(c, "COM_OBL_RC_ACT", 5, _INT32)
        _takeoff(c)
        _geofence(c, _offboard(c))
        _data_link(c, _offboard(c))
        target = _offboard(c)
        c.step = "offboard_loss"
        c.obs.details["offboard_loss"] = _until_failsafe(c, target, stream=False)
        c.step = "land"
        c.set_mode("land", *_MODES["land"])
        c.wait_state(lambda: not c.armed, 240.0, "landed and disarmed")
        for step in HOLD_STEPS:
            c.obs.details[step]["texts"] = _texts(c, step)
        return c.obs
    finally:
        c.close()


def observe(target: str, *, mock_speedup: float = 1.0) -> Observation:
    """Run :func:`run_hold_failsafes` against ``"mock"`` (one mock PX4, its clock ``mock_speedup``
    times real time) or ``"sitl"`` (one real PX4 SIH instance, real time)."""
    if target == "mock":
        return on_mock("px4", mock_speedup, run_hold_failsafes)
    return on_sitl("px4", 1.0, run_hold_failsafes)


def differences(mock: Observation, sitl: Observation) -> list[str]:
    """What the mock does or says differently from real PX4 SIH in these steps (empty: conforms);
    texts compared as :func:`said` lists them."""
    out = []
    for step in HOLD_STEPS:
        m, s = mock.details[step], sitl.details[step]
        for key in ("mode", "texts_unheard"):
            if m.get(key) != s.get(key):
                out.append(f"{step} {key}: mock {m.get(key)} vs SITL {s.get(key)}")
        if said(m["texts"]) != said(s["texts"]):
            out.append(f"{step} texts: mock {m['texts']} vs SITL {s['texts']}")
    return out


def said(texts: list[str]) -> list[str]:
    """The distinct texts in the order first said, each on its first 50 characters (one STATUSTEXT;
    the mock sends no chunks). PX4's health report may say a check's words again: real PX4 SIH said
    its geofence words once in one run, twice within 3 s in another."""
    out: list[str] = []
    for t in texts:
        if t[:50] not in out:
            out.append(t[:50])
    return out
