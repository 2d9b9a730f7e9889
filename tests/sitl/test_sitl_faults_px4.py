"""Faults against REAL PX4 firmware (PX4 SIH, ``SWARMSEEK_PX4_SITL``): whole ``swarmseek fly`` missions
with one ``swarmseek sensor`` per vehicle, each a subprocess, and a fault injected mid-mission.

* ``test_px4_link_cut_then_kill_in_one_mission``: 6 vehicles (speed-up ``_SPEEDUP``) with the fleet's failsafe
  parameters as the preflight reads them (PX4's default offboard-loss action ``COM_OBL_RC_ACT = 0``,
  position mode; ``NAV_DLL_ACT = 3``, land after ``COM_DL_LOSS_T`` 10 s), ``[faults] readmit = true``.
  Vehicle 6's API link goes through a UDP relay in the test (the plan points its connection at the
  relay); after seek iteration 2 the relay drops everything both ways. The ground station declares
  it lost and re-forms for 5. PX4 itself (heard on its own GCS link, not through the relay) leaves
  OFFBOARD for POSCTL and, with no RC, descends at its land speed (MPC_LAND_SPEED 0.7 m/s; landed
  state IN_AIR until ON_GROUND, never LANDING), lands and disarms; once disarmed its heartbeat
  shows OFFBOARD again (the mode the ground station had chosen: PX4's failsafe ends with the
  flight). AUTO.LOITER then AUTO.LAND are allowed on the way down (its data-link-loss timer may run
  out first on a slow host: PX4 holds for COM_FAIL_ACT_T, then lands). The relay stays cut until PX4 says it is disarmed on the ground, then forwards
  again. Heard again (judged on a HEARTBEAT from after the loss), disarmed on the ground, the
  vehicle is not re-admitted but kept out, no command sent. At the next iteration another PX4 process is killed with SIGKILL:
  lost, re-formed for 4, the mission converges with 4. Checked: the outcome and exit status (5:
  converged, one vehicle unheard at the end, ``airborne_left``; docs/mission.md), both losses in
  the summary and no re-admission, the detection latencies, what PX4 did after the cut (its modes,
  a descent to the ground, disarmed, never armed again), every living vehicle landed and disarmed
  (PX4's own land detector), one ``.tlog`` per planned vehicle, ``swarmseek audit`` clean.
  (Before: 5 vehicles with ``COM_OBL_RC_ACT = 5`` and a re-admission; its check of a LAND mode at
  the end failed once; stop 28.)
* ``test_px4_battery_and_geofence_failsafes_in_one_mission``: PX4's own low-battery failsafe
  (SIH's battery let down) and geofence breach in one 5-vehicle mission (its docstring).
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

from tests.sitl.sitl_px4_fault_support import FlyRun, GcsListener, UdpRelay, free_udp_port
from tests.support.sitl_support import audit_failure_context, require_sitl

#: simulation speed-up of the fault missions: 1 (real time) by default, not the 3x of
#: tests/sitl/test_sitl_px4.py: 6 instances plus 6 sensors; at 2x, on this 2-core host at load average
#: 41 (other work), PX4 SIH and the sensors fell so far behind that no reading came for minutes and
#: PX4 lost its offboard setpoints (at load 15-30 the 2x runs passed); at 3x and load 25-30 PX4's
#: 1 s offboard-loss timer took over 30 s of wall time
_SPEEDUP = float(os.environ.get("SWARMSEEK_TEST_PX4_SPEEDUP", "1"))

_SOURCE = (6.0, 12.0, 13.0)
_START = (0.0, 20.0, 15.0)
_NOISE = 0.005
_SEEKING = {"eps": 50.0, "convergence_window": 10, "convergence_tol_m": 0.5, "arrival_tol_m": 0.7,
            "start_enu_m": list(_START)}
#: the plan's link timeout in the link-cut mission: 1.4 s (the plan's maximum), not the default 1 s:
#: at load average 35 the relay process stalled 1.25 s during the takeoff and the vehicle was lost
#: before any cut
_LINK_TIMEOUT_S = 1.4
#: the documented exit status of a mission that converged with a vehicle lost and unheard at the end
#: (its state unknown: reported airborne, ``airborne_left``; docs/mission.md "Exit status")
_EXIT_VEHICLE_UNACCOUNTED = 5
#: PX4 modes (``mavutil.mode_string_v10``) in which a vehicle that lost its offboard setpoints
#: without RC comes down: position mode (COM_OBL_RC_ACT 0, no pilot: PX4 descends) and AUTO.LAND
#: (its data-link-loss action NAV_DLL_ACT 3 when COM_DL_LOSS_T runs out before the touchdown),
#: preceded by AUTO.LOITER, PX4's hold for COM_FAIL_ACT_T (5 s) before that action (measured: a run
#: at load 10-11 descending at 0.49 m/wall s showed POSCTL 2.1 s, LOITER 12.2 s, LAND 17.3 s after the cut)
_DESCENT_MODES = ("POSCTL", "LOITER", "LAND")
#: the documented exit status of a mission that ended with vehicles lost, none left airborne (docs/mission.md)
_EXIT_VEHICLE_LOST = 4
#: the documented exit status of a preflight that fails: aborted, nothing armed (docs/mission.md)
_EXIT_ABORTED = 1
#: ``swarmseek audit``: 3 = incomplete (no setpoint checked; docs/audit.md)
_AUDIT_INCOMPLETE = 3


def _free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _audit(log_dir) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mission", "audit", str(log_dir), "--json"],
                          capture_output=True, text=True, timeout=180)


def _events(records, sysid: int, words: str) -> list[dict]:
    return [r for r in records if r.get("type") == "event" and r.get("sysid") == sysid
            and words in r.get("message", "")]


def _iterations(records) -> list[dict]:
    return [r for r in records if r.get("type") == "iteration"]


def _cut_until_down(run: FlyRun, relay: UdpRelay, gcs: GcsListener, sysid: int) -> dict:
    """Cut the relay after iteration 2; restore it once PX4 has come down and disarmed by itself."""
    run.wait_for(lambda recs: len(_iterations(recs)) >= 2, 240.0, "seek iteration 2")
    early = _events(run.records(), sysid, "lost:")
    assert not early, f"vehicle {sysid} lost before the cut (a stalled host or relay): {early[0]['message']}"
    t_cut = time.time()
    relay.cut(True)
    lost = run.wait_for(lambda recs: _events(recs, sysid, "lost:"), 90.0, f"vehicle {sysid} declared lost")[0]
    # generous: a loaded host slows PX4's simulated time down (its descent from 15 m took about
    # 10 s of wall time at 2x on a quiet host)
    gcs.wait(lambda g: [m for m in g.modes(sysid, t_cut) if m[1] != "OFFBOARD"], 120.0,
             f"PX4 {sysid} to leave OFFBOARD without its ground station")
    gcs.wait(lambda g: g.down(sysid), 300.0, f"PX4 {sysid} to land and disarm by itself")
    t_down = time.time()
    relay.cut(False)
    t_restore = time.time()
    back = run.wait_for(lambda recs: _events(recs, sysid, "heard again"), 120.0,
                        f"vehicle {sysid} heard again after the restore")[0]
    return {"t_cut": t_cut, "t_down": t_down, "t_restore": t_restore, "lost": lost, "back": back}


def _kill_after_next_iteration(run: FlyRun, vehicle) -> dict:
    """SIGKILL ``vehicle``'s PX4 at the first iteration from now; its loss event."""
    k0 = len(_iterations(run.records()))
    run.wait_for(lambda recs: len(_iterations(recs)) > k0, 180.0, "the next iteration")
    t_kill = time.time()
    os.killpg(vehicle.pid, signal.SIGKILL)
    lost = run.wait_for(lambda recs: _events(recs, vehicle.sysid, "lost:"), 90.0,
                        f"vehicle {vehicle.sysid} declared lost after the kill")[0]
    return {"t_kill": t_kill, "lost": lost, "iteration": k0}


