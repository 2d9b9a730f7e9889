"""The ground station's own faults (issue 20), stop side: SIGHUP and SIGPIPE sent to ``swarmseek fly``
mid-seek, and its zenoh router killed mid-seek. Helpers and the cases' checks:
tests/gcs_fault_support.py."""
from __future__ import annotations

import signal

import pytest

from gcs_fault_support import _Fly, _router_gone, _signal_mid_seek

pytestmark = [pytest.mark.timeout(300), pytest.mark.slow]

CASES = {
    "sighup": (_signal_mid_seek(signal.SIGHUP, 129), False),
    "sigpipe": (_signal_mid_seek(signal.SIGPIPE, 141), False),
    "zenoh-router-gone": (_router_gone, True),
}


@pytest.mark.parametrize("fault", list(CASES))
def test_fly_survives_its_own_faults(tmp_path, fault):
    case, routed = CASES[fault]
    m = _Fly(tmp_path, routed)
    try:
        case(m)
    finally:
        m.stop()
