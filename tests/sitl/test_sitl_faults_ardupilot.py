"""Faults on real ArduCopter SITL, in one whole mission: the ground station killed and resumed, a
battery failsafe, a breach of the autopilot's own geofence.

Five ArduCopter 4.7 SITL instances (:class:`mission.sim.sitl_fleet.SitlFleet`, instance numbers
and ports picked free on the host; ``SWARMSEEK_ARDUPILOT_SITL``; skipped by name without it, a
failure under ``CI=true``), speed-up ``AP_SPEEDUP``, one ``swarmseek sensor`` per vehicle,
``swarmseek fly --json`` in its own process. The faults, one after the other (they do not
interfere, and one SITL start-up serves all three):

1. **the ground station killed** (SIGKILL) after the second seek iteration, then ``swarmseek
   resume LOG`` (``FS_GCS_TIMEOUT`` long enough for it to start: the vehicles hold in GUIDED
   meanwhile): every vehicle re-engaged in the air, no new takeoff, the seek goes on numbering
   iterations on;
2. **low battery** through the SITL's simulated battery: ``SIM_BATT_VOLTAGE`` set to 9.5 V on one
   vehicle (PARAM_SET from the test, on the vehicle's own port) with ``BATT_LOW_VOLT`` 10.5 V and
   ``BATT_FS_LOW_ACT`` 1 (land): ArduCopter switches to LAND after ``BATT_LOW_TIMER``; the ground
   station must call it "left", stop commanding it (its mode never goes back to GUIDED), re-form
   for four and go on (another iteration);
3. **its own geofence**: ``FENCE_ENABLE`` 1 (altitude and circle) from boot with a high ceiling,
   then ``FENCE_ALT_MAX`` 10 m set mid-seek on another vehicle flying 13-17 m up: ArduCopter
   breaches and flies RTL (``FENCE_ACTION`` 1); the ground station calls it "left", three remain:
   the seek ends ``too_few_vehicles`` and the three come home and land.

Checked at the end: the outcome, exit status, every vehicle disarmed on the ground (read from its
own port), the battery vehicle landed in LAND, the fence vehicle in RTL, and ``swarmseek audit``
of the whole log (both sessions). Printed: the autopilot's reaction time and the ground station's
detection latency of each failsafe (wall seconds).

Run alone: ``SWARMSEEK_ARDUPILOT_SITL=../shared/sitl/ardupilot python -m pytest -n 0 -s
tests/sitl/test_sitl_faults_ardupilot.py``.
"""
from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.sitl.ap_fault_support import COPTER_MODES, VehicleWatch, stop_procs, watch_connection
from tests.support.gcs_fault_support import records
from tests.support.sitl_support import audit_failure_context, require_sitl
from tests.support.wait_helpers import wait_until

_N = 5
#: simulation speed-up of the SITL instances (wall clock for the ground station)
AP_SPEEDUP = float(os.environ.get("SWARMSEEK_TEST_AP_SPEEDUP", "3"))
_NOISE = 0.005
_SOURCE = (8.0, 36.0, 14.0)
#: simulated seconds without a GCS heartbeat before ArduCopter lands (FS_GCS_ENABLE 5): ArduCopter's
#: maximum, 40 wall seconds at speed-up 3 (more on a loaded host, whose SITL lags) for ``resume`` to
#: start and reconnect (it took 1-6 s here)
_FS_GCS_TIMEOUT_S = 120.0
#: wall seconds for ``fly`` to start, pass its preflight (the EKFs) and assemble on a loaded host
_START_TIMEOUT_S = 300.0
_PARAMS = {
    "FS_GCS_TIMEOUT": _FS_GCS_TIMEOUT_S,
    "BATT_LOW_VOLT": 10.5, "BATT_FS_LOW_ACT": 1,  # land; BATT_MONITOR 4 (copter.parm), 12.6 V simulated
    "FENCE_ENABLE": 1, "FENCE_TYPE": 3, "FENCE_ALT_MAX": 100.0, "FENCE_ACTION": 1,  # altitude + circle, RTL
}
_LOW_VOLTAGE_V = 9.5
_FENCE_CEILING_M = 10.0
_GUIDED, _RTL, _LAND = 4, 6, 9


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _cli(*args) -> list[str]:
    return [sys.executable, "-m", "mission", *args]


def _spawn(argv, out_path: Path) -> subprocess.Popen:
    with open(out_path, "wb") as out:
        return subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)


def _sensors(fleet, zenoh_port: int, log_dir: Path) -> list[subprocess.Popen]:
    lat, lon, alt = fleet.origin
    return [_spawn(_cli("sensor", "--connect", v.sensor_connection, "--sysid", str(v.sysid), "--fleet", "sitl",
                        "--field", "sigma2", "--source=" + ",".join(map(str, _SOURCE)),
                        f"--origin={lat},{lon},{alt}", "--noise", str(_NOISE), "--seed", str(v.sysid),
                        "--zenoh-connect", f"tcp/127.0.0.1:{zenoh_port}", "--quiet"),
                   log_dir / f"sensor{v.sysid}.log") for v in fleet.vehicles]