def _cut_figures(cut: dict, gcs: GcsListener, sysid: int) -> dict:
    modes = gcs.modes(sysid, cut["t_cut"])
    alts = gcs.alts(sysid, cut["t_cut"])
    left = next(t for t, m, _ in modes if m != "OFFBOARD")
    disarmed = next((t for t, _, a in modes if not a), None)
    low = next((t for t, a in alts if t > left and a < 0.5), None)
    high = min(alts, key=lambda x: abs(x[0] - left)) if alts else None
    return {"px4_modes_after_cut": [(round(t - cut["t_cut"], 2), m, a) for t, m, a in modes],
            "landed_states_after_cut": [(round(t - cut["t_cut"], 2), x) for t, x in
                                        gcs.landed_states(sysid, cut["t_cut"])],
            "descent_m_per_wall_s": round((high[1] - 0.5) / (low - high[0]), 2) if low and high else None,
            "left_offboard_after_cut_s": round(left - cut["t_cut"], 2),
            "disarmed_after_cut_s": disarmed and round(disarmed - cut["t_cut"], 2),
            "alt_at_left_m": round(min(alts, key=lambda x: abs(x[0] - left))[1], 2) if alts else None,
            "alt_end_m": round(alts[-1][1], 2) if alts else None,
            "lost_latency_s": cut["lost"]["latency_s"],
            "detect_after_cut_s": round(cut["lost"]["t_s"] - cut["t_cut"], 2),
            "heard_again_after_restore_s": round(cut["back"]["t_s"] - cut["t_restore"], 2),
            "heard_again_message": cut["back"]["message"]}


