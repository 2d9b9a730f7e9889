"""Faults against REAL PX4 firmware (PX4 SIH, ``SWARMSEEK_PX4_SITL``): whole ``swarmseek fly`` missions
with one ``swarmseek sensor`` per vehicle, each a subprocess, and a fault injected mid-mission.

* ``test_px4_kill_and_link_cut_in_one_mission``: 5 vehicles at 2x, ``[faults] readmit = true``.
  PX4's offboard-loss action set to hold (``COM_OBL_RC_ACT = 5``; the default 0 descends and
  lands without RC, docs/faults.md). Vehicle 5's API link goes through a UDP relay in the test (the plan points its connection at the
  relay); after seek iteration 2 the relay drops everything both ways until PX4 itself has left
  OFFBOARD (heard on its own GCS link, not through the relay) and at least ``_CUT_S`` wall seconds
  have passed, then forwards again. The ground station declares it lost, re-forms for 4, and
  re-admits it when it is heard again (5 again). At the next iteration one PX4 process is killed
  with SIGKILL: lost, re-formed for 4, the mission converges with 4. Checked: the outcome and
  exit status (1: converged, one vehicle unheard at the end, ``airborne_left``; docs/mission.md),
  the losses and re-admission in the summary, the detection latencies, what PX4 did on the
  offboard loss (its mode, heard on its GCS link), every living vehicle landed and disarmed (PX4's
  own land detector), one ``.tlog`` per planned vehicle, ``swarmseek audit`` clean.
* ``test_px4_vehicle_that_cannot_arm``: 4 vehicles, one whose pre-arm checks fail
  (``SYS_HAS_MAG = 2``: PX4 SIH has one compass: "Preflight Fail: Found 1 compass (required: 2)").
  ``fly`` arms nothing: aborted in preflight naming the vehicle and PX4's words, exit 1; no vehicle
  armed (heard from PX4); ``swarmseek audit`` says the log is incomplete (no setpoint, exit 3).

The measured figures are printed (``pytest -s``) and are in docs/faults.md.
"""
from __future__ import annotations

import dataclasses
import json
import os
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from sitl_px4_fault_support import FlyRun, GcsListener, UdpRelay, free_udp_port
from sitl_support import audit_failure_context, require_sitl

#: 2x, not the 3x of tests/test_sitl_px4.py: 5 instances plus 5 sensors; on a host at load average
#: 25-30 a 3x fleet fell so far behind that PX4's 1 s offboard-loss timer took over 30 s of wall time
_SPEEDUP = 2.0
_SOURCE = (6.0, 12.0, 13.0)
_START = (0.0, 20.0, 15.0)
_NOISE = 0.005
_SEEKING = {"eps": 50.0, "convergence_window": 10, "convergence_tol_m": 0.5, "arrival_tol_m": 0.7,
            "start_enu_m": list(_START)}
#: the relay stays cut at least this long (wall seconds): well over the ground station's 1 s link
#: timeout and PX4's COM_OF_LOSS_T (1 s of wall time at any speed-up), under its COM_DL_LOSS_T (10 s)
_CUT_S = 4.0
#: the documented exit status of a mission that converged with a vehicle lost and unheard at the end
#: (its state unknown: reported airborne, ``airborne_left``; docs/mission.md "Exit status")
_EXIT_VEHICLE_UNACCOUNTED = 1
#: the documented exit status of a preflight that fails: aborted, nothing armed (docs/mission.md)
_EXIT_ABORTED = 1
#: ``swarmseek audit``: 3 = incomplete (no setpoint checked; docs/audit.md)
_AUDIT_INCOMPLETE = 3


def _free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _events(records, sysid: int, words: str) -> list[dict]:
    return [r for r in records if r.get("type") == "event" and r.get("sysid") == sysid
            and words in r.get("message", "")]


def _iterations(records) -> list[dict]:
    return [r for r in records if r.get("type") == "iteration"]


def _audit(log_dir) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mission", "audit", str(log_dir), "--json"],
                          capture_output=True, text=True, timeout=180)


def _cut_and_restore(run: FlyRun, relay: UdpRelay, gcs: GcsListener, sysid: int) -> dict:
    """Cut the relay after iteration 2, restore it once PX4 left OFFBOARD and ``_CUT_S`` passed."""
    run.wait_for(lambda recs: len(_iterations(recs)) >= 2, 240.0, "seek iteration 2")
    t_cut = time.time()
    relay.cut(True)
    lost = run.wait_for(lambda recs: _events(recs, sysid, "lost:"), 90.0, f"vehicle {sysid} declared lost")[0]
    deadline = time.monotonic() + 120.0  # generous: a loaded host slows PX4's simulated time down
    while not [m for m in gcs.modes(sysid, t_cut) if m[1] != "OFFBOARD"]:
        assert time.monotonic() < deadline, f"PX4 {sysid} stayed OFFBOARD 120 s without its ground station"
        time.sleep(0.2)
    while time.time() < t_cut + _CUT_S:
        time.sleep(0.2)
    relay.cut(False)
    t_restore = time.time()
    back = run.wait_for(lambda recs: _events(recs, sysid, "re-admitted:"), 120.0, f"vehicle {sysid} re-admitted")[0]
    return {"t_cut": t_cut, "t_restore": t_restore, "lost": lost, "readmitted": back}


