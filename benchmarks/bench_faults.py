"""Faults survived: whole missions against the mock fleet, one fault each, and what happened.

Each scenario flies the embedded mission (PX4 personality unless said, sigma_2, noise 0.005,
source 8-11 m from the start, mission clock = the fleet's SimClock) with one fault injected
through ``MockFleet.set_fault`` (or a rogue zenoh peer, or the plan), and prints one row:
outcome, the figure that matters (detection latency of a lost vehicle, measured from the
injection on the mission clock; final error ``||estimate - source||``; frames dropped; readings
rejected), iterations and wall time.

Run::

    python benchmarks/bench_faults.py             # every scenario, ~4 min on 2 cores
    python benchmarks/bench_faults.py --only crash,gcs_resume
    python benchmarks/bench_faults.py --json      # the rows as JSON too
"""
from __future__ import annotations

import argparse
import asyncio
import dataclasses
import json
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mission.flight.coordinator import Coordinator  # noqa: E402
from mission.sim.embedded import DEFAULT_ORIGIN, default_eps, embedded_plan, fleet_ports, free_port_block  # noqa: E402
from mission.telemetry.mission_log import MissionLog, read_mission_log  # noqa: E402
from mission.core.plan_types import GeofencePlan
from sitl_mock.fields_gaussian import sigma2
from sitl_mock.fleet import MockFleet  # noqa: E402


class _Injector(threading.Thread):
    """Sets ``(sysid, name, value)`` faults once the log shows ``k`` iterations."""

    def __init__(self, fleet, log_path, schedule):
        super().__init__(daemon=True)
        self.fleet, self.log_path, self.schedule = fleet, log_path, schedule
        self.injected: dict[int, float] = {}
        self.done = threading.Event()

    def run(self):
        for k, sysid, name, value in self.schedule:
            while not self.done.is_set():
                text = self.log_path.read_text() if self.log_path.exists() else ""
                if text.count('"type":"iteration"') >= k:
                    break
                self.fleet.clock.sleep_blocking(0.2)
            if self.done.is_set():
                return
            self.fleet.set_fault(sysid, name, value)
            self.injected[sysid] = self.fleet.clock.time()


class _Rogue(threading.Thread):
    """A zenoh peer publishing bad readings (garbage, unknown vehicle, NaN, late, far away)."""

    def __init__(self, port, fleet_name, clock, origin):
        super().__init__(daemon=True)
        import zenoh

        conf = zenoh.Config()
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
        self.session = zenoh.open(conf)
        self.fleet_name, self.clock, self.origin = fleet_name, clock, origin
        self.stop = threading.Event()
        self.sent = 0

    def _reading(self, sysid, **over):
        from formation.geodesy import enu_to_geodetic

        lat, lon, alt = enu_to_geodetic(np.array([200.0, 200.0, 10.0]), self.origin)
        d = {"schema": "swarmseek.sensor.v1", "fleet": self.fleet_name, "sysid": sysid, "seq": 10**9,
             "time_s": self.clock.time(), "lat_deg": float(lat), "lon_deg": float(lon), "alt_m": float(alt),
             "value": 0.5}
        d.update(over)
        return json.dumps(d).encode()

    def run(self):
        key = f"swarmseek/{self.fleet_name}/vehicle/{{}}/sensor"
        while not self.stop.wait(0.05):  # the intruder's publishing pace
            now = self.clock.time()
            for sysid, payload in ((1, b"\x00garbage"), (42, self._reading(42)),
                                   (3, self._reading(3, value=float("nan"))),
                                   (4, self._reading(4, time_s=now - 3600.0)), (5, self._reading(5))):
                self.session.put(key.format(sysid), payload)
                self.sent += 1

    def close(self):
        self.stop.set()
        self.join(timeout=10)
        self.session.close()