def _check_px4_came_down(figures: dict, modes: list) -> None:
    """PX4 after the cut: position mode (COM_OBL_RC_ACT 0), armed, then only descent modes while
    armed, then disarmed (on the ground) and never armed again. Once disarmed PX4 shows the mode
    the ground station had chosen, OFFBOARD (its failsafe ends with the flight): measured, not a
    re-engagement."""
    assert modes and modes[0][1:] == ("POSCTL", True), figures
    armed = [m for _, m, a in modes if a]
    assert set(armed) <= set(_DESCENT_MODES), figures
    first_disarm = next((i for i, (_, _, a) in enumerate(modes) if not a), None)
    assert first_disarm is not None, figures
    assert all(not a for _, _, a in modes[first_disarm:]), figures


def _wait_down(gcs: GcsListener, sysids, timeout_s: float) -> None:
    gcs.wait(lambda g: all(g.down(s) for s in sysids), timeout_s, f"{sysids} disarmed on the ground")


class SeparationDeadlock(AssertionError):
    """The mission aborted: two vehicles held by the separation envelope until a settle timeout
    (the ground-station defect fixed by moving held vehicles aside, docs/faults.md "The
    separation-hold deadlock, fixed"; raised under its own name should it come back)."""


@pytest.mark.unstable_mission  # passes alone (its plan sets [seeking] region_hold = 0 so the seek reaches the fault);
# beside the suite's other SITL fleets the 2-core machine starved (docs/faults.md)
@pytest.mark.slow
@pytest.mark.timeout(1200)
def test_px4_link_cut_then_kill_in_one_mission(tmp_path):
    sitl_dir = require_sitl("px4")
    from mission.sim.sitl_fleet import SitlFleet, SitlFleetConfig
    from mission.sim.sitl_plan import seeker_settings, write_plan

    # a 30-iteration convergence window: the seek must not end before both faults are in
    seeking = dict(_SEEKING, convergence_window=30, region_hold=0, **seeker_settings("model"))
    zenoh = f"tcp/127.0.0.1:{_free_tcp_port()}"
    cfg = SitlFleetConfig(flavour="px4", n=6, sitl_dir=sitl_dir, speedup=_SPEEDUP).free()
    log_dir = tmp_path / "logs"
    with SitlFleet(cfg) as fleet, GcsListener(14550 + cfg.port_offset, [v.sysid for v in fleet.vehicles]) as gcs:
        cut_v, kill_v = fleet.vehicles[5], fleet.vehicles[1]
        relay_port = free_udp_port()
        with UdpRelay(int(cut_v.connection.rsplit(":", 1)[1]), relay_port) as relay:
            planned = [dataclasses.replace(v, connection=f"udpin:127.0.0.1:{relay_port}") if v is cut_v else v
                       for v in fleet.vehicles]
            plan = write_plan(tmp_path / "plan.toml", planned, fleet.origin, flavour="px4", zenoh_endpoint=zenoh,
                              speedup=_SPEEDUP, overrides={"seeking": seeking,
                                                           "faults": {"readmit": True, "link_timeout_s": _LINK_TIMEOUT_S}})
            with FlyRun(fleet, plan, log_dir, _SOURCE, zenoh=zenoh, noise=_NOISE) as run:
                cut = _cut_until_down(run, relay, gcs, cut_v.sysid)
                kill = _kill_after_next_iteration(run, kill_v)
                status = run.wait_end(600.0)
                output, summary = run.output(), run.summary()
        dropped = relay.counts.get("dropped", {})
        living = [v.sysid for v in fleet.vehicles if v is not kill_v]
        _wait_down(gcs, living, 120.0)
        killed_state, t_end = gcs.state(kill_v.sysid), time.time()
        figures = _cut_figures(cut, gcs, cut_v.sysid)
        cut_modes = gcs.modes(cut_v.sysid, cut["t_cut"])
        cut_final = gcs.state(cut_v.sysid)
    figures.update({"kill_lost_latency_s": kill["lost"]["latency_s"],
                    "kill_detect_after_kill_s": round(kill["lost"]["t_s"] - kill["t_kill"], 2),
                    "relay_dropped": dropped, "exit": status,
                    "outcome": summary and summary["outcome"],
                    "estimate_enu": summary and summary.get("estimate_enu"),
                    "iterations": len(_iterations(run.records()))})
    print("PX4 SIH link cut + kill:", json.dumps(figures))
    _check_px4_came_down(figures, cut_modes)  # PX4's own behaviour, whatever the ground station did
    if summary is not None and summary["outcome"] == "aborted" and "to settle" in summary.get("message", "") \
            and summary.get("separation_interventions", 0) > 0:
        raise SeparationDeadlock(f"{summary['message']} ({summary['separation_interventions']} separation holds)")
    assert status == _EXIT_VEHICLE_UNACCOUNTED, (status, output)
    assert summary is not None and summary["outcome"] == "converged", (summary, output)
    assert sorted(e["sysid"] for e in summary["lost"]) == sorted([kill_v.sysid, cut_v.sysid]), summary["lost"]
    assert all(e["reason"] == "link" for e in summary["lost"]), summary["lost"]
    assert summary["readmitted"] == [], summary["readmitted"]
    assert [e["sysid"] for e in summary["airborne_left"]] == [kill_v.sysid], summary["airborne_left"]
    # each loss declared after its fault, once the vehicle had been silent for the plan's link
    # timeout (no upper bound on wall time: a loaded host delays detection, docs/faults.md)
    for fault, t_fault in ((cut, cut["t_cut"]), (kill, kill["t_kill"])):
        assert fault["lost"]["t_s"] > t_fault, figures
        assert fault["lost"]["latency_s"] >= _LINK_TIMEOUT_S, figures
    # PX4's own failsafe with the preflight-checked parameters (checked above: position mode without
    # RC, came down and disarmed on the ground by itself, the link cut until then); heard again: kept out
    assert cut_final.get("armed") is False and cut_final.get("alt", 99.0) < 1.0, cut_final
    assert "kept out" in cut["back"]["message"] and "disarmed" in cut["back"]["message"], cut["back"]
    # the killed PX4 stayed silent (its last heartbeat came soon after the kill at the latest)
    assert killed_state.get("heard", 0.0) < min(t_end - 10.0, kill["lost"]["t_s"] + 5.0), (killed_state, t_end)
    assert dropped.get("up", 0) > 0 and dropped.get("down", 0) > 0, ("relay counts", relay.counts)
    error_m = float(np.linalg.norm(np.asarray(summary["estimate_enu"]) - np.asarray(_SOURCE)))
    assert error_m < 1.5, figures
    tlogs = sorted(p.name for p in (log_dir / "tlogs").glob("vehicle-*.tlog"))
    assert tlogs == sorted(f"vehicle-{v.sysid}.tlog" for v in fleet.vehicles), tlogs  # sysids 5-10 when others run
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


