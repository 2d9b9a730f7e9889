"""The ground station killed mid-seek and ``swarmseek resume`` taking over REAL PX4 vehicles (PX4 SIH,
``SWARMSEEK_PX4_SITL``; skipped by name without it, a failure under ``CI=true``).

4 PX4 SIH vehicles at speed-up ``_SPEEDUP``, one ``swarmseek sensor`` per vehicle, ``swarmseek fly``
in its own process (``tests/sitl_px4_fault_support.FlyRun``), PX4's own GCS link listened to
beside the ground station (``GcsListener``). After seek iteration 2 ``fly`` is killed with SIGKILL
(no return, no land: its links just stop); ``swarmseek resume LOG`` is started at once.

What PX4 does meanwhile depends on its parameters, which the preflight reads and reports:
``COM_OBL_RC_ACT`` 5 (hold: AUTO.LOITER after ``COM_OF_LOSS_T`` without setpoints; PX4's default 0,
position mode, descends and lands without RC: docs/faults.md) and ``NAV_DLL_ACT`` 3 (land, the SITL
fleet's default) after ``COM_DL_LOSS_T``, set here to 300 s (simulated, PX4's maximum: 100 wall
seconds at speed-up 3; PX4's start-up script sets it to 10 s x the speed-up, i.e. 10 wall seconds,
and 120 s was 40 wall seconds, less than ``resume`` needed at load 38-40 to start and reconnect,
33-44 s; on a quiet host 4.8 s, docs/faults.md), as the ArduCopter test sets ``FS_GCS_TIMEOUT``.
The preflight of ``fly`` reads and reports it ("on data-link loss (300 s): land").

Asserted: PX4 held (AUTO.LOITER, heard from PX4) after the kill, then the resume re-engaged OFFBOARD:
every vehicle seen holding went back to OFFBOARD, and none showed any other mode or disarmed before
the resumed mission's return (a PX4 may show no hold at all: on a loaded host the resume's setpoints
can come before its offboard-loss hold, or the hold can be shorter than a heartbeat of PX4's GCS
link; at least one must be seen holding); the resume took all 4 in the air (no new takeoff), the
seek went on numbering iterations on and ended by itself (converged, or at its iteration cap), every vehicle landed and disarmed
(PX4's land detector), the summary consistent with the exit status, ``swarmseek audit`` of both
sessions clean. The figures (the resume's delay, PX4's reaction) are printed (``pytest -s``) and
are in docs/faults.md.
"""
from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from tests.sitl.sitl_px4_fault_support import FlyRun, GcsListener
from tests.support.sitl_support import audit_failure_context, require_sitl
from tests.support.wait_helpers import wait_until

_SPEEDUP = 3.0
_N = 4
_SOURCE = (6.0, 12.0, 13.0)
_START = (0.0, 20.0, 15.0)
_NOISE = 0.005
_SEEKING = {"eps": 50.0, "convergence_window": 10, "convergence_tol_m": 0.5, "arrival_tol_m": 0.7,
            "start_enu_m": list(_START), "max_iterations": 40}
#: COM_OBL_RC_ACT 5: hold on offboard loss (PX4 SIH's default 0 descends and lands without RC)
_PARAMS = {"COM_OBL_RC_ACT": 5}
#: simulated seconds without a ground-station heartbeat before PX4 lands (NAV_DLL_ACT 3): PX4's maximum
_DL_LOSS_T_S = 300
_ON_GROUND = 1  # MAV_LANDED_STATE_ON_GROUND
#: PX4's hold (AUTO.LOITER) as pymavlink's mode_string_v10 names it
_HOLD = "LOITER"


def _free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _set_param(fleet, v, name: str, value) -> None:
    done = subprocess.run([str(fleet.run_dir / "px4-bin" / "px4-param"), "--instance", str(v.instance),
                           "set", name, str(value)], capture_output=True, text=True, timeout=30)
    assert done.returncode == 0, done.stdout + done.stderr