class _Mission:
    """The mission log of ``fly`` then ``resume``, read while it is written."""

    def __init__(self, log: Path):
        self.log = log
        self.proc: subprocess.Popen | None = None

    def recs(self) -> list[dict]:
        return records(self.log)

    def iterations(self) -> list[dict]:
        return [r for r in self.recs() if r["type"] == "iteration"]

    def lost(self, sysid: int) -> dict | None:
        return next((r for r in self.recs() if r["type"] == "event"
                     and r.get("message", "").startswith(f"vehicle {sysid} lost:")), None)

    def wait(self, predicate, what: str, timeout_s: float = 180.0):
        """Wait for ``predicate()`` while the current process runs (fails if it exits first)."""
        value = wait_until(lambda: predicate() or self.proc.poll() is not None, timeout_s, what, poll_s=0.05)
        assert self.proc.poll() is None, f"{self.proc.args[3]} exited ({self.proc.returncode}) before {what}"
        return value


def _inject(m: _Mission, watch: VehicleWatch, name: str, value: float, modes: set[int]) -> dict:
    """Set ``name`` on the vehicle; wait for its failsafe mode and the ground station's loss event.
    Returns the figures (wall seconds) and the loss event."""
    t_set = watch.set_param(name, value)
    t_mode = m.wait(lambda: watch.first_mode_after(t_set, modes), f"vehicle {watch.sysid} in {modes}", 120.0)
    lost = m.wait(lambda: m.lost(watch.sysid), f"the loss of vehicle {watch.sysid}", 60.0)
    return {"reaction_s": t_mode - t_set, "detect_s": lost["t_s"] - t_mode, "latency_s": lost["latency_s"],
            "mode": COPTER_MODES.get(next(md for t, md, _ in watch.snapshot()[0] if t >= t_mode), "?"),
            "event": lost, "t_mode": t_mode}


def _kill_and_resume(m: _Mission, out_dir: Path, procs: list) -> dict:
    """SIGKILL ``fly`` after iteration 2; ``resume`` it (added to ``procs`` at once, so that it is
    stopped whatever happens next); wait for a resumed iteration."""
    m.wait(lambda: m.recs(), "fly's first log record", _START_TIMEOUT_S)
    m.wait(lambda: len(m.iterations()) >= 2, "two seek iterations", _START_TIMEOUT_S)
    k_killed = m.iterations()[-1]["k"]
    t_kill = time.time()
    m.proc.send_signal(signal.SIGKILL)
    m.proc.wait(timeout=30)
    fly = m.proc
    m.proc = _spawn(_cli("resume", str(m.log), "--json"), out_dir / "resume.out")
    procs.append(m.proc)
    resumed = m.wait(lambda: next((r for r in m.recs() if r["type"] == "event"
                                   and r.get("message", "").startswith("resumed at iteration")), None),
                     "the resume", _START_TIMEOUT_S)
    m.wait(lambda: any(r["k"] > k_killed for r in m.iterations()), "an iteration after the resume")
    return {"fly": fly, "k_killed": max(r["k"] for r in m.iterations() if r["t_s"] <= t_kill),
            "t_kill": t_kill, "resumed_after_s": resumed["t_s"] - t_kill, "resumed": resumed}