#: parameters of every instance from boot for the failsafe mission: PX4's own low-battery action
#: "return at critical, land at emergency" (COM_LOW_BAT_ACT 3) with a low return altitude, and its
#: geofence action land (GF_ACTION 5); the fence itself is off (GF_MAX_VER_DIST 0) until lowered
_FAILSAFE_PARAMS = {"COM_LOW_BAT_ACT": 3, "RTL_RETURN_ALT": 15.0, "RTL_DESCEND_ALT": 10.0, "GF_ACTION": 5}
#: SIH's simulated battery drains from the arming at 100 % / SIM_BAT_DRAIN (60 s) down to
#: SIM_BAT_MIN_PCT (50 % by default); lowered to this mid-seek it goes on draining: with 6 PX4
#: reported 7 % and stayed there, not under BAT_CRIT_THR (7 %): no failsafe (measured)
_BATTERY_MIN_PCT = 3.0
#: the failsafe mission's speed-up: 2, as measured (at 2x PX4 went to LAND 18 s after the
#: parameter; at 1x, load 26-29, PX4 reported 4 % and took no failsafe action within 240 s:
#: unexplained, open, docs/faults.md)
_FAILSAFE_SPEEDUP = float(os.environ.get("SWARMSEEK_TEST_PX4_FAILSAFE_SPEEDUP", "2"))
#: the geofence's height above home set mid-seek on a vehicle flying 11-17 m up
_FENCE_MAX_VER_M = 8.0
_FAILSAFE_MODES = ("RTL", "LAND")


