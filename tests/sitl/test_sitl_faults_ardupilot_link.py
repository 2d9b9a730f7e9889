"""Faults on real ArduCopter SITL, two whole ``swarmseek fly`` missions: one vehicle's link cut both
ways and restored; one vehicle that never arms.

ArduCopter 4.7 SITL instances (:class:`mission.sim.sitl_fleet.SitlFleet`, instance numbers and ports
picked free; ``SWARMSEEK_ARDUPILOT_SITL``; skipped by name without it, a failure under ``CI=true``),
speed-up ``AP_SPEEDUP``, one ``swarmseek sensor`` per vehicle, ``swarmseek fly --json`` in its own
process; each vehicle watched on its own spare port (SERIAL2, :class:`ap_fault_support.VehicleWatch`).

* ``test_ardupilot_link_cut_and_restored`` (6 vehicles, ``[faults] readmit = true``): the ground
  station reaches vehicle 3 through a TCP relay (``tests/sitl/ap_tcp_relay.py``, its own process) that
  drops every byte both ways after seek iteration 2, until ArduCopter has left GUIDED by itself and
  the ground station has declared the loss; then forwards again. Once vehicle 3 is declared lost,
  the ArduCopter process of the last vehicle still in the formation is killed (SIGKILL of its
  process group: an autopilot that dies in the air); it must be declared lost too and reported
  airborne. The failsafe parameters are the
  ones the preflight checks and reports (``FS_GCS_ENABLE`` 5 (land) and ``FS_GCS_TIMEOUT`` 10 s x
  the speed-up, the SITL fleet's defaults; the other vehicles get 120 s: a loaded host stalls the
  ground station's heartbeats for seconds, and the test is about the cut one). Asserted: lost (``link``) after the cut; ArduCopter
  switched to LAND (never back to GUIDED while armed); heard again: kept out (in LAND: not
  re-admissible), never re-admitted; the killed one lost (``link``) after the kill and left airborne
  (``airborne_left``, exit 5: a vehicle unaccounted for); the mission goes on with 4 and ends by
  itself; every other vehicle disarmed on the ground, the cut one in LAND; summary consistent with
  the exit status; ``swarmseek audit`` clean.
* ``test_ardupilot_vehicle_that_never_arms`` (4 vehicles, 3 s between takeoffs): when ``fly``
  enters its takeoff phase, the last vehicle of the takeoff order gets ``BATT_ARM_VOLT`` 13 V
  (the simulated pack gives 12.6 V): ArduCopter refuses to arm it ("below minimum arming
  voltage"). Asserted: it never armed; lost (``failed``) with ArduCopter's words after
  ``[preflight] autopilot_ready_timeout_s``; 3 left before the assembly: ``aborted``, exit 1; the 3 others
  landed and disarmed, nothing left airborne or armed; ``swarmseek audit`` clean.

The figures are printed (``pytest -s``) and are in docs/faults.md. Run alone:
``CI=true SWARMSEEK_ARDUPILOT_SITL=../shared/sitl/ardupilot python -m pytest -n 0 -s
tests/sitl/test_sitl_faults_ardupilot_link.py``.
"""
from __future__ import annotations

import contextlib
import dataclasses
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
from tests.sitl.ap_tcp_relay import TcpRelay
from tests.support.gcs_fault_support import records
from tests.support.sitl_support import audit_failure_context, require_sitl
from tests.support.wait_helpers import wait_until