def _kill_after_next_iteration(run: FlyRun, vehicle) -> dict:
    """SIGKILL ``vehicle``'s PX4 at the first iteration after the re-admission; its loss event."""
    k0 = len(_iterations(run.records()))
    run.wait_for(lambda recs: len(_iterations(recs)) > k0, 120.0, "an iteration after the re-admission")
    t_kill = time.time()
    os.killpg(vehicle.pid, signal.SIGKILL)
    lost = run.wait_for(lambda recs: _events(recs, vehicle.sysid, "lost:"), 90.0,
                        f"vehicle {vehicle.sysid} declared lost after the kill")[0]
    return {"t_kill": t_kill, "lost": lost, "iteration": k0}


def _wait_down(gcs: GcsListener, sysids, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while not all(gcs.down(s) for s in sysids):
        if time.monotonic() > deadline:
            pytest.fail(f"not all of {sysids} disarmed on the ground after {timeout_s} s: "
                        f"{ {s: gcs.state(s) for s in sysids} }")
        time.sleep(0.1)


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_px4_kill_and_link_cut_in_one_mission(tmp_path):
    sitl_dir = require_sitl("px4")
    from mission.sim.sitl_fleet import SitlFleet, SitlFleetConfig
    from mission.sim.sitl_plan import seeker_settings, write_plan

    # a 30-iteration convergence window (10 in the plain mission): the seek must not end before
    # both faults are in (on a host at load average 40 it converged 14 iterations in, while the
    # cut vehicle waited to be re-admitted)
    seeking = dict(_SEEKING, convergence_window=30, **seeker_settings("model"))
    zenoh = f"tcp/127.0.0.1:{_free_tcp_port()}"
    # COM_OBL_RC_ACT = 5 (hold): with PX4's default 0 (position mode) and no RC, PX4 v1.16 SIH shows
    # POSCTL but descends at about 0.5 m/s and lands (measured, docs/faults.md): whether the vehicle
    # is re-admitted or found landed is then a race with the ground station's next re-formation
    cfg = SitlFleetConfig(flavour="px4", n=5, sitl_dir=sitl_dir, speedup=_SPEEDUP,
                          params={"COM_OBL_RC_ACT": 5}).free()
    log_dir = tmp_path / "logs"
    with SitlFleet(cfg) as fleet, GcsListener(14550 + cfg.port_offset, [v.sysid for v in fleet.vehicles]) as gcs:
        cut_v, kill_v = fleet.vehicles[4], fleet.vehicles[1]
        relay_port = free_udp_port()
        with UdpRelay(int(cut_v.connection.rsplit(":", 1)[1]), relay_port) as relay:
            planned = [dataclasses.replace(v, connection=f"udpin:127.0.0.1:{relay_port}") if v is cut_v else v
                       for v in fleet.vehicles]
            plan = write_plan(tmp_path / "plan.toml", planned, fleet.origin, flavour="px4", zenoh_endpoint=zenoh,
                              speedup=_SPEEDUP, overrides={"seeking": seeking, "faults": {"readmit": True}})
            with FlyRun(fleet, plan, log_dir, _SOURCE, zenoh=zenoh, noise=_NOISE) as run:
                cut = _cut_and_restore(run, relay, gcs, cut_v.sysid)
                kill = _kill_after_next_iteration(run, kill_v)
                status = run.wait_end(420.0)
                output, summary = run.output(), run.summary()
        dropped = relay.counts.get("dropped", {})
        living = [v.sysid for v in fleet.vehicles if v is not kill_v]
        _wait_down(gcs, living, 60.0)
        killed_state, t_end = gcs.state(kill_v.sysid), time.time()
        cut["px4_modes"] = gcs.modes(cut_v.sysid, cut["t_cut"])
    figures = {"cut_lost_latency_s": cut["lost"]["latency_s"],
               "cut_detect_after_cut_s": round(cut["lost"]["t_s"] - cut["t_cut"], 2),
               "px4_modes_after_cut": [(round(t - cut["t_cut"], 2), m, a) for t, m, a in cut["px4_modes"]],
               "readmitted_after_restore_s": round(cut["readmitted"]["t_s"] - cut["t_restore"], 2),
               "kill_lost_latency_s": kill["lost"]["latency_s"],
               "kill_detect_after_kill_s": round(kill["lost"]["t_s"] - kill["t_kill"], 2),
               "relay_dropped": dropped, "exit": status,
               "estimate_enu": summary and summary.get("estimate_enu"),
               "iterations": len(_iterations(run.records()))}
    print("PX4 SIH kill + link cut:", json.dumps(figures))
    assert status == _EXIT_VEHICLE_UNACCOUNTED, (status, output)
    assert summary is not None and summary["outcome"] == "converged", (summary, output)
    assert [e["sysid"] for e in summary["lost"]] == [kill_v.sysid], summary["lost"]
    assert [e["sysid"] for e in summary["readmitted"]] == [cut_v.sysid], summary["readmitted"]
    assert [e["sysid"] for e in summary["airborne_left"]] == [kill_v.sysid], summary["airborne_left"]
    # each loss declared after its fault, once the vehicle had been silent for the plan's link
    # timeout (1 s; no upper bound on wall time here: a loaded host delays everything, the figures
    # are in docs/faults.md)
    for fault, t_fault in ((cut, cut["t_cut"]), (kill, kill["t_kill"])):
        assert fault["lost"]["t_s"] > t_fault and fault["lost"]["reason"] == "link", figures
        assert fault["lost"]["latency_s"] >= 1.0, figures
    # PX4's own offboard-loss failsafe (COM_OBL_RC_ACT 5): hold (AUTO.LOITER), armed, until the
    # ground station re-engaged OFFBOARD; then landed by the mission's end
    after_cut = [(m, a) for _, m, a in cut["px4_modes"]]
    assert after_cut[:2] == [("LOITER", True), ("OFFBOARD", True)], figures
    assert ("LAND", True) in after_cut[2:], figures
    assert summary["lost"][0]["reason"] == "link", summary["lost"]
    # the killed PX4 stayed silent (its last heartbeat, stamped when the listener read it, came soon
    # after the kill at the latest, long before the end of the mission)
    assert killed_state.get("heard", 0.0) < min(t_end - 10.0, kill["lost"]["t_s"] + 5.0), (killed_state, t_end)
    assert dropped.get("up", 0) > 0 and dropped.get("down", 0) > 0, dropped
    error_m = float(np.linalg.norm(np.asarray(summary["estimate_enu"]) - np.asarray(_SOURCE)))
    assert error_m < 1.5, figures
    tlogs = sorted(p.name for p in (log_dir / "tlogs").glob("vehicle-*.tlog"))
    assert tlogs == [f"vehicle-{v.sysid}.tlog" for v in fleet.vehicles], tlogs
    audit = _audit(log_dir)
    assert audit.returncode == 0, (audit.stdout[-3000:] + audit.stderr[-2000:] + "\n"
                                   + audit_failure_context(log_dir))
    report = json.loads(audit.stdout)
    assert report["ok"] and sorted(int(s) for s in report["per_vehicle"]) == [v.sysid for v in fleet.vehicles]
    assert report["setpoints_checked"] > 0


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_px4_vehicle_that_cannot_arm(tmp_path):
    sitl_dir = require_sitl("px4")
    from mission.sim.sitl_fleet import SitlFleet, SitlFleetConfig

    zenoh = f"tcp/127.0.0.1:{_free_tcp_port()}"
    cfg = SitlFleetConfig(flavour="px4", n=4, sitl_dir=sitl_dir).free()
    log_dir = tmp_path / "logs"
    with SitlFleet(cfg) as fleet, GcsListener(14550 + cfg.port_offset, [v.sysid for v in fleet.vehicles]) as gcs:
        bad = fleet.vehicles[3]
        done = subprocess.run([str(fleet.run_dir / "px4-bin" / "px4-param"), "--instance", str(bad.instance),
                               "set", "SYS_HAS_MAG", "2"], capture_output=True, text=True, timeout=20)
        assert done.returncode == 0, done.stdout + done.stderr
        plan = fleet.write_plan(tmp_path / "plan.toml", zenoh_endpoint=zenoh,
                                overrides={"seeking": dict(_SEEKING),
                                           "preflight": {"autopilot_ready_timeout_s": 10.0}})
        t0 = time.time()
        with FlyRun(fleet, plan, log_dir, _SOURCE, zenoh=zenoh, noise=_NOISE) as run:
            status = run.wait_end(180.0)
            output, summary = run.output(), run.summary()
        ever_armed = [c for c in gcs.changes if c[0] >= t0 and c[3]]
        final = {v.sysid: gcs.state(v.sysid) for v in fleet.vehicles}
    print("PX4 SIH vehicle that cannot arm:", json.dumps({"exit": status, "outcome": summary and summary["outcome"],
                                                          "message": summary and summary.get("message"),
                                                          "fly_wall_s": round(time.time() - t0, 1)}))
    assert status == _EXIT_ABORTED, (status, output)
    assert summary is not None and summary["outcome"] == "aborted", (summary, output)
    assert "nothing armed" in summary["message"], summary["message"]
    readiness = {r["sysid"]: r for r in summary["readiness"]}
    assert readiness[bad.sysid]["checks"]["autopilot"] is False, readiness[bad.sysid]
    assert "compass" in " ".join(readiness[bad.sysid]["problems"]), readiness[bad.sysid]
    assert all(all(readiness[v.sysid]["checks"].values()) for v in fleet.vehicles if v is not bad), readiness
    assert ever_armed == [], ever_armed
    assert all(st.get("armed") is False for st in final.values()), final
    audit = _audit(log_dir)
    assert audit.returncode == _AUDIT_INCOMPLETE, audit.stdout[-2000:] + audit.stderr[-2000:]