def _px4_param(fleet, vehicle, name: str, value: float) -> float:
    """``px4-param set`` on ``vehicle``'s instance; its wall time."""
    t = time.time()
    done = subprocess.run([str(fleet.run_dir / "px4-bin" / "px4-param"), "--instance", str(vehicle.instance),
                           "set", name, str(value)], capture_output=True, text=True, timeout=30)
    assert done.returncode == 0, (name, done.stdout + done.stderr)
    return t


def _px4_failsafe(run: FlyRun, gcs: GcsListener, fleet, vehicle, name: str, value: float) -> dict:
    """Set ``name`` on ``vehicle``; wait for PX4's failsafe mode (heard on its GCS link) and the
    ground station's loss event. Wall seconds."""
    assert run.fly.poll() is None, f"fly ended before {name} was set:\n{run.output()}"
    t_set = _px4_param(fleet, vehicle, name, value)
    gcs.wait(lambda g: [m for m in g.modes(vehicle.sysid, t_set) if m[1] in _FAILSAFE_MODES and m[2]], 240.0,
             f"PX4 {vehicle.sysid} in {_FAILSAFE_MODES} after {name} = {value}")
    t_mode, mode, _ = next(m for m in gcs.modes(vehicle.sysid, t_set) if m[1] in _FAILSAFE_MODES and m[2])
    lost = run.wait_for(lambda recs: _events(recs, vehicle.sysid, "lost:"), 120.0,
                        f"vehicle {vehicle.sysid} declared lost after its failsafe")[0]
    return {"t_set": t_set, "t_mode": t_mode, "mode": mode, "lost": lost,
            "battery_pct": [(round(t - t_set, 2), b) for t, b in gcs.batteries(vehicle.sysid, t_set)][:8],
            "px4_texts": [(round(t - t_set, 2), x) for t, x in gcs.statustexts(vehicle.sysid, t_set)][:8],
            "modes_before": [(round(t - t_set, 2), m, a) for t, m, a in gcs.modes(vehicle.sysid, t_set) if t < t_mode],
            "reaction_s": round(t_mode - t_set, 2), "detect_s": round(lost["t_s"] - t_mode, 2)}


class FoughtPx4Failsafe(AssertionError):
    """The ground station re-engaged OFFBOARD while PX4's own failsafe was acting (the defect fixed
    by handing such a vehicle to its autopilot, docs/faults.md; raised by name should it come back)."""


