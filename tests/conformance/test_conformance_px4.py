"""Mock conformance, PX4 SIH: the scripted pymavlink session (tests/conformance/script.py) against
the mock's "px4" personality and one real PX4 SIH SITL instance, compared with the tolerances of
tests/conformance/compare.py. Every difference must be one of the known ones
(tests/conformance/known.py), each documented in docs/interfaces.md ("Mock vs real SITL").

Needs ``SWARMSEEK_PX4_SITL`` (skipped without it; a failure under CI=true).
"""
from __future__ import annotations

import pytest
from tests.conformance.check import assert_conforms
from tests.support.sitl_support import require_sitl

FLAVOUR = "px4"


@pytest.mark.slow
@pytest.mark.timeout(420)
def test_mock_behaves_like_real_sitl():
    require_sitl(FLAVOUR)
    assert_conforms(FLAVOUR)