#: simulation speed-up of the SITL instances (wall clock for the ground station)
AP_SPEEDUP = float(os.environ.get("SWARMSEEK_TEST_AP_SPEEDUP", "3"))
_SOURCE = (8.0, 36.0, 14.0)
_NOISE = 0.005
#: wall seconds for ``fly`` to start, pass its preflight and assemble on a loaded host
_START_TIMEOUT_S = 480.0
_LAND, _RTL = 9, 6
#: ArduCopter refuses to arm below this pack voltage; its simulated pack gives 12.6 V
_ARM_VOLT_V = 13.0
#: ArduCopter's maximum FS_GCS_TIMEOUT (simulated s), set where the GCS failsafe is not under test:
#: on a host at load 25 the ground station's heartbeats stopped for over 10 wall seconds
_FS_GCS_TIMEOUT_MAX_S = 120.0
#: the arming refusals are retried this long (wall seconds): also preflight's wait for the EKFs
_READY_TIMEOUT_S = 30.0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _cli(*args) -> list[str]:
    return [sys.executable, "-m", "mission", *args]


def _spawn(argv, out_path: Path) -> subprocess.Popen:
    with open(out_path, "wb") as out:
        return subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)


class _Run:
    """The SITL fleet's sensors and ``fly`` (each its own process, stopped at the end pass or fail),
    the vehicles' watches, and the mission log read while it is written."""

    def __init__(self, fleet, tmp_path: Path, stack: contextlib.ExitStack):
        self.fleet, self.tmp = fleet, tmp_path
        self.log = tmp_path / "logs" / "mission.jsonl"
        self.zenoh = f"tcp/127.0.0.1:{_free_port()}"
        self.watches = {v.sysid: stack.enter_context(VehicleWatch(watch_connection(v.sensor_connection), v.sysid))
                        for v in fleet.vehicles}
        self.procs: list[subprocess.Popen] = []
        stack.callback(stop_procs, self.procs)  # before the watches close and the fleet stops
        self.fly: subprocess.Popen | None = None

    def start(self, vehicles, overrides: dict) -> None:
        """Sensors for every vehicle, then ``fly`` on a plan for ``vehicles`` (their connections)."""
        from mission.sim.sitl_plan import write_plan

        lat, lon, alt = self.fleet.origin
        for v in self.fleet.vehicles:
            self.procs.append(_spawn(_cli(
                "sensor", "--connect", v.sensor_connection, "--sysid", str(v.sysid), "--fleet", "sitl",
                "--field", "sigma2", "--source=" + ",".join(map(str, _SOURCE)), f"--origin={lat},{lon},{alt}",
                "--noise", str(_NOISE), "--seed", str(v.sysid), "--zenoh-connect", self.zenoh, "--quiet"),
                self.tmp / f"sensor{v.sysid}.log"))
        plan = write_plan(self.tmp / "plan.toml", vehicles, self.fleet.origin, flavour="ardupilot",
                          zenoh_endpoint=self.zenoh, overrides=overrides, speedup=self.fleet.config.speedup)
        self.fly = _spawn(_cli("fly", "--plan", str(plan), "--log-dir", str(self.log.parent), "--json"),
                          self.tmp / "fly.out")
        self.procs.append(self.fly)

    def recs(self) -> list[dict]:
        return records(self.log)

    def events(self, prefix: str = "") -> list[dict]:
        return [r for r in self.recs() if r["type"] == "event" and r.get("message", "").startswith(prefix)]

    def wait(self, predicate, what: str, timeout_s: float = 180.0):
        """Wait for ``predicate()`` while ``fly`` runs (fails naming ``what`` if it exits first)."""
        value = wait_until(lambda: predicate() or self.fly.poll() is not None, timeout_s, what, poll_s=0.05)
        assert self.fly.poll() is None, f"fly exited ({self.fly.returncode}) before {what}:\n{self.output()}"
        return value

    def finish(self, timeout_s: float = 400.0, dead=()) -> tuple[int, dict]:
        """``fly``'s exit status and ``--json`` summary; then every vehicle disarmed on the ground,
        but those in ``dead`` (system ids whose autopilot process the test killed)."""
        status = self.fly.wait(timeout=timeout_s)
        text = self.output()
        try:
            out = json.loads(text[text.rfind("\n{") + 1 if not text.startswith("{") else 0:])
        except ValueError:
            raise AssertionError(f"fly printed no JSON summary:\n{text[-3000:]}") from None
        wait_until(lambda: all(w.down() for s, w in self.watches.items() if s not in dead), 180.0,
                   "every vehicle disarmed on the ground", poll_s=0.2)
        return status, out

    def output(self) -> str:
        return (self.tmp / "fly.out").read_text(errors="replace")

    def audit(self) -> None:
        audit = subprocess.run(_cli("audit", str(self.log.parent)), capture_output=True, text=True, timeout=300)
        assert audit.returncode == 0, (audit.stdout[-3000:] + audit.stderr[-2000:] + "\n"
                                       + audit_failure_context(self.log.parent))


