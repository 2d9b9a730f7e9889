"""Mock conformance, ArduCopter: the scripted pymavlink session (tests/conformance/script.py) against
the mock's "ardupilot" personality and one real ArduCopter SITL instance, compared with the tolerances of
tests/conformance/compare.py. Every difference must be one of the known ones
(tests/conformance/known.py), each documented in docs/interfaces.md ("Mock vs real SITL").

Needs ``SWARMSEEK_ARDUPILOT_SITL`` (skipped without it; a failure under CI=true).
"""
from __future__ import annotations

import pytest
from tests.conformance.check import assert_conforms
from tests.support.sitl_support import require_sitl

FLAVOUR = "ardupilot"


@pytest.mark.slow
@pytest.mark.timeout(420)
def test_mock_behaves_like_real_sitl():
    require_sitl(FLAVOUR)
    assert_conforms(FLAVOUR)
