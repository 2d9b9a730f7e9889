"""Mock conformance, ArduCopter: the scripted pymavlink session (tests/conformance/script.py) against
the mock's "ardupilot" personality and one real ArduCopter SITL instance, compared with the tolerances of
tests/conformance/compare.py. Every difference must be one of the known ones
(tests/conformance/known.py), each documented in docs/interfaces.md ("Mock vs real SITL").

Needs ``SWARMSEEK_ARDUPILOT_SITL`` (skipped without it; a failure under CI=true).
"""
from __future__ import annotations

import pytest
from conformance.check import check_conformance
from conformance.compare import EVENT_ORDER
from sitl_support import require_sitl

FLAVOUR = "ardupilot"


@pytest.mark.slow
@pytest.mark.timeout(420)
def test_mock_behaves_like_real_sitl():
    require_sitl(FLAVOUR)
    result = check_conformance(FLAVOUR)
    listing = "\n".join(str(d) for d in result["differences"])
    assert result["unexpected"] == [], f"new mock/SITL differences (fix the mock or document them):\n{listing}"
    assert result["missing"] == [], f"known differences no longer seen (remove them from known.py and docs):\n{listing}"
    assert result["undocumented"] == [], "known differences missing from docs/interfaces.md"
    for obs in (result["mock"], result["sitl"]):   # the sequence really ran through, in both
        assert all(name in obs.events_s for name in EVENT_ORDER)
        assert obs.acks["arm"] == obs.acks["takeoff"] == obs.acks["land"] == 0
        assert obs.details["target"]["reached"] and obs.details["mission_download"]["waypoints_match"]