@pytest.mark.unstable_mission  # passes alone (its plan sets [seeking] region_hold = 0 so the seek reaches the fault);
# beside the suite's other SITL fleets the 2-core machine starved (docs/faults.md)
@pytest.mark.slow
@pytest.mark.timeout(1200)
def test_px4_battery_and_geofence_failsafes_in_one_mission(tmp_path):
    """5 vehicles (speed-up ``_FAILSAFE_SPEEDUP``). After seek iteration 2, SIH's simulated battery of one vehicle is let down
    (``SIM_BAT_MIN_PCT``): PX4 returns (COM_LOW_BAT_ACT 3) by itself; the ground station calls it
    "left", does not fight it, re-forms for 4. At the next iteration another vehicle's geofence is
    lowered under it (``GF_MAX_VER_DIST``): PX4 holds (AUTO.LOITER, ``COM_FAIL_ACT_T``) then lands
    (GF_ACTION 5); "left"; 3 left: the seek ends ``too_few_vehicles`` (exit 1), the three come home
    and land. Checked: the outcome, PX4's modes, every vehicle disarmed on the ground, the audit;
    last, that neither failsafe was fought (never OFFBOARD again while armed). Before the fix the
    fence one was, once (LOITER 1.0 s after the lowered ceiling, the ground station re-engaged
    OFFBOARD, PX4 held and landed again); now both holds (AUTO.LOITER, system status CRITICAL, not
    the POSCTL of PX4's offboard loss) are called "left" before PX4's LAND and never re-engaged."""
    sitl_dir = require_sitl("px4")
    from mission.sim.sitl_fleet import SitlFleet, SitlFleetConfig
    from mission.sim.sitl_plan import seeker_settings, write_plan

    # the seek must outlast both failsafes (it converged 24 s in, before PX4's battery failsafe
    # acted): a convergence window longer than the iteration cap; with 3 left it ends anyway
    seeking = dict(_SEEKING, convergence_window=400, region_hold=0, max_iterations=300, **seeker_settings("model"))
    zenoh = f"tcp/127.0.0.1:{_free_tcp_port()}"
    cfg = SitlFleetConfig(flavour="px4", n=5, sitl_dir=sitl_dir, speedup=_FAILSAFE_SPEEDUP,
                          params=_FAILSAFE_PARAMS).free()
    log_dir = tmp_path / "logs"
    with SitlFleet(cfg) as fleet, GcsListener(14550 + cfg.port_offset, [v.sysid for v in fleet.vehicles]) as gcs:
        bat_v, fence_v = fleet.vehicles[2], fleet.vehicles[3]
        plan = write_plan(tmp_path / "plan.toml", fleet.vehicles, fleet.origin, flavour="px4", zenoh_endpoint=zenoh,
                          speedup=_FAILSAFE_SPEEDUP, overrides={"seeking": seeking})
        with FlyRun(fleet, plan, log_dir, _SOURCE, zenoh=zenoh, noise=_NOISE) as run:
            run.wait_for(lambda recs: len(_iterations(recs)) >= 2, 300.0, "seek iteration 2")
            battery = _px4_failsafe(run, gcs, fleet, bat_v, "SIM_BAT_MIN_PCT", _BATTERY_MIN_PCT)
            run.wait_for(lambda recs: [r for r in _iterations(recs) if r["t_s"] > battery["lost"]["t_s"]], 180.0,
                         "an iteration with 4 vehicles after the battery failsafe")
            fence = _px4_failsafe(run, gcs, fleet, fence_v, "GF_MAX_VER_DIST", _FENCE_MAX_VER_M)
            status = run.wait_end(600.0)
            output, summary = run.output(), run.summary()
        _wait_down(gcs, [v.sysid for v in fleet.vehicles], 240.0)
        after = {ev["lost"]["sysid"]: [(m, a) for _, m, a in gcs.modes(ev["lost"]["sysid"], ev["t_mode"])]
                 for ev in (battery, fence)}
        final = {v.sysid: gcs.state(v.sysid) for v in fleet.vehicles}
    figures = {name: {k: ev[k] for k in ("mode", "reaction_s", "detect_s", "modes_before", "battery_pct", "px4_texts")}
               | {"latency_s": ev["lost"]["latency_s"], "reason": ev["lost"]["reason"],
                  "modes_after": after[ev["lost"]["sysid"]]} for name, ev in (("battery", battery), ("fence", fence))}
    figures.update(exit=status, outcome=summary and summary["outcome"], iterations=len(_iterations(run.records())))
    print("PX4 SIH battery + geofence:", json.dumps(figures))
    assert status == _EXIT_VEHICLE_LOST, (status, output)
    assert summary is not None and summary["outcome"] == "too_few_vehicles", (summary, output)
    assert sorted(e["sysid"] for e in summary["lost"]) == sorted([bat_v.sysid, fence_v.sysid]), summary["lost"]
    assert summary.get("airborne_left", []) == [] and summary.get("still_armed", []) == [], summary
    for ev in (battery, fence):
        assert ev["lost"]["reason"] == "left", figures  # PX4's own failsafe: "left"
        # it ended in its own landing: LAND while armed last, then disarmed
        armed = [m for m, a in after[ev["lost"]["sysid"]] if a]
        assert armed and armed[-1] == "LAND", figures
    assert battery["mode"] in _FAILSAFE_MODES and fence["mode"] == "LAND", figures
    assert any("re-forming for 4" in r.get("message", "") for r in run.records("event")), "no re-formation for 4"
    for sysid, st in final.items():
        assert st.get("armed") is False and abs(st.get("alt", 99.0)) < 1.0, (sysid, st)
    audit = _audit(log_dir)
    assert audit.returncode == 0, (audit.stdout[-3000:] + audit.stderr[-2000:] + "\n"
                                   + audit_failure_context(log_dir))
    assert ("OFFBOARD", True) not in after[battery["lost"]["sysid"]], figures  # the battery one: never fought
    if ("OFFBOARD", True) in after[fence["lost"]["sysid"]]:
        raise FoughtPx4Failsafe(f"OFFBOARD re-engaged during PX4's geofence failsafe: {figures['fence']}")