def _kill_and_resume(run: FlyRun) -> dict:
    """SIGKILL ``fly`` after iteration 2; start ``resume`` in its place (``run.fly``: stopped by the
    run's exit whatever happens next); wait for its first iteration."""
    def two_iterations(rs):
        its = [r for r in rs if r["type"] == "iteration"]
        return its if len(its) >= 2 else None

    iterations = run.wait_for(two_iterations, 600.0, "two seek iterations")  # 220 s to the seek at load 58
    k_killed = iterations[-1]["k"]
    t_kill = time.time()
    run.fly.send_signal(signal.SIGKILL)
    fly_status = run.fly.wait(timeout=30)
    with open(run.log_dir.with_suffix(".stdout"), "ab") as out, open(run.log_dir.with_suffix(".stderr"), "ab") as err:
        run.fly = subprocess.Popen([sys.executable, "-m", "mission", "resume", str(run.log), "--json"],
                                   stdout=out, stderr=err, start_new_session=True)
    resumed = run.wait_for(lambda rs: next((r for r in rs if r["type"] == "event" and
                                            r.get("message", "").startswith("resumed at iteration")), None),
                           300.0, "the resume")
    run.wait_for(lambda rs: any(r["type"] == "iteration" and r["k"] > k_killed and r["t_s"] > t_kill for r in rs),
                 300.0, "an iteration after the resume")
    return {"fly_status": fly_status, "t_kill": t_kill, "resumed": resumed,
            "k_killed": max(r["k"] for r in run.records("iteration") if r["t_s"] <= t_kill)}


def _json_out(run: FlyRun) -> dict:
    text = run.log_dir.with_suffix(".stdout").read_text(errors="replace")
    start = text.rfind("\n{") + 1 if not text.startswith("{") else 0
    try:
        return json.loads(text[start:])
    except ValueError:
        raise AssertionError(f"resume printed no JSON summary:\n{run.output()}") from None


@pytest.mark.slow
@pytest.mark.extra_sitl  # the ground station killed and resumed: flown on real ArduCopter by default (test_sitl_faults_ardupilot.py)
@pytest.mark.timeout(1200)
def test_px4_gcs_killed_and_resumed(tmp_path):
    sitl_dir = require_sitl("px4")
    from mission.sim.sitl_fleet import SitlFleet, SitlFleetConfig
    from mission.sim.sitl_plan import seeker_settings

    zenoh = f"tcp/127.0.0.1:{_free_tcp_port()}"
    cfg = SitlFleetConfig(flavour="px4", n=_N, sitl_dir=sitl_dir, speedup=_SPEEDUP, params=_PARAMS).free()
    log_dir = tmp_path / "logs"
    t_test = time.monotonic()
    with SitlFleet(cfg) as fleet, GcsListener(14550 + cfg.port_offset, [v.sysid for v in fleet.vehicles]) as gcs:
        for v in fleet.vehicles:
            _set_param(fleet, v, "COM_DL_LOSS_T", _DL_LOSS_T_S)
        plan = fleet.write_plan(tmp_path / "plan.toml", zenoh_endpoint=zenoh,
                                overrides={"seeking": dict(_SEEKING, **seeker_settings("model"))})
        with FlyRun(fleet, plan, log_dir, _SOURCE, zenoh=zenoh, noise=_NOISE) as run:
            kill = _kill_and_resume(run)
            status = run.wait_end(600.0)
            records = run.records()
        wait_until(lambda: all(gcs.down(v.sysid) for v in fleet.vehicles), 120.0,
                   "every vehicle disarmed on the ground (PX4's land detector)", poll_s=0.2)
        modes = {v.sysid: gcs.modes(v.sysid, kill["t_kill"]) for v in fleet.vehicles}
        final = {v.sysid: gcs.state(v.sysid) for v in fleet.vehicles}
        texts = {v.sysid: [(round(t - kill["t_kill"], 2), x) for t, x in gcs.statustexts(v.sysid, kill["t_kill"] - 5.0)]
                 for v in fleet.vehicles}
    out = _json_out(run)
    t_resumed = kill["resumed"]["t_s"]
    hold_s = {s: next((t - kill["t_kill"] for t, m, _ in ms if m == _HOLD), None) for s, ms in modes.items()}
    error_m = float(np.linalg.norm(np.asarray(out["estimate_enu"]) - np.asarray(_SOURCE))) \
        if out.get("estimate_enu") else None
    print("\nPX4 SIH x4 GCS killed + resume:", json.dumps({
        "speedup": _SPEEDUP, "k_killed": kill["k_killed"], "resumed_after_s": round(t_resumed - kill["t_kill"], 2),
        "px4_hold_after_kill_s": {s: h and round(h, 2) for s, h in hold_s.items()}, "outcome": out["outcome"],
        "exit": status, "iterations": out["iterations"], "error_m": error_m and round(error_m, 3),
        "test_wall_s": round(time.monotonic() - t_test)}))
    dl_loss_wall_s = _DL_LOSS_T_S / _SPEEDUP
    assert t_resumed - kill["t_kill"] < dl_loss_wall_s, (
        f"the resume re-engaged {t_resumed - kill['t_kill']:.1f} s after the kill, later than PX4's data-link-loss "
        f"timeout ({_DL_LOSS_T_S} s at speed-up {_SPEEDUP:g}: {dl_loss_wall_s:.0f} wall s): PX4 landed meanwhile")
    _check(records, out, status, kill, modes, final, texts)
    audit = subprocess.run([sys.executable, "-m", "mission", "audit", str(log_dir)], capture_output=True, text=True,
                           timeout=300)
    assert audit.returncode == 0, (audit.stdout[-3000:] + audit.stderr[-2000:] + "\n" + audit_failure_context(log_dir))


