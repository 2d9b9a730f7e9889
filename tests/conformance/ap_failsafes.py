"""ArduCopter's own failsafes, the same scripted session against the mock and real SITL.

:func:`run_failsafes` (plain pymavlink through :class:`~conformance.client.Client`, timed on the
autopilot's clock) configures the fence (``FENCE_ENABLE`` 1, ``FENCE_TYPE`` 3: altitude and
circle, ``FENCE_ALT_MAX`` 100 m, ``FENCE_ACTION`` 1) and the battery failsafe (``BATT_LOW_VOLT``
10.5 V, ``BATT_FS_LOW_ACT`` 1: land), takes off in GUIDED to 14 m, then:

1. **fence**: ``FENCE_ALT_MAX`` 10 m: the mode the breach switches to, how long after the
   PARAM_SET echo, the mode once landed and disarmed; the fence is then turned off;
2. **battery**: a new takeoff to 8 m, then ``SIM_BATT_VOLTAGE`` 9.5 V (the SITL's simulated pack,
   the mock's pack override): the mode, how long after (``BATT_LOW_TIMER``, 10 s by default), the
   mode once landed and disarmed, and whether it arms again in GUIDED (ArduCopter: no, its
   battery failsafe stays latched until a reboot: ``PreArm: Battery failsafe``).

:func:`observe` runs it against one mock ArduPilot (TCP, as SERIAL0) or one real instance;
:func:`differences` lists what differs beyond the tolerances (reaction times compared in
autopilot seconds: within ``REACTION_TOL_S``).
"""
from __future__ import annotations

from tests.conformance.client import Client, ConformanceError, Observation
from tests.conformance.targets import on_mock, on_sitl

__all__ = ["REACTION_TOL_S", "differences", "observe", "run_failsafes"]

#: autopilot seconds two reaction times may differ by (heartbeats come at 1 Hz on both)
REACTION_TOL_S = 1.5
_GUIDED, _RTL, _LAND = 4, 6, 9
_REAL32, _INT8 = 9, 2
_SETUP = (("FENCE_ENABLE", 1, _INT8), ("FENCE_TYPE", 3, _INT8), ("FENCE_ALT_MAX", 100.0, _REAL32),
          ("FENCE_ACTION", 1, _INT8), ("BATT_LOW_VOLT", 10.5, _REAL32), ("BATT_FS_LOW_ACT", 1, _INT8))


#: the telemetry the session reads, Hz
_RATES_HZ = {"LOCAL_POSITION_NED": 5.0, "HOME_POSITION": 0.5, "EXTENDED_SYS_STATE": 1.0}


def _set(c: Client, name: str, value: float, ptype: int) -> None:
    answer = c.set_param(name, name, value, ptype, wall_s=6.0)
    if answer is None or abs(answer[1] - value) > 1e-3:
        raise ConformanceError(f"step {c.step}: {name} = {value} not taken (answer {answer})")


def _takeoff(c: Client, alt_m: float) -> None:
    """GUIDED, arm (retried while pre-arm checks refuse), NAV_TAKEOFF to ``alt_m``."""
    c.set_mode("guided", _GUIDED)
    c.wait_mode("guided", _GUIDED, 10.0)
    c.arm()
    c.command("takeoff", c.m.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt_m)
    c.wait_state(lambda: c.rel_alt_m() > alt_m - 1.0, 60.0, f"{alt_m - 1.0:g} m above home")


def _failsafe(c: Client, name: str, param: tuple) -> dict:
    """Set ``param``; wait for a failsafe mode (RTL or LAND) and for the vehicle landed and disarmed; the figures."""
    c.step = name
    _set(c, *param)
    start_s = c.boot_s
    c.wait(lambda m: m.custom_mode in (_RTL, _LAND), 60.0, "a failsafe mode", kind="HEARTBEAT")
    figures = {"mode": c.custom_mode, "reaction_s": round(c.boot_s - start_s, 2)}
    c.wait_state(lambda: not c.armed, 120.0, "landed and disarmed")
    c.settle(1.0)
    figures.update(mode_landed=c.custom_mode, rel_alt_m=round(c.rel_alt_m(), 1),
                   texts=[t for step, _, t in c.obs.statustexts if step == name])
    return figures


def run_failsafes(uri: str, sysid: int, wall_scale: float = 1.0) -> Observation:
    """The whole sequence against one ArduPilot; ``details["fence"]`` and ``details["battery"]``."""
    c = Client(uri, sysid, "ardupilot", wall_scale)
    try:
        c.connect(_RATES_HZ, 30.0, 60.0)
        c.step = "configure"
        for name, value, ptype in _SETUP:
            _set(c, name, value, ptype)
        c.step = "takeoff"
        _takeoff(c, 14.0)
        c.obs.details["fence"] = _failsafe(c, "fence", ("FENCE_ALT_MAX", 10.0, _REAL32))
        _set(c, "FENCE_ENABLE", 0, _INT8)
        c.step = "takeoff_again"
        _takeoff(c, 8.0)
        c.obs.details["battery"] = _failsafe(c, "battery", ("SIM_BATT_VOLTAGE", 9.5, _REAL32))
        c.step = "rearm"  # ArduCopter latches its battery failsafe: no new arming until a reboot
        c.set_mode("guided_again", _GUIDED)
        c.wait_mode("guided_again", _GUIDED, 10.0)
        rearm = c.command("rearm", c.m.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        c.obs.details["battery"]["rearm_accepted"] = rearm == c.m.MAV_RESULT_ACCEPTED
        if rearm == c.m.MAV_RESULT_ACCEPTED:
            c.command("disarm", c.m.MAV_CMD_COMPONENT_ARM_DISARM, 0)
        return c.obs
    finally:
        c.close()


def observe(target: str, *, mock_speedup: float = 4.0, sitl_speedup: float = 4.0) -> Observation:
    """Run :func:`run_failsafes` against ``"mock"`` (one ArduPilot mock) or ``"sitl"`` (real ArduCopter)."""
    if target == "mock":
        return on_mock("ardupilot", mock_speedup, run_failsafes)
    return on_sitl("ardupilot", sitl_speedup, run_failsafes)


def differences(mock: Observation, sitl: Observation) -> list[str]:
    """What the mock does differently from real ArduCopter in this sequence (empty: conforms)."""
    out = []
    for case in ("fence", "battery"):
        m, s = mock.details[case], sitl.details[case]
        for key in ("mode", "mode_landed", "rearm_accepted"):
            if m.get(key) != s.get(key):
                out.append(f"{case}: {key} mock {m[key]} vs SITL {s[key]}")
        if abs(m["reaction_s"] - s["reaction_s"]) > REACTION_TOL_S:
            out.append(f"{case}: reaction mock {m['reaction_s']} s vs SITL {s['reaction_s']} s (autopilot time)")
        if abs(m["rel_alt_m"]) > 1.0 or abs(s["rel_alt_m"]) > 1.0:
            out.append(f"{case}: not on the ground after disarming: mock {m['rel_alt_m']} m, SITL {s['rel_alt_m']} m")
    return out
