"""End to end: ``swarmseek run`` (in-process) flies the whole mission against the mock fleet over
real sockets (MAVLink UDP for PX4, TCP for ArduPilot; readings and state over zenoh).

Tolerance, justified from the offline simulation of the same setting: ``experiments.offline``
runs the same formation (same offsets, same orientation), field, start, eps, gamma and noise
with perfect tracking over many noise draws, and the same convergence test; the mission must
find the source within the offline 99th-percentile error plus ``_FLIGHT_MARGIN_M``. The margin
covers what the offline model leaves out: the vehicles sit within ``arrival_tol_m`` (0.35 m) of
their slots rather than exactly on them (Theorem 2 uses the actual positions, so this changes the
geometry only slightly) and readings are taken while they hover, not at the exact slots. With
N = 4 the offline error is itself metres (the 4-vehicle estimator is biased by the field's
curvature, see docs/mission.md), and the tolerance grows accordingly.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from mission.cli import main as cli_main

from tests.support.fly_helpers import run_fleet

_FLIGHT_MARGIN_M = 0.5
_NOISE = 0.005

CASES = [
    pytest.param("px4", "cvt", 8, id="px4-cvt-8"),
    pytest.param("ardupilot", "cvt", 7, id="ardupilot-cvt-7"),
    pytest.param("px4", "symmetric", 4, id="px4-symmetric-4"),
    pytest.param("ardupilot", "symmetric", 6, id="ardupilot-symmetric-6"),
]


def _offline_tolerance(formation: str, n: int, source, start, eps: float, gamma: float,
                       window: int, tol_m: float) -> tuple[float, np.ndarray]:
    """(99th percentile of the offline final error, offline mean estimate)."""
    from estimator import convergence_scan
    from mission.flight.targets import formation_offsets
    from sitl_mock.fields_gaussian import sigma2
    from experiments.offline import simulate

    offsets = formation_offsets(formation, n, 4.0)
    res = simulate(offsets, sigma2(source), start, eps=eps, gamma=gamma, iterations=200, trials=200,
                   noise_std=_NOISE, method=formation, seed=1)
    first, est, _ = convergence_scan(res.centres, window=window, tol_m=tol_m)
    assert np.all(first >= 0), "the offline simulation of this setting does not converge"
    err = np.linalg.norm(est - np.asarray(source), axis=-1)
    return float(np.percentile(err, 99)), est.mean(axis=0)


@pytest.mark.slow
@pytest.mark.timeout(600)
@pytest.mark.parametrize("personality, formation, n, clock_args", [
    *[pytest.param(*case.values, [], id=case.id) for case in CASES],
    # 5x: a reading is late (refused, counted) after 1 s of wall clock, a vehicle lost after 0.5 s
    # (run --speedup: mission.cli.cmd_run.link_timeout_for_speedup); at 10x a loaded host (CI:
    # 3 workers on 2 cores) stalled the process past both
    # (6 vehicles: the wall clock's behaviour does not need the default 8, flown in lock-step above)
    pytest.param("px4", "cvt", 6, ["--speedup", "5"], id="px4-cvt-6-wallclock-5x"),
])
def test_mission_finds_the_source(tmp_path, capsys, personality, formation, n, clock_args):
    from mission.sim.embedded import default_eps
    from mission.telemetry.mission_log import read_mission_log
    from sitl_mock.fields_gaussian import sigma2

    source = np.array([6.0, -4.0, 13.0])
    start = source + np.array([-8.0, 5.0, -2.0])
    eps = default_eps(sigma2(source))
    tolerance_m, offline_estimate = _offline_tolerance(formation, n, source, start, eps, 1.0, 12, 0.3)
    argv = ["run", "--n", str(n), "--formation", formation, "--personality", personality,
            "--noise", str(_NOISE), "--seed", "3", "--json", *clock_args,
            "--source=" + ",".join(map(str, source)), "--start=" + ",".join(map(str, start)),
            "--max-iterations", "150", "--seeker", "gradient"]  # the offline tolerance models the paper's ascent
    log_dir = tmp_path / "run"
    code = cli_main([*argv, "--log-dir", str(log_dir)])
    captured = capsys.readouterr()
    assert captured.out, f"run exited {code} without its JSON summary: {captured.err[-2000:]}"
    out = json.loads(captured.out)
    assert out["outcome"] == "converged", out["message"]
    assert code == 0
    error_m = out["error_m"]
    assert error_m <= tolerance_m + _FLIGHT_MARGIN_M, (error_m, tolerance_m, offline_estimate)
    assert np.linalg.norm(np.asarray(out["estimate_enu"]) - offline_estimate) <= tolerance_m + _FLIGHT_MARGIN_M
    assert sum(out["readings"]["rejected"].values()) == 0, out["readings"]
    assert out["readings"]["accepted"] > 0

    records = read_mission_log(log_dir / "mission.jsonl")
    phases = [r["phase"] for r in records if r["type"] == "phase"]
    assert phases == ["connect", "preflight", "takeoff", "assemble", "seek", "finish", "return", "done"]
    landed = [r for r in records if r["type"] == "event" and r["message"].endswith("landed")]
    assert len(landed) == n
    # separation between vehicles (telemetry at every iteration) never below the plan's 1.5 m
    its = [r for r in records if r["type"] == "iteration"]
    assert len(its) == out["iterations"] or len(its) <= out["iterations"]
    for r in its:
        pos = np.array([p for p in r["positions_enu"].values() if p is not None])
        d = np.linalg.norm(pos[:, None] - pos[None], axis=-1) + np.eye(len(pos)) * 1e9
        assert d.min() >= 1.5
        assert len(r["readings"]) >= 4
    # one .tlog per vehicle; a quarantine.tlog may hold stray frames from a test running beside
    # this one on loopback (refused and counted: never a vehicle's tlog)
    tlogs = sorted(p.name for p in (log_dir / "tlogs").iterdir() if p.name != "quarantine.tlog")
    assert tlogs == [f"vehicle-{s}.tlog" for s in sorted(range(1, n + 1), key=str)]
    assert all((log_dir / "tlogs" / t).stat().st_size > 0 for t in tlogs)


def _plan_toml(ports: dict, n: int, source, start) -> str:
    vehicles = "".join(
        f'[[vehicles]]\nid = "m{i + 1}"\nsysid = {i + 1}\nconnection = "udpin:127.0.0.1:{ports["udp_base_port"] + i}"\n\n'
        for i in range(n))
    return f"""version = 1