async def _fly(co, stop_after=None):
    if stop_after is None:
        return await co.run()
    co.return_on_interrupt = False
    task = asyncio.get_running_loop().create_task(co.run())
    while co.state.iteration < stop_after and not task.done():
        await co.clock.sleep(0.2)
    task.cancel()
    try:
        await task
    except asyncio.CancelledError:
        pass
    return None


def scenario(name, *, n=6, formation="cvt", estimator=None, speedup=10.0, personality="px4",
             schedule=(), initial=(), source=(8.0, -5.0, 13.0), fence=None, rogue=False, resume_after=None,
             faults=None, max_iterations=120, noise=0.005, radius_m=4.0, convergence_tol_m=0.3):
    """Fly one mission with faults; returns a dict (one table row)."""
    import zenoh

    source = np.asarray(source, dtype=float)
    ports = fleet_ports(n, personality)
    if rogue:
        ports["coordinator_zenoh_port"] = free_port_block(1, kinds=("tcp",))
    fleet = MockFleet(n=n, personality=personality, field=sigma2(source), origin=DEFAULT_ORIGIN,
                      speedup=speedup, seed=4, udp_base_port=ports["udp_base_port"],
                      udp_bind_base_port=ports["udp_bind_base_port"], tcp_base_port=ports["tcp_base_port"],
                      zenoh_listen=[f"tcp/127.0.0.1:{ports['zenoh_port']}"], sensor_noise_std=noise)
    for sysid, fname, value in initial:
        for s in (range(1, n + 1) if sysid == "all" else (sysid,)):
            fleet.set_fault(s, fname, value)
    plan = embedded_plan(n, ports, personality=personality, formation=formation, estimator=estimator,
                         start_enu_m=(0.0, 0.0, 11.0), eps=default_eps(sigma2(source)), max_iterations=max_iterations,
                         radius_m=radius_m, convergence_tol_m=convergence_tol_m)
    if faults is not None:
        plan = dataclasses.replace(plan, faults=dataclasses.replace(plan.faults, **faults))
    if fence is not None:
        plan = dataclasses.replace(plan, geofence=GeofencePlan(polygon_en_m=fence, min_alt_m=2.0, max_alt_m=40.0))
    if rogue:
        plan = dataclasses.replace(plan, zenoh=dataclasses.replace(
            plan.zenoh, listen=(f"tcp/127.0.0.1:{ports['coordinator_zenoh_port']}",)))
    tmp = Path(tempfile.mkdtemp(prefix="bench_faults_"))
    log_path = tmp / "mission.jsonl"
    inj = _Injector(fleet, log_path, list(schedule))
    t0 = time.perf_counter()
    fleet.start()
    inj.start()
    intruder = None
    try:
        if rogue:
            intruder = _Rogue(ports["coordinator_zenoh_port"], plan.fleet, fleet.clock, plan.origin)
            intruder.start()

        async def _main():
            session = zenoh.open(plan.zenoh.to_config())
            log = MissionLog(log_path, fleet.clock)
            try:
                co = Coordinator(plan, clock=fleet.clock, zenoh_session=session, log=log)
                return await _fly(co, stop_after=resume_after)
            finally:
                log.close()
                session.close()

        result = asyncio.run(_main())
        if resume_after is not None:
            from mission.cli.cmd_resume import resume

            deadline = fleet.clock.time() + 30.0
            while fleet.clock.time() < deadline and any(v.mode_name == "OFFBOARD" for v in fleet.vehicles):
                fleet.clock.sleep_blocking(0.2)
            modes = sorted({v.mode_name for v in fleet.vehicles})
            result = asyncio.run(resume(log_path, clock=fleet.clock, tlog=False))
        counters = {k: sum(v.counters.get(k, 0) for v in fleet.vehicles)
                    for k in ("rx_dropped_loss", "tx_dropped_loss")}
    finally:
        inj.done.set()
        inj.join(timeout=10)
        if intruder is not None:
            intruder.close()
        fleet.stop()
    wall_s = time.perf_counter() - t0
    records = read_mission_log(log_path)
    events = [r for r in records if r["type"] == "event"]
    latencies = []
    for sysid, t_inj in inj.injected.items():
        ev = next((e for e in events if e.get("message", "").startswith(f"vehicle {sysid} lost")), None)
        if ev is not None:
            latencies.append(round(ev["detected_s"] - t_inj, 2))
    error = None if result.estimate_enu is None else float(np.linalg.norm(np.asarray(result.estimate_enu) - source))
    rejected = {k: v for k, v in result.readings.get("rejected", {}).items() if v}
    # the robust estimator's suspects at the last iteration (sysid, reason; * = excluded)
    last = [r for r in records if r["type"] == "iteration"]
    suspects = [f"{x['sysid']} {x['reason']}{'*' if x.get('excluded') else ''}"
                for x in ((last[-1].get("suspects") or []) if last else [])]
    # retired sensors (sysid@iteration) and the closest approach of any two vehicles: planned
    # transfers and the positions logged at each iteration (parked vehicles included)
    retired = [f"{x['sysid']}@{x['iteration']}" for x in result.retired]
    planned = [e["min_separation_m"] for e in events if "strategy" in e and e.get("min_separation_m") is not None]
    closest = []
    for r in last:
        pts = np.array([p for p in r["positions_enu"].values() if p is not None], dtype=float).reshape(-1, 3)
        if len(pts) > 1:
            d = np.linalg.norm(pts[:, None] - pts[None], axis=-1) + 1e9 * np.eye(len(pts))
            closest.append(float(d.min()))
    # (the planned transfers' closest approach, and the closest two vehicles logged at the iterations)
    row = {"fault": name, "outcome": result.outcome, "iterations": result.iterations,
           "error_m": None if error is None else round(error, 2), "detect_s": latencies,
           "lost": [x["sysid"] for x in result.lost], "reengaged": sum(result.reengaged.values()),
           "rejected": rejected, "dropped_frames": counters["rx_dropped_loss"] + counters["tx_dropped_loss"],
           "suspects": suspects, "retired": retired,
           "closest_m": [round(min(x), 2) if x else None for x in (planned, closest)],
           "wall_s": round(wall_s, 1)}
    if resume_after is not None:
        row["modes_after_stop"] = modes
    return row


