"""`swarmseek ctl` and `swarmseek watch` in their own processes against a mission in another, as
peers connecting to the ground station's listen endpoint (through a zenoh router:
tests/mission/telemetry/test_ctl_processes_routed.py; the helpers: tests/support/ctl_processes.py)."""
from __future__ import annotations

import pytest

from tests.support.ctl_processes import _fly_and_operate, ctl, free_port

pytestmark = [pytest.mark.timeout(400), pytest.mark.slow]


def test_ctl_and_watch_peers_of_the_ground_station(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    _fly_and_operate(tmp_path, "direct", f'mode = "peer"\nlisten = ["{endpoint}"]', endpoint)
    # nobody there any more (every process stopped): a clear message and status 3, after the whole
    # --timeout-s (1 s: nobody can answer, however long it waits)
    rc, out = ctl(endpoint, "pause", fleet="direct", wait_s=1.0)
    assert rc == 3 and f"cannot reach {endpoint}" in out