def _fleet(tmp_path: Path, n: int, params: dict | None = None):
    from mission.sim.sitl_fleet import SitlFleet, SitlFleetConfig

    cfg = SitlFleetConfig(flavour="ardupilot", n=n, speedup=AP_SPEEDUP, params=params or {},
                          run_dir=tmp_path / "sitl", ready_timeout_s=180.0).free()
    return SitlFleet(cfg)


def _armed_modes_after(watch: VehicleWatch, t0: float) -> list[str]:
    return [COPTER_MODES.get(md, str(md)) for t, md, armed in watch.snapshot()[0] if t > t0 and armed]


@pytest.mark.slow
@pytest.mark.extra_sitl  # 76-84 CPU s: out of the default suite for CI's budget (docs/testing.md); real PX4's
# link-loss failsafe stays in it (tests/conformance/test_conformance_px4_failsafes.py), the mock's link cut too
@pytest.mark.timeout(1200)
def test_ardupilot_link_cut_and_restored(tmp_path):
    require_sitl("ardupilot")
    t_test = time.monotonic()
    with _fleet(tmp_path, 6) as fleet, contextlib.ExitStack() as stack:
        cut_v = fleet.vehicles[2]
        relay = stack.enter_context(TcpRelay(int(cut_v.connection.rsplit(":", 1)[1])))
        run = _Run(fleet, tmp_path, stack)
        for v in fleet.vehicles:  # the others must not land if a loaded host stalls the ground station
            if v is not cut_v:
                # (60 s: the echo took over 20 s with four xdist workers on 2 cores)
                run.watches[v.sysid].set_param("FS_GCS_TIMEOUT", _FS_GCS_TIMEOUT_MAX_S, timeout_s=60.0)
        vehicles = [dataclasses.replace(v, connection=relay.connection) if v is cut_v else v for v in fleet.vehicles]
        # the SITL plan's radius, 2 m: the 4 others' re-formation around the lost vehicle deadlocked in
        # the separation hold in 2 of 2 runs before held vehicles were moved aside (docs/faults.md)
        run.start(vehicles, {"faults": {"readmit": True}, "seeking": {"max_iterations": 15},
                             "preflight": {"autopilot_ready_timeout_s": 180.0}})
        run.wait(lambda: sum(r["type"] == "iteration" for r in run.recs()) >= 2, "two seek iterations",
                 _START_TIMEOUT_S)
        watch, sysid = run.watches[cut_v.sysid], cut_v.sysid
        t_cut = time.time()
        relay.cut(True)
        lost = run.wait(lambda: next(iter(e for e in run.events(f"vehicle {sysid} lost:") if e["t_s"] >= t_cut),
                                         None), "the loss", 120.0)
        # the autopilot killed: one in the formation now (on a loaded host one can have been lost and
        # re-admitted in the takeoff: not that one)
        kill_v = next(v for v in reversed(fleet.vehicles) if v is not cut_v
                      and not run.events(f"vehicle {v.sysid} lost:"))
        t_kill = time.time()
        os.killpg(kill_v.pid, signal.SIGKILL)  # the autopilot dies in the air
        killed = run.wait(lambda: next(iter(e for e in run.events(f"vehicle {kill_v.sysid} lost:")
                                            if e["t_s"] > t_kill), None), "the killed vehicle's loss", 120.0)
        t_fs = run.wait(lambda: watch.first_mode_after(t_cut, {_LAND, _RTL}), "ArduCopter's own failsafe", 120.0)
        t_restore = time.time()
        relay.cut(False)
        back = run.wait(lambda: next((e for e in run.events(f"vehicle {sysid} is heard again")), None),
                        "the vehicle heard again", 120.0)
        status, out = run.finish(dead=(kill_v.sysid,))
        final = {s: w.snapshot() for s, w in run.watches.items() if s != kill_v.sysid}
        # the killed autopilot's own port closed: its process is gone (the watch's last heartbeat is
        # stamped when its thread parsed it, seconds late on a loaded host, so not compared with the loss)
        killed_port_closed = run.watches[kill_v.sysid].port_closed.wait(60.0)
        events = run.events()
        failsafe_events = [e["message"] for e in events if "if the ground station dies" in e["message"]]
        armed_after = _armed_modes_after(watch, t_fs)
    relay_counts = relay.counts
    print(f"\nArduCopter SITL x6 (speed-up {AP_SPEEDUP:g}) link cut: ArduCopter "
          f"{COPTER_MODES.get(next(md for t, md, _ in final[sysid][0] if t >= t_fs), '?')} {t_fs - t_cut:.2f} s after "
          f"the cut; lost {lost['t_s'] - t_cut:.2f} s after the cut (latency_s {lost['latency_s']}); restored "
          f"{t_restore - t_cut:.2f} s after the cut, heard again {back['t_s'] - t_restore:.2f} s later: "
          f"{back['message']!r}; killed vehicle {kill_v.sysid} lost {killed['t_s'] - t_kill:.2f} s after the kill "
          f"(latency_s {killed['latency_s']}); outcome {out['outcome']}, exit {status}, iterations "
          f"{out['iterations']}; failsafe reported: {failsafe_events}; relay {relay_counts}; "
          f"test {time.monotonic() - t_test:.0f} s wall")
    assert lost["reason"] == "link" and lost["t_s"] >= t_cut, lost
    assert killed["reason"] == "link" and killed["t_s"] > t_kill, killed
    assert killed_port_closed, "the killed autopilot's port stayed open"
    # the ground station never heard the killed autopilot again
    assert not [e for e in events if f"vehicle {kill_v.sysid} is heard again" in e["message"]], events
    assert "kept out" in back["message"], back["message"]  # in LAND: not re-admissible
    assert "GUIDED" not in armed_after, armed_after  # its failsafe never fought
    lost_ids, readmitted_ids = {x["sysid"] for x in out["lost"]}, {x["sysid"] for x in out["readmitted"]}
    # any other loss was a loaded host's frame gap, healed by a re-admission
    assert {sysid, kill_v.sysid} <= lost_ids and lost_ids - {sysid, kill_v.sysid} <= readmitted_ids, out["lost"]
    assert not readmitted_ids & {sysid, kill_v.sysid}, out["readmitted"]
    # the dead autopilot cannot be landed: reported loudly, and the exit status says so
    assert [x["sysid"] for x in out["airborne_left"]] == [kill_v.sysid], out["airborne_left"]
    assert out["outcome"] in ("converged", "max_iterations"), out["message"]
    assert status == 5 == out["exit_status"], (status, out["outcome"])  # a vehicle unaccounted for
    # the mission went on after the vehicle came back: another seek iteration, or (when the seek had
    # just converged or hit its cap, as the model seeker can by then) the next phase
    assert any(r["t_s"] > back["t_s"] for r in records(run.log) if r["type"] in ("iteration", "phase")), \
        "the mission did not go on after the vehicle came back"
    for s, (modes, alt_m) in final.items():
        assert not modes[-1][2] and abs(alt_m) < 1.0, (s, modes[-1], alt_m)
    assert final[sysid][0][-1][1] == _LAND, final[sysid][0][-1]
    assert relay_counts["dropped"]["down"] > 0 and relay_counts["dropped"]["up"] > 0, relay_counts
    run.audit()