fleet = "planned"
max_speed_m_s = 3.0
min_separation_m = 1.5
takeoff_alt_m = 8.0
stagger_s = 0.5
return = "land"

[origin]
lat_deg = 45.1885
lon_deg = 5.7245
alt_m = 212.0

{vehicles}
[formation]
type = "cvt"
radius_m = 4.0

[seeking]
eps = 49.9
gamma_m = 1.0
estimator = "cvt"
rate_hz = 2.0
max_iterations = 150
convergence_tol_m = 0.3
convergence_window = 12
start_enu_m = [{start[0]}, {start[1]}, {start[2]}]
arrival_tol_m = 0.35
reading_window_s = 0.3

[geofence]
polygon_enu_m = [[-100.0, -100.0], [100.0, -100.0], [100.0, 100.0], [-100.0, 100.0]]
min_alt_m = 2.0
max_alt_m = 60.0

[zenoh]
connect = ["tcp/127.0.0.1:{ports["zenoh_port"]}"]
listen = ["tcp/127.0.0.1:{ports["coordinator_zenoh_port"]}"]
"""


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_dry_run_then_fly_a_plan_file_against_a_mock_fleet(tmp_path):
    """The ``fly`` path: a TOML plan naming the mock's UDP ports and zenoh endpoint, while a rogue
    zenoh peer connected to the coordinator publishes bad readings on the fleet's keys: every
    kind is rejected and counted, and the mission still finds the source."""
    from mission.cli.cmd_dryrun import dry_run
    from mission.cli.cmd_fly import fly
    from mission.sim.embedded import DEFAULT_ORIGIN, fleet_ports, free_port_block
    from mission.core.plan import load_plan
    from sitl_mock.fields_gaussian import sigma2
    from mission.sim.lockstep import VirtualClock
    from sitl_mock.fleet import MockFleet

    n = 5
    source = np.array([-3.0, 4.0, 12.0])
    start = source + np.array([6.0, 4.0, -1.0])
    ports = fleet_ports(n, "px4")
    ports["coordinator_zenoh_port"] = free_port_block(1, kinds=("tcp",))
    plan_path = tmp_path / "plan.toml"
    plan_path.write_text(_plan_toml(ports, n, source, start))
    plan = load_plan(plan_path)
    fleet = MockFleet(n=n, personality="px4", field=sigma2(source), origin=DEFAULT_ORIGIN, clock=VirtualClock(),
                      seed=5, udp_base_port=ports["udp_base_port"], udp_bind_base_port=ports["udp_bind_base_port"],
                      tcp_base_port=0, fleet_name="planned", sensor_noise_std=_NOISE,
                      zenoh_listen=[f"tcp/127.0.0.1:{ports['zenoh_port']}"])
    try:
        ready = run_fleet(fleet, lambda _world: dry_run(plan, clock=fleet.clock))
        assert ready.outcome == "ready", ready.readiness
        assert all(r["checks"]["armable"] and r["checks"]["home"] for r in ready.readiness)
        assert not any(v.armed for v in fleet.vehicles)  # the dry run armed nothing
        rogue = _Rogue(ports["coordinator_zenoh_port"], "planned", fleet.clock, plan.origin)
        try:
            result = run_fleet(fleet, lambda world: fly(plan, clock=fleet.clock, log_dir=tmp_path, tlog=False,
                                                        world=world))
        finally:
            rogue.stop()
    finally:
        fleet.stop()
    rejected = result.readings["rejected"]
    for reason in ("malformed", "wrong_schema", "unknown_vehicle", "sysid_mismatch", "not_finite", "late",
                   "position_far"):
        assert rejected[reason] > 0, (reason, rejected)
    assert rogue.sent > 0
    assert result.outcome == "converged", result.message
    tolerance_m, _ = _offline_tolerance("cvt", n, source, start, 49.9, 1.0, 12, 0.3)
    assert np.linalg.norm(np.asarray(result.estimate_enu) - source) <= tolerance_m + _FLIGHT_MARGIN_M
    assert not (tmp_path / "tlogs").exists()


class _Rogue:
    """A zenoh peer publishing bad readings on a fleet's sensor keys from a thread."""

    def __init__(self, port: int, fleet: str, clock, origin):
        import threading

        import zenoh

        conf = zenoh.Config()
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
        self._session = zenoh.open(conf)
        self._fleet, self._clock, self._origin = fleet, clock, origin
        self._stop = threading.Event()
        self.sent = 0
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _reading(self, sysid, enu=(200.0, 200.0, 10.0), **over):
        from formation.geodesy import enu_to_geodetic

        lat, lon, alt = enu_to_geodetic(np.array(enu), self._origin)
        d = {"schema": "swarmseek.sensor.v1", "fleet": self._fleet, "sysid": sysid, "seq": 1,
             "time_s": self._clock.time(), "lat_deg": float(lat), "lon_deg": float(lon), "alt_m": float(alt),
             "value": 0.5}
        d.update(over)
        return json.dumps(d).encode()

    def _run(self):
        key = "swarmseek/" + self._fleet + "/vehicle/{}/sensor"
        bad = [
            (key.format(1), b"\x00garbage"),
            (key.format(2), self._reading(2, schema="evil.v9")),
            (key.format(42), None),
            (key.format(3), None),
            (key.format(4), None),
            (key.format(5), None),
            (key.format(1), None),
        ]
        while not self._stop.wait(0.05):  # publishing pace of the intruder, not a wait on a condition
            now = self._clock.time()
            payloads = [
                bad[0][1], bad[1][1],
                self._reading(42),                                   # unknown vehicle
                self._reading(4, seq=10**9),                         # key says 3: sysid mismatch
                b'{"schema": "swarmseek.sensor.v1", "fleet": "%s", "sysid": 4, "seq": 1, "time_s": %f, '
                b'"lat_deg": 45.0, "lon_deg": 5.0, "alt_m": 1.0, "value": NaN}' % (self._fleet.encode(), now),
                self._reading(5, seq=10**9, time_s=now - 3600.0),    # late
                self._reading(1, seq=10**9),                          # 200 m from vehicle 1
            ]
            for (k, _), p in zip(bad, payloads):
                self._session.put(k, p)
                self.sent += 1

    def stop(self):
        self._stop.set()
        self._thread.join(timeout=10)
        self._session.close()
