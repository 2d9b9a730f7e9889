"""Mock conformance of PX4's offboard-loss failsafe with its default action (``COM_OBL_RC_ACT`` 0,
position mode) and no RC: the same scripted session (tests/conformance/px4_failsafes.py) against
the mock's "px4" personality and one real PX4 SIH instance: the same failsafe mode (POSCTL), the
same modes while armed, the descent speed within ``DESCENT_TOL_M_S`` (MPC_LAND_SPEED), the same
landed states (IN_AIR until ON_GROUND), the same mode once disarmed (OFFBOARD again), the reaction
within ``REACTION_TOL_S`` autopilot seconds, both on the ground.

The mock side alone runs without a SITL (``test_mock_offboard_loss_descends_as_real_px4``, the
figures measured on real PX4 SIH written in); the comparison needs ``SWARMSEEK_PX4_SITL`` (skipped
without it; a failure under CI=true). Run alone:
``SWARMSEEK_PX4_SITL=../shared/sitl/px4-sih python -m pytest -n 0 -s tests/conformance/test_conformance_px4_failsafes.py``.
"""
from __future__ import annotations

import pytest
from tests.conformance.px4_failsafes import DESCENT_TOL_M_S, differences, observe
from tests.conformance.script import FLAVOUR
from tests.support.sitl_support import require_sitl

_POSCTL = 3 << 16
_OFFBOARD = FLAVOUR["px4"]["custom"]["offboard"]
_IN_AIR, _ON_GROUND = 2, 1
#: real PX4 v1.16 SIH's descent without a pilot (m/s, autopilot time): MPC_LAND_SPEED 0.7
_PX4_DESCENT_M_S = 0.7


def _check_px4_behaviour(figures: dict) -> None:
    assert figures["mode"] == _POSCTL, figures
    assert figures["armed_modes"] == [_POSCTL], figures
    assert figures["landed_states"] == [_IN_AIR, _ON_GROUND], figures
    assert figures["mode_disarmed"] == _OFFBOARD, figures
    assert figures["descent_m_s"] == pytest.approx(_PX4_DESCENT_M_S, abs=DESCENT_TOL_M_S), figures
    assert abs(figures["rel_alt_m"]) <= 1.0, figures


#: the mock's clock runs this much faster than real time (its failsafe timeouts and the session's
#: figures are in autopilot seconds; the session's 1 Hz GCS heartbeat stays well inside the timeouts)
MOCK_SPEEDUP_X = 2.0


@pytest.fixture(scope="module")
def mock_obs():
    """The mock's session, run once for both tests of this module."""
    return observe("mock", mock_speedup=MOCK_SPEEDUP_X)


@pytest.mark.timeout(300)
def test_mock_offboard_loss_descends_as_real_px4(mock_obs):
    mock = mock_obs
    print("\nmock: offboard loss", mock.details["offboard_loss"])
    _check_px4_behaviour(mock.details["offboard_loss"])
    assert mock.details["offboard_loss"]["reaction_s"] < 2.5  # COM_OF_LOSS_T 1 s + a heartbeat


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_mock_offboard_loss_behaves_like_real_px4(mock_obs):
    require_sitl("px4")
    sitl, mock = observe("sitl"), mock_obs
    for name, obs in (("mock", mock), ("PX4 SIH", sitl)):
        print(f"\n{name}: offboard loss {obs.details['offboard_loss']}")
    assert differences(mock, sitl) == []
    _check_px4_behaviour(sitl.details["offboard_loss"])