@pytest.mark.slow
@pytest.mark.timeout(1500)
def test_ardupilot_sitl_faults(tmp_path):
    require_sitl("ardupilot")
    from mission.sim.sitl_fleet import SitlFleet, SitlFleetConfig

    cfg = SitlFleetConfig(flavour="ardupilot", n=_N, speedup=AP_SPEEDUP, params=_PARAMS,
                          run_dir=tmp_path / "sitl", ready_timeout_s=180.0).free()
    zenoh_port = _free_port()
    m = _Mission(tmp_path / "logs" / "mission.jsonl")
    t0 = time.monotonic()
    with SitlFleet(cfg) as fleet, contextlib.ExitStack() as stack:
        watches = {v.sysid: stack.enter_context(VehicleWatch(watch_connection(v.sensor_connection), v.sysid))
                   for v in fleet.vehicles}
        plan = fleet.write_plan(tmp_path / "plan.toml", zenoh_endpoint=f"tcp/127.0.0.1:{zenoh_port}",
                                overrides={"preflight": {"autopilot_ready_timeout_s": 180.0}})
        procs: list[subprocess.Popen] = []
        stack.callback(stop_procs, procs)  # runs before the watches close and the fleet stops
        procs += _sensors(fleet, zenoh_port, tmp_path)
        m.proc = _spawn(_cli("fly", "--plan", str(plan), "--log-dir", str(m.log.parent), "--json"),
                        tmp_path / "fly.out")
        procs.append(m.proc)
        kill = _kill_and_resume(m, tmp_path, procs)
        assert sorted(kill["resumed"]["vehicles"]) == sorted(watches), kill["resumed"]["message"]
        battery_id, fence_id = fleet.vehicles[1].sysid, fleet.vehicles[3].sysid
        battery = _inject(m, watches[battery_id], "SIM_BATT_VOLTAGE", _LOW_VOLTAGE_V, {_LAND, _RTL})
        m.wait(lambda: any(r["t_s"] > battery["event"]["t_s"] for r in m.iterations()),
               "an iteration with four vehicles after the battery failsafe")
        fence = _inject(m, watches[fence_id], "FENCE_ALT_MAX", _FENCE_CEILING_M, {_LAND, _RTL})
        status = m.proc.wait(timeout=300)
        wait_until(lambda: all(w.down() for w in watches.values()), 120.0, "every vehicle disarmed on the ground",
                   poll_s=0.2)
        final = {s: (w.snapshot()[0][-1], w.snapshot()[1]) for s, w in watches.items()}
        modes_after = {s: [md for t, md, armed in w.snapshot()[0] if t > ev["t_mode"] and armed]
                       for s, ev in ((battery_id, battery), (fence_id, fence)) for w in [watches[s]]}
    wall_s = time.monotonic() - t0
    out = _json_out(tmp_path / "resume.out")
    print(f"\nArduCopter SITL x{_N} (speed-up {AP_SPEEDUP:g}), test {wall_s:.0f} s wall; "
          f"fly killed after iteration {kill['k_killed']}, resume's first event {kill['resumed_after_s']:.1f} s later; "
          f"battery: {battery['mode']} {battery['reaction_s']:.1f} s after SIM_BATT_VOLTAGE {_LOW_VOLTAGE_V}, seen "
          f"{battery['detect_s']:.2f} s later (latency_s {battery['latency_s']}); fence: {fence['mode']} "
          f"{fence['reaction_s']:.1f} s after FENCE_ALT_MAX {_FENCE_CEILING_M:g}, seen {fence['detect_s']:.2f} s later "
          f"(latency_s {fence['latency_s']}); outcome {out['outcome']} ({out['message']}), exit {status}, "
          f"iterations {out['iterations']}")
    _check(m, out, status, kill, battery, fence, final, modes_after, (battery_id, fence_id))
    audit = subprocess.run(_cli("audit", str(m.log.parent)), capture_output=True, text=True, timeout=300)
    assert audit.returncode == 0, (audit.stdout[-3000:] + audit.stderr[-2000:] + "\n"
                                   + audit_failure_context(m.log.parent))


def _json_out(path: Path) -> dict:
    """The ``--json`` object of ``resume`` (its stdout and stderr share the file: the object is last)."""
    text = path.read_text(errors="replace")
    start = text.rfind("\n{") + 1 if not text.startswith("{") else 0
    try:
        return json.loads(text[start:])
    except ValueError:
        raise AssertionError(f"resume printed no JSON summary:\n{text[-3000:]}") from None


def _check(m: _Mission, out: dict, status: int, kill: dict, battery: dict, fence: dict, final: dict,
           modes_after: dict, ids: tuple[int, int]) -> None:
    battery_id, fence_id = ids
    recs = m.recs()
    assert kill["fly"].returncode == -signal.SIGKILL
    plans = [r for r in recs if r["type"] == "plan"]
    assert len(plans) == 2 and plans[1].get("resumed") is True, [p.get("resumed") for p in plans]
    t_resume = plans[1]["t_s"]
    assert not any(r["type"] == "phase" and r.get("phase") == "takeoff" and r["t_s"] > t_resume for r in recs), \
        "the resume took off again"
    # the failsafes: "left", never fought (the vehicle never back in GUIDED while armed)
    for ev, sysid in ((battery, battery_id), (fence, fence_id)):
        assert ev["event"]["reason"] == "left", ev["event"]
        assert _GUIDED not in modes_after[sysid], (sysid, modes_after[sysid])
    assert battery["mode"] == "LAND" and fence["mode"] in ("RTL", "LAND"), (battery["mode"], fence["mode"])
    assert any(r["type"] == "event" and "re-forming for 4" in r.get("message", "") for r in recs), \
        "no re-formation for 4 after the battery failsafe"
    # three left: the seek ends, the three come home; every vehicle down
    assert out["outcome"] == "too_few_vehicles", out["message"]
    assert status == 4 == out["exit_status"]  # ended with vehicles lost
    # the two failsafe vehicles, and no other for good: on a loaded host one SITL once went silent for
    # 1.06 s, was declared lost and came back (``came_back_s``), which the mission handled
    assert sorted(x["sysid"] for x in out["lost"] if x["came_back_s"] is None) == sorted(ids), out["lost"]
    assert out.get("airborne_left", []) == [] and out.get("still_armed", []) == [], out
    for sysid, ((_, mode, armed), alt_m) in final.items():
        assert not armed and abs(alt_m) < 1.0, (sysid, mode, armed, alt_m)
    assert final[battery_id][0][1] == _LAND, final[battery_id]
    assert final[fence_id][0][1] == _RTL, final[fence_id]  # ArduCopter stays in RTL once landed