_NOISY_5X = dict(n=8, estimator="robust", noise=0.005, radius_m=2.0, convergence_tol_m=0.5,
                 source=(20.0, -12.0, 14.0), initial=[(3, "sensor_noise_std", 0.025)])

SCENARIOS = {
    # N = 7 -> 6 after the loss: the octahedron, whose estimate is unbiased (docs/mission.md)
    "crash": lambda: scenario("N=7: vehicle 3 crashes (iteration 3)", n=7, schedule=[(3, 3, "crashed", True)]),
    "link_cut": lambda: scenario("N=7: vehicle 2 link cut (iteration 3)", n=7, schedule=[(3, 2, "link_cut", True)]),
    "battery": lambda: scenario("N=7: vehicle 4 low battery -> RTL (iteration 3)", n=7,
                                schedule=[(3, 4, "battery_low", True)]),
    "ap_crash": lambda: scenario("ArduPilot N=7: vehicle 2 crashes", n=7, personality="ardupilot",
                                 schedule=[(3, 2, "crashed", True)]),
    "ap_battery": lambda: scenario("ArduPilot N=7: vehicle 4 low battery -> LAND", n=7, personality="ardupilot",
                                   schedule=[(3, 4, "battery_low", True)]),
    "symmetric": lambda: scenario("N=6 symmetric: vehicle 2 crashes -> CVT 5", formation="symmetric",
                                  schedule=[(3, 2, "crashed", True)]),
    "to_three": lambda: scenario("N=5: 3 crashes, then 1 (below 4)", n=5,
                                 schedule=[(2, 3, "crashed", True), (5, 1, "crashed", True)]),
    "lossy": lambda: scenario("20 % loss + 50 ms latency, all links, 4x", n=6, speedup=4.0,
                              initial=[("all", "loss_uplink", 0.2), ("all", "loss_downlink", 0.2),
                                       ("all", "latency_uplink_s", 0.05), ("all", "latency_downlink_s", 0.05)]),
    "gcs_resume": lambda: scenario("GCS stops at iteration 4, resume", resume_after=4),
    "stuck_robust": lambda: scenario("sensor 2 stuck, --estimator robust", n=8, estimator="robust",
                                     initial=[(2, "sensor_stuck", True)]),
    "stuck_plain": lambda: scenario("sensor 2 stuck, Theorem 2 (no robust)", n=8, initial=[(2, "sensor_stuck", True)]),
    "spike_robust": lambda: scenario("sensor 5 spiking (20 %, 0.5), robust", n=8, estimator="robust",
                                     initial=[(5, "sensor_spike_prob", 0.2), (5, "sensor_spike_size", 0.5)]),
    # as tests/mission/flight/test_resilience_sensor.py: N = 8, D = 2 m, noise 0.005 and 0.025 on vehicle 3, source
    # 24 m away, retire_after = 5, retire_min_noise_ratio = 2, convergence 0.5 m. At D = 4 m (the
    # other rows) the field's curvature across the formation dominates the leave-one-out errors:
    # the noisy sensor's estimated noise is 1.1-1.3x the median, it is not retired (noisy_retire_d4)
    "noisy_retire": lambda: scenario("N=8, D=2: sensor 3 noisy (5x), robust, retire after 5 at 2x", **_NOISY_5X,
                                     faults={"retire_after": 5, "retire_min_noise_ratio": 2.0}),
    "noisy_retire_20": lambda: scenario("N=8, D=2: sensor 3 noisy (5x), robust, retire after 20 (default)",
                                        **_NOISY_5X),
    "noisy_keep": lambda: scenario("N=8, D=2: sensor 3 noisy (5x), robust, faulty_sensor = keep", **_NOISY_5X,
                                   faults={"faulty_sensor": "keep"}),
    "noisy_retire_d4": lambda: scenario("N=8, D=4, noise 0.005: sensor 3 noisy (5x), robust, retire", n=8,
                                        estimator="robust", initial=[(3, "sensor_noise_std", 0.025)]),
    "bad_readings": lambda: scenario("rogue zenoh peer: bad readings", n=6, rogue=True),
    "outside_fence": lambda: scenario("source outside the fence", n=6, source=(25.0, 2.0, 12.0),
                                      fence=((-15.0, -15.0), (15.0, -15.0), (15.0, 15.0), (-15.0, 15.0))),
}


def main(argv=None) -> int:
    """Run the scenarios and print the table."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="", help="comma-separated scenario names: " + ", ".join(SCENARIOS))
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    names = [s for s in args.only.split(",") if s] or list(SCENARIOS)
    unknown = [s for s in names if s not in SCENARIOS]
    if unknown:
        ap.error(f"unknown scenario(s) {unknown}; known: {', '.join(SCENARIOS)}")
    rows = []
    print("| fault | outcome | detect s | lost | error m | iterations | re-engaged | frames dropped | "
          "readings rejected | suspects | retired | closest m (transfers, flown) | wall s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name in names:
        row = SCENARIOS[name]()
        rows.append(row)
        rej = ", ".join(f"{k} {v}" for k, v in row["rejected"].items()) or "0"
        print(f"| {row['fault']} | {row['outcome']} | {row['detect_s'] or '-'} | {row['lost'] or '-'} | "
              f"{row['error_m']} | {row['iterations']} | {row['reengaged']} | {row['dropped_frames']} | {rej} | "
              f"{row['suspects'] or '-'} | {row['retired'] or '-'} | {row['closest_m']} | {row['wall_s']} |",
              flush=True)
    if args.json:
        print(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
