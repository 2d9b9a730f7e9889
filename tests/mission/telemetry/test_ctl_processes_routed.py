"""`swarmseek ctl` and `swarmseek watch` in their own processes against a mission in another, all
connecting to a zenoh router (as peers of the ground station: tests/mission/telemetry/test_ctl_processes.py;
the helpers: tests/support/ctl_processes.py)."""
from __future__ import annotations

import json

import pytest

from tests.support.ctl_processes import _fly_and_operate, free_port

pytestmark = [pytest.mark.timeout(400), pytest.mark.slow]


def test_ctl_and_watch_through_a_zenoh_router(tmp_path):
    """The ground station (client), the mock fleet's sensors and the monitors each connect to a router."""
    import zenoh

    router_ep = f"tcp/127.0.0.1:{free_port()}"
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps([router_ep]))
    router = zenoh.open(conf)
    try:
        _fly_and_operate(tmp_path, "routed", f'mode = "client"\nconnect = ["{router_ep}"]', router_ep)
    finally:
        router.close()
