"""The mock's ArduPilot failsafes as real ArduCopter does them (measured by
tests/conformance/test_conformance_ap_failsafes.py on real SITL), without SITL: the scripted session of
tests/conformance/ap_failsafes.py against one mock ArduPilot. A fence breach (``FENCE_ALT_MAX``
below the vehicle, ``FENCE_TYPE`` 3) switches to RTL at once; ``SIM_BATT_VOLTAGE`` below
``BATT_LOW_VOLT`` switches to LAND after ``BATT_LOW_TIMER`` (10 s), and the battery failsafe stays
latched: no new arming.
"""
from __future__ import annotations

from tests.conformance.ap_failsafes import observe


def test_mock_ardupilot_fence_and_voltage_failsafes():
    obs = observe("mock", mock_speedup=8.0)
    fence, battery = obs.details["fence"], obs.details["battery"]
    assert (fence["mode"], fence["mode_landed"]) == (6, 6), fence  # RTL, stays RTL once landed
    assert fence["reaction_s"] < 2.0, fence
    assert (battery["mode"], battery["mode_landed"]) == (9, 9), battery  # LAND
    assert 9.5 <= battery["reaction_s"] <= 12.5, battery  # BATT_LOW_TIMER 10 s, heartbeats at 1 Hz
    assert battery["rearm_accepted"] is False
    assert "Failsafe: battery low" in battery["texts"] and "Failsafe: geofence breached" in fence["texts"]
