"""End to end against REAL PX4 firmware: 4 PX4 SIH vehicles (``SWARMSEEK_PX4_SITL``), CVT formation,
``swarmseek fly`` and one ``swarmseek sensor`` per vehicle (on PX4's onboard link 14030+i+offset),
each a subprocess, as a field team runs them.

Checks: the mission converges; the source is found within the tolerance the offline simulation
gives for this setting (the offline simulation is stop and go; the mission samples while moving,
measured at 0.21 m against real PX4, docs/sitl.md); every vehicle ends landed and disarmed (heard from PX4 itself, not from
the ground station's log); ``swarmseek audit`` is clean and counts exactly the 4 planned vehicles
(PX4 forwards the sensors' heartbeats, system id 255: no tlog for it).

Seeker: the plan ``swarmseek sitl`` writes, ``model`` with ``gamma_m = 20`` m, sampling while
moving (:func:`mission.sim.sitl_plan.seeker_settings`); the paper's gradient ascent is flown
against real ArduCopter (``tests/sitl/test_sitl_ardupilot.py``).

Tolerance: ``experiments.offline_seek.simulate_seeker`` runs the same seeker, formation (same CVT
offsets, same orientation), field, start, gamma, noise and convergence test with perfect tracking
over 200 noise draws; the flight must end within the offline 99th-percentile error plus the plan's
``arrival_tol_m`` (each vehicle only has to come within that distance of its slot before its
reading counts, which the offline model does not have), and its estimate within the same
distance of the offline mean estimate.

Speed: PX4 SIH honours ``PX4_SIM_SPEED_FACTOR`` (lock-step; PX4's start-up script scales its
link-loss timeouts by it) and the plan's wall-clock quantities are scaled by it
(:func:`mission.sim.sitl_plan.scale_for_speedup`), so the vehicles fly the real-time mission
``_SPEEDUP`` times faster (docs/sitl.md).
"""
from __future__ import annotations

import json
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
from pymavlink import mavutil

from mission.core.plan_sections import LINK_TIMEOUT_MAX_S
from tests.support.sitl_support import audit_failure_context, mission_story, require_sitl

_SPEEDUP = 3.0
_ON_GROUND = 1  # MAV_LANDED_STATE_ON_GROUND
_N = 4
_SOURCE = (6.0, 12.0, 13.0)
_START = (0.0, 20.0, 15.0)
_NOISE = 0.005
_SEEKING = {"eps": 50.0, "convergence_window": 10, "convergence_tol_m": 0.5, "arrival_tol_m": 0.7,
            "start_enu_m": list(_START)}


def _offline_tolerance(seeking: dict) -> tuple[float, np.ndarray]:
    """(offline 99th-percentile final error + arrival tolerance, offline mean estimate)."""
    from estimator import convergence_scan
    from estimator.seekers import make_seeker
    from experiments.offline_seek import simulate_seeker
    from mission.flight.targets import formation_offsets
    from sitl_mock.fields_gaussian import sigma2

    offsets = formation_offsets("cvt", _N, 2.0)
    trials = 200
    res = simulate_seeker(offsets, sigma2(np.array(_SOURCE)), np.tile(_START, (trials, 1)),
                          make_seeker(seeking["seeker"]), gamma_m=seeking["gamma_m"], iterations=120,
                          noise_std=_NOISE, rotate=False, seed=1)
    first, est, _ = convergence_scan(res.centres, window=seeking["convergence_window"],
                                     tol_m=seeking["convergence_tol_m"])
    assert np.all(first >= 0), "the offline simulation of this setting does not converge"
    err = np.linalg.norm(est - np.asarray(_SOURCE), axis=-1)
    return float(np.percentile(err, 99)) + seeking["arrival_tol_m"], est.mean(axis=0)


