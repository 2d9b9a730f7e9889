"""The conformance comparison itself, without real SITL: the script runs through against the mock,
an observation agrees with itself, and each kind of disagreement is reported under its key (so the
real-SITL conformance tests can fail)."""
from __future__ import annotations

import copy

import pytest
from tests.conformance.check import DOC_PATH
from tests.conformance.compare import compare
from tests.conformance.known import KNOWN_DIFFERENCES, documented_keys
from tests.conformance.targets import observe_mock


@pytest.fixture(scope="module")
def px4_mock_observation():
    return observe_mock("px4", speedup=6.0)


def test_known_differences_are_documented():
    for flavour, known in KNOWN_DIFFERENCES.items():
        assert set(known) == documented_keys(DOC_PATH, flavour), flavour


@pytest.mark.slow
def test_observation_agrees_with_itself(px4_mock_observation):
    obs = px4_mock_observation
    assert compare(obs, copy.deepcopy(obs)) == []
    assert obs.acks["cmd_user_1"] == 3 and obs.acks["arm_in_rtl"] == 1   # UNSUPPORTED, TEMPORARILY_REJECTED
    assert obs.details["mission_download"]["waypoints_match"] and obs.details["target"]["reached"]


@pytest.mark.slow
def test_each_kind_of_difference_is_reported(px4_mock_observation):
    mock = px4_mock_observation
    sitl = copy.deepcopy(mock)
    sitl.acks["mode_invalid"] = 4                                   # another ACK result
    sitl.modes["land"] = 123                                        # another custom_mode
    sitl.message_counts["VFR_HUD"] = 5                              # a watched message only the SITL sends
    sitl.rates_hz["LOCAL_POSITION_NED"] = mock.rates_hz["LOCAL_POSITION_NED"] * 2.5
    sitl.details["param_types"]["MPC_XY_VEL_MAX"] = None            # a mock parameter the SITL lacks
    sitl.statustexts = [(s, sev, "no refusal") if s == "arm_in_rtl" else (s, sev, t)
                        for s, sev, t in sitl.statustexts]
    ev = sitl.events_s
    ev["disarmed_after_land"] = ev["land_commanded"] + 4 * (ev["disarmed_after_land"] - ev["land_commanded"]) + 5
    keys = sorted(d.key for d in compare(mock, sitl))
    assert keys == sorted(["ack:mode_invalid", "mode:land", "message:VFR_HUD", "rate:LOCAL_POSITION_NED",
                           "param_type:MPC_XY_VEL_MAX", "text:arm_in_rtl", "duration:land_to_disarmed"])
    del ev["landed"]                                                # no landing seen
    assert "events:landed_states" in {d.key for d in compare(mock, sitl)}
    ev["armed"] = ev["disarmed_after_land"] + 1.0                   # state changes out of order
    assert "events:order" in {d.key for d in compare(mock, sitl)}
