"""The ground station's own faults, stop side: SIGHUP and SIGPIPE sent to ``swarmseek fly``
mid-seek, and its zenoh router killed mid-seek. Helpers and the cases' checks:
tests/support/gcs_fault_support.py."""
from __future__ import annotations

import signal

import pytest

from tests.support.gcs_fault_support import _Fly, _Run, _router_gone, _signal_mid_seek

pytestmark = [pytest.mark.timeout(300), pytest.mark.slow]

#: fault -> (case, runner, routed): as tests/mission/flight/test_gcs_faults_output.py (``fly`` or lock-step ``run``)
CASES = {
    "sighup": (_signal_mid_seek(signal.SIGHUP, 129), _Fly, False),
    "sigpipe": (_signal_mid_seek(signal.SIGPIPE, 141), _Run, False),
    "zenoh-router-gone": (_router_gone, _Fly, True),
}


@pytest.mark.parametrize("fault", list(CASES))
def test_fly_survives_its_own_faults(tmp_path, fault):
    case, runner, routed = CASES[fault]
    m = runner(tmp_path, routed)
    try:
        case(m)
    finally:
        m.stop()