def _free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _final_states(gcs_port: int, sysids, timeout_s: float = 20.0) -> dict:
    """sysid -> {"armed", "alt" (relative, m), "landed_state"}, heard from PX4 on its GCS link: the
    latest of each, read until every vehicle reports disarmed and on the ground (PX4 disarms
    COM_DISARM_LAND seconds after it detects the landing) or ``timeout_s``."""
    conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs_port}", source_system=253)
    states: dict = {s: {} for s in sysids}
    deadline = time.monotonic() + timeout_s

    def _done():
        return all(v.get("armed") is False and v.get("landed_state") == _ON_GROUND and "alt" in v
                   for v in states.values())

    try:
        while time.monotonic() < deadline and not _done():
            msg = conn.recv_match(type=["HEARTBEAT", "GLOBAL_POSITION_INT", "EXTENDED_SYS_STATE"],
                                  blocking=True, timeout=0.5)
            if msg is None or msg.get_srcSystem() not in states or msg.get_srcComponent() != 1:
                continue
            state = states[msg.get_srcSystem()]
            if msg.get_type() == "HEARTBEAT":
                state["armed"] = bool(msg.base_mode & 128)
            elif msg.get_type() == "EXTENDED_SYS_STATE":
                state["landed_state"] = msg.landed_state
            else:
                state["alt"] = msg.relative_alt / 1000.0
    finally:
        conn.close()
    return states


@pytest.mark.slow
@pytest.mark.timeout(420)
def test_px4_sih_mission_finds_the_source_and_lands(tmp_path):
    sitl_dir = require_sitl("px4")
    from mission.sim.sitl_fleet import SitlFleet, SitlFleetConfig
    from mission.sim.sitl_mission import fly_sitl_mission

    from mission.sim.sitl_plan import seeker_settings

    seeking = dict(_SEEKING, **seeker_settings("model"))
    tolerance_m, offline_estimate = _offline_tolerance(seeking)
    zenoh = f"tcp/127.0.0.1:{_free_tcp_port()}"
    cfg = SitlFleetConfig(flavour="px4", n=_N, sitl_dir=sitl_dir, speedup=_SPEEDUP).free()
    with SitlFleet(cfg) as fleet:
        plan = fleet.write_plan(tmp_path / "plan.toml", zenoh_endpoint=zenoh,
                                overrides={"seeking": seeking, "faults": {"link_timeout_s": LINK_TIMEOUT_MAX_S}})
        result = fly_sitl_mission(fleet, plan, tmp_path / "logs", _SOURCE, zenoh=zenoh, noise=_NOISE,
                                  timeout_s=240.0)
        final = _final_states(14550 + cfg.port_offset, [v.sysid for v in fleet.vehicles])
    assert result.returncode == 0, "\n".join([mission_story(tmp_path / "logs"), "stdout:", result.stdout[-2000:],
                                              "stderr:", result.stderr[-2000:]])
    summary = result.summary
    assert summary is not None and summary["outcome"] == "converged", summary
    estimate = np.asarray(summary["estimate_enu"])
    error_m = float(np.linalg.norm(estimate - np.asarray(_SOURCE)))
    assert error_m <= tolerance_m, (error_m, tolerance_m, estimate)
    assert np.linalg.norm(estimate - offline_estimate) <= tolerance_m, (estimate, offline_estimate)
    for sysid, state in final.items():
        assert state.get("armed") is False, (sysid, state)
        assert state.get("landed_state") == _ON_GROUND, (sysid, state)  # PX4's own land detector
        # and near its home's height: PX4 SIH's altitude estimate drifts on the ground (1.1 m seen
        # once, with the land detector saying on the ground), so this only rules out a vehicle
        # disarmed in the air
        assert abs(state.get("alt", 99.0)) < 2.0, (sysid, state)
    tlogs = sorted(p.name for p in (tmp_path / "logs" / "tlogs").glob("vehicle-*.tlog"))
    assert tlogs == [f"vehicle-{v.sysid}.tlog" for v in fleet.vehicles], tlogs
    audit = subprocess.run([sys.executable, "-m", "mission", "audit", str(tmp_path / "logs"), "--json"],
                           capture_output=True, text=True, timeout=120)
    assert audit.returncode == 0, (audit.stdout[-3000:] + audit.stderr[-2000:] + "\n"
                                   + audit_failure_context(tmp_path / "logs"))
    report = json.loads(audit.stdout)
    assert report["ok"] and sorted(int(s) for s in report["per_vehicle"]) == [v.sysid for v in fleet.vehicles]
    assert report["setpoints_checked"] > 0