def _check(records: list, out: dict, status: int, kill: dict, modes: dict, final: dict, texts: dict) -> None:
    """The mission's checks; a vehicle's failure names its modes and what PX4 said (``texts``:
    ``(seconds after the kill, STATUSTEXT)`` from 5 s before the kill on)."""
    assert kill["fly_status"] == -signal.SIGKILL
    assert sorted(kill["resumed"]["vehicles"]) == sorted(modes), kill["resumed"]["message"]
    plans = [r for r in records if r["type"] == "plan"]
    assert len(plans) == 2 and plans[1].get("resumed") is True, [p.get("resumed") for p in plans]
    t_resume = plans[1]["t_s"]
    assert not any(r["type"] == "phase" and r.get("phase") == "takeoff" and r["t_s"] > t_resume for r in records), \
        "the resume took off again"
    t_return = min((r["t_s"] for r in records if r["type"] == "phase" and r.get("phase") == "return"
                    and r["t_s"] > t_resume), default=float("inf"))
    held = []
    for sysid, ms in modes.items():
        # until the resumed mission's return (whose LAND is the normal landing): PX4 held by itself
        # while no ground station streamed, then the resume re-engaged OFFBOARD; or PX4 stayed in
        # OFFBOARD (the resume's setpoints came before its offboard-loss hold, or the hold was
        # shorter than a heartbeat of PX4's GCS link on a loaded host: seen in the whole suite)
        names = [m for t, m, _ in ms if t < t_return]
        said = f"vehicle {sysid}: modes {ms}; PX4 said {texts.get(sysid)}"
        assert set(names) <= {_HOLD, "OFFBOARD"}, said
        if _HOLD in names:
            held.append(sysid)
            assert "OFFBOARD" in names[names.index(_HOLD):], said
        assert all(armed for t, m, armed in ms if t < t_return), said  # nobody landed meanwhile
    assert held, f"no PX4 was seen holding after the kill: {modes}"
    assert out["lost"] == [] and out["airborne_left"] == [] and out.get("still_armed", []) == [], out
    assert out["outcome"] in ("converged", "max_iterations"), out["message"]
    assert status == (0 if out["outcome"] == "converged" else 1) == out["exit_status"], (status, out["outcome"])
    for sysid, st in final.items():
        assert st.get("armed") is False and st.get("landed_state") == _ON_GROUND, (sysid, st)