@pytest.mark.slow
@pytest.mark.extra_sitl  # arming refused at takeoff: lost, the others go on (on the mock: test_takeoff_loss.py)
@pytest.mark.timeout(1200)
def test_ardupilot_vehicle_that_never_arms(tmp_path):
    require_sitl("ardupilot")
    t_test = time.monotonic()
    with _fleet(tmp_path, 4, {"FS_GCS_TIMEOUT": _FS_GCS_TIMEOUT_MAX_S}) as fleet, contextlib.ExitStack() as stack:
        run = _Run(fleet, tmp_path, stack)
        # 3 wall s between two takeoffs at speed-up 3: room to set the parameter before the last one's turn
        run.start(fleet.vehicles, {"stagger_s": 3.0 * AP_SPEEDUP,
                                   "preflight": {"autopilot_ready_timeout_s": _READY_TIMEOUT_S}})
        layers = run.wait(lambda: next((e["layers"] for e in run.recs() if e.get("layers")), None),
                          "the takeoff layers", _START_TIMEOUT_S)
        last = max(layers, key=lambda s: (layers[s], int(s)))
        bad = int(last)
        watch = run.watches[bad]
        assert not watch.snapshot()[0][-1][2], "the last vehicle of the takeoff order armed already"
        # PARAM_SET every second until ArduCopter refuses to arm it (its echo was missed on a host at
        # load 30, the parameter taken all the same): the refusal is the proof
        sent = [watch.send_param("BATT_ARM_VOLT", _ARM_VOLT_V)]
        t_set = sent[0]

        def refused_or_armed():
            if time.time() - sent[-1] >= 1.0:
                sent.append(watch.send_param("BATT_ARM_VOLT", _ARM_VOLT_V))
            return run.events(f"vehicle {bad}: arming refused") or any(a for _, _, a in watch.snapshot()[0])

        run.wait(refused_or_armed, f"vehicle {bad}'s arming refused", _START_TIMEOUT_S)
        status, out = run.finish()
        lost = next(iter(run.events(f"vehicle {bad} lost:")), None)
        refused = next(iter(e for e in run.events(f"vehicle {bad}: arming refused")), None)
        ever_armed = [t for t, _, armed in watch.snapshot()[0] if armed]
        final = {s: w.snapshot() for s, w in run.watches.items()}
    times = [r["t_s"] for r in records(run.log) if "t_s" in r]
    print(f"\nArduCopter SITL x4 (speed-up {AP_SPEEDUP:g}) vehicle {bad} never arms (BATT_ARM_VOLT {_ARM_VOLT_V:g}): "
          f"refusal {refused and refused['message']!r}; lost {lost and round(lost['t_s'] - t_set, 1)} s after the "
          f"parameter: {lost and lost['message']!r}; outcome {out['outcome']} ({out['message']}), exit {status}; "
          f"mission {max(times) - min(times):.0f} s, test {time.monotonic() - t_test:.0f} s wall")
    assert ever_armed == [], "the vehicle with BATT_ARM_VOLT armed"
    assert refused is not None and "arming voltage" in refused["message"], refused
    assert lost is not None and lost["reason"] == "failed" and "arming refused" in lost["message"], lost
    # 3 left before the assembly: the mission ends (aborted) and brings them home
    assert out["outcome"] == "aborted" and status == 4, (status, out["outcome"], out["message"])  # a vehicle lost
    assert "lost before the formation was assembled: 3 left" in out["message"], out["message"]
    assert [x["sysid"] for x in out["lost"]] == [bad], out["lost"]
    assert out["airborne_left"] == [] and out.get("still_armed", []) == [], out
    others = [s for s in final if s != bad]
    assert all(any(armed for _, _, armed in final[s][0]) for s in others), "the 3 others did not take off"
    for s, (modes, alt_m) in final.items():
        assert not modes[-1][2] and abs(alt_m) < 1.0, (s, modes[-1], alt_m)
    run.audit()
