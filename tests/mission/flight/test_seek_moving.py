"""Sampling while moving (``[seeking] sampling = "moving"``, :mod:`mission.flight.phases.seek_moving`):
whole lock-step missions, the readings the seeker gets, the envelope, plan and CLI selection."""
from __future__ import annotations

import copy
import dataclasses
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from mission.cli import main as cli_main
from mission.cli.cmd_run import _check_args, _seeking_options, configure
from mission.core.plan_types import GeofencePlan, PlanError
from mission.core.plan import parse_plan
from mission.flight.phases.seek_moving import MovingSampling, lagged_positions
from mission.telemetry.mission_log import read_mission_log
from mission.telemetry.reading_format import Reading
from sitl_mock.fields_gaussian import sigma2

SAMPLE = Path(__file__).resolve().parents[3] / "mission" / "examples" / "sitl_plan.toml"


def _fly(tmp_path, capsys, name: str, *options) -> tuple[dict, list[dict]]:
    log_dir = tmp_path / name
    code = cli_main(["run", "--json", "--no-tlog", "--log-dir", str(log_dir), *options])
    out = json.loads(capsys.readouterr().out)
    assert code == 0, out["message"]
    return out, read_mission_log(log_dir / "mission.jsonl")


def _by_vehicle(iterations: list[dict]) -> dict[int, list[dict]]:
    out: dict[int, list[dict]] = {}
    for it in iterations:
        for r in it["readings"]:
            out.setdefault(r["sysid"], []).append(r)
    return out


@pytest.mark.slow
def test_moving_mission_converges_and_feeds_every_reading_where_it_was_taken(tmp_path, capsys):
    """The default mission (sigma_2, 25 m) with 4 vehicles (not 8, for CPU: every claim is per reading
    or per vehicle), noise 0, moving sampling: converged within 0.4 m; the seeker got every reading of
    every vehicle once, in order, none skipped (consecutive seq), each with the position where it was
    taken (its value is the field's there) and a time before its estimate; readings of one iteration
    span a stretch of the path."""
    out, log = _fly(tmp_path, capsys, "moving", "--seed", "0", "--noise", "0", "--sampling", "moving", "--n", "4")
    assert out["outcome"] == "converged" and out["error_m"] < 0.4, out["message"]
    event = next(r for r in log if r["type"] == "event" and r.get("message") == "embedded mock fleet")
    assert event["sampling"] == "moving"
    field = sigma2(np.asarray(next(r for r in log if r["type"] == "truth")["source_enu"]))
    its = [r for r in log if r["type"] == "iteration"]
    for it in its:
        assert all(r["time_s"] <= it["t_s"] + 1e-9 for r in it["readings"])
        pos = np.array([r["position_enu_m"] for r in it["readings"]])
        values = np.array([r["value"] for r in it["readings"]])
        np.testing.assert_allclose(values, field.value(pos), rtol=1e-3, atol=1e-6)
    for sysid, readings in _by_vehicle(its).items():
        seq = np.array([r["seq"] for r in readings])
        assert np.all(np.diff(seq) == 1), f"vehicle {sysid}: readings skipped or given twice"
        assert np.all(np.diff([r["time_s"] for r in readings]) > 0)
    flying = max(its, key=lambda it: len(it["readings"]))
    pos = np.array([r["position_enu_m"] for r in flying["readings"] if r["sysid"] == 1])
    assert len(pos) >= 10 and np.linalg.norm(pos[-1] - pos[0]) > 3.0  # a stretch of the path, not one point
    source = np.asarray(next(r for r in log if r["type"] == "truth")["source_enu"])
    assert np.linalg.norm(np.asarray(its[-1]["centroid_enu"]) - source) < 0.5  # the formation got there


@pytest.mark.slow
def test_lagged_sensor_is_compensated_when_moving(tmp_path, capsys):
    """A sensor with a 0.5 s time constant: moving readings placed where the vehicle was 0.5 s
    earlier (run's default --sensor-lag) keep the final error within 0.4 m; the log keeps the
    real positions (a reading's position is its vehicle's telemetry, not the lagged one).

    4 vehicles (not 8, for CPU): 0.18 m measured, as with 8; without the compensation
    (``--sensor-lag 0``) 0.86 m (1.4 m with 8)."""
    out, log = _fly(tmp_path, capsys, "lagged", "--seed", "11", "--sensor-tau", "0.5", "--n", "4")
    assert out["outcome"] == "converged" and out["error_m"] < 0.4, out["message"]
    seeking = next(r for r in log if r["type"] == "plan")["plan"]["seeking"]
    assert (seeking["sampling"], seeking["sensor_lag_s"]) == ("moving", 0.5)
    vehicle = {int(s): np.asarray(p) for s, p in next(r for r in log if r["type"] == "iteration")["positions_enu"].items()}
    first = next(r for r in log if r["type"] == "iteration")["readings"]
    # at rest at the start: the logged reading positions are where the vehicles are
    assert all(np.linalg.norm(np.asarray(r["position_enu_m"]) - vehicle[r["sysid"]]) < 0.2 for r in first)


@pytest.mark.slow
def test_envelope_clamps_the_moving_centre_at_the_fence(tmp_path):
    """Source outside the fence: with moving sampling the centre is still held at the fence
    (``stopped_at_fence``) and no setpoint left it (audit of the .tlogs)."""
    from tests.support.fly_helpers import run_with_saboteur

    from mission.safety.audit import audit_mission
    from mission.sim.embedded import DEFAULT_ORIGIN, default_eps, embedded_plan, fleet_ports
    from mission.sim.lockstep import VirtualClock
    from sitl_mock.fleet import MockFleet

    n, source = 5, np.array([24.0, 2.0, 13.0])
    ports = fleet_ports(n, "px4")
    fleet = MockFleet(n=n, personality="px4", field=sigma2(source), origin=DEFAULT_ORIGIN, clock=VirtualClock(),
                      seed=11, udp_base_port=ports["udp_base_port"], udp_bind_base_port=ports["udp_bind_base_port"],
                      tcp_base_port=0, fleet_name="swarmseek", zenoh_listen=[f"tcp/127.0.0.1:{ports['zenoh_port']}"],
                      sensor_noise_std=0.005)
    plan = embedded_plan(n, ports, start_enu_m=(8.0, 2.0, 11.0), eps=default_eps(sigma2(source)), max_iterations=60)
    fence = GeofencePlan(polygon_en_m=((-40.0, -40.0), (16.0, -40.0), (16.0, 40.0), (-40.0, 40.0)),
                         min_alt_m=2.0, max_alt_m=40.0)
    plan = dataclasses.replace(plan, geofence=fence, seeking=dataclasses.replace(
        plan.seeking, seeker="model", sampling="moving", gamma_m=20.0))
    result = run_with_saboteur(plan, fleet, tmp_path)
    assert result.outcome == "stopped_at_fence", result.message
    report = audit_mission(tmp_path)
    assert {k: v for k, v in report.violation_counts.items() if k != "speed"} == {}, report.format_text()
    assert report.min_fence_margin_m >= -report.limits["fence_tol_m"]
    assert report.min_fence_margin_m < 1.0, report.format_text()  # pushed against the fence
    its = [r for r in read_mission_log(tmp_path / "mission.jsonl") if r["type"] == "iteration"]
    assert max(len(it["readings"]) for it in its) > n  # it did sample while moving


def test_plan_selects_moving_sampling(doc):
    doc["seeking"].update(seeker="model", sampling="moving", replan_fraction=0.3, sensor_lag_s=1.5)
    sk = parse_plan(doc).seeking
    assert (sk.sampling, sk.replan_fraction, sk.sensor_lag_s) == ("moving", 0.3, 1.5)
    assert parse_plan(tomllib.loads(SAMPLE.read_text())).seeking.sampling == "moving"  # the model seeker's default
    doc["seeking"].update(seeker="gradient")
    del doc["seeking"]["sampling"], doc["seeking"]["replan_fraction"], doc["seeking"]["sensor_lag_s"]
    assert parse_plan(doc).seeking.sampling == "stop_and_go"  # the paper's seeker samples at rest


@pytest.mark.parametrize("changes, key, why", [
    ({"sampling": "sometimes"}, "seeking.sampling", "must be one of stop_and_go, moving, got 'sometimes'"),
    ({"seeker": "gradient", "sampling": "moving"}, "seeking.sampling", 'needs seeker = "model", "newton" or "ste"'),
    ({"seeker": "plume", "sampling": "moving"}, "seeking.sampling", 'needs seeker = "model", "newton" or "ste"'),
    ({"seeker": "model", "replan_fraction": 0.0}, "seeking.replan_fraction", "must be > 0"),
    ({"seeker": "model", "replan_fraction": 1.5}, "seeking.replan_fraction", "must be <= 1"),
    ({"seeker": "model", "sensor_lag_s": -1.0}, "seeking.sensor_lag_s", "must be >= 0"),
])
def test_bad_sampling_is_rejected_with_its_key(doc, changes, key, why):
    bad = copy.deepcopy(doc)
    bad["seeking"].update(changes)
    with pytest.raises(PlanError) as info:
        parse_plan(bad)
    problems = dict(info.value.problems)
    assert key in problems and why in problems[key], problems


def _args(*argv):
    import argparse

    ap = argparse.ArgumentParser()
    configure(ap)
    return ap.parse_args(list(argv))


def test_run_cli_selects_sampling():
    assert _seeking_options(_args())["sampling"] == "moving"                       # run's default seeker: model
    assert _seeking_options(_args("--seeker", "newton"))["sampling"] == "moving"
    assert _seeking_options(_args("--seeker", "gradient"))["sampling"] == "stop_and_go"
    plume = _seeking_options(_args("--seeker", "plume", "--seek-wind-from", "270"))
    assert (plume["sampling"], plume["wind_from_deg"]) == ("stop_and_go", 270.0)
    assert _seeking_options(_args("--sampling", "stop_and_go"))["sampling"] == "stop_and_go"
    opts = _seeking_options(_args("--replan-fraction", "0.7", "--sensor-lag", "0.2"))
    assert (opts["replan_fraction"], opts["sensor_lag_s"]) == (0.7, 0.2)
    assert _check_args(_args("--sampling", "moving")) is None


def test_run_cli_rejects_moving_gradient_and_bad_fraction(capsys):
    assert "needs --seeker model, newton or ste" in _check_args(_args("--sampling", "moving", "--seeker", "gradient"))
    assert "got plume" in _check_args(_args("--sampling", "moving", "--seeker", "plume"))
    assert "--replan-fraction must be in (0, 1]" in _check_args(_args("--replan-fraction", "1.5"))
    assert cli_main(["run", "--sampling", "moving", "--seeker", "gradient"]) == 2
    assert "needs --seeker model, newton or ste" in capsys.readouterr().err
    with pytest.raises(SystemExit) as info:
        cli_main(["run", "--sampling", "sometimes"])
    assert info.value.code == 2
    assert "invalid choice: 'sometimes'" in capsys.readouterr().err


def _reading(sysid, seq, t_s, pos):
    return Reading(sysid=sysid, seq=seq, time_s=t_s, lat_deg=0.0, lon_deg=0.0, alt_m=0.0, value=1.0,
                   position_enu_m=np.asarray(pos, dtype=float), received_s=t_s)


def test_lagged_positions_go_back_along_the_path():
    """A vehicle flying east at 3 m/s, readings every 0.1 s: with a 0.5 s lag each reading is placed
    1.5 m back along the path; before the history starts, at its first position; lag 0: as taken."""
    hist = [_reading(1, i, 0.1 * i, (0.3 * i, 2.0, 10.0)) for i in range(30)]
    new = hist[20:]
    back = np.array(lagged_positions(hist, new, 0.5))
    np.testing.assert_allclose(back, np.array([r.position_enu_m for r in new]) - [1.5, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(lagged_positions(hist, hist[:2], 0.5), [[0.0, 2.0, 10.0]] * 2)
    assert all(a is r.position_enu_m for a, r in zip(lagged_positions(hist, new, 0.0), new))


def test_moving_sampling_rejects_bad_parameters():
    class _Clock:
        def time(self):
            return 0.0

    class _Co:
        clock = _Clock()

    with pytest.raises(ValueError, match=r"replan_fraction must be in \(0, 1\]"):
        MovingSampling(_Co.clock, None, None, 0.0)
    with pytest.raises(ValueError, match="sensor_lag_s must be a finite number >= 0"):
        MovingSampling(_Co.clock, None, None, 0.5, float("nan"))


class _Store:
    def __init__(self, readings):
        self.readings = readings

    def history(self, sysid):
        return [r for r in self.readings if r.sysid == sysid]


class _FakeCo:
    """Just what :meth:`MovingSampling.collect` reads: a clock and a reading store."""

    def __init__(self, readings, t_s=0.0):
        self.t_s = t_s
        self.store = _Store(readings)
        self.clock = self

    def time(self):
        return self.t_s


def test_collect_gives_every_new_reading_once_with_its_time_and_lagged_positions():
    """Two vehicles flying east and north: each collect returns the readings taken since the
    previous one (their own times and positions, untouched), and the seeker's positions are the
    vehicles' positions ``sensor_lag_s`` earlier."""
    hist = [_reading(s, i, 0.1 * i, (0.3 * i, 0.0, 10.0) if s == 1 else (0.0, 0.3 * i, 10.0))
            for i in range(20) for s in (1, 2)]
    co = _FakeCo(hist[:20], t_s=-0.05)  # the seek starts just before the first reading
    moving = MovingSampling(co.clock, co.store, None, 0.5, sensor_lag_s=0.2)
    first = moving.collect([1, 2])
    assert sorted((r.sysid, r.seq) for r in first) == [(s, i) for s in (1, 2) for i in range(10)]
    co.store.readings, co.t_s = hist, 1.0
    second = moving.collect([1, 2])
    assert sorted((r.sysid, r.seq) for r in second) == [(s, i) for s in (1, 2) for i in range(10, 20)]
    assert all(r is hist[2 * r.seq + r.sysid - 1] for r in second)  # the store's readings, untouched
    shift = np.array([[0.6, 0.0, 0.0] if r.sysid == 1 else [0.0, 0.6, 0.0] for r in second])
    np.testing.assert_allclose(moving.positions_enu, [r.position_enu_m for r in second] - shift, atol=1e-9)
    assert moving.collect([1, 2]) == [] and moving.positions_enu.shape == (0, 3)


def test_offline_moving_gets_there_and_shows_the_lag_bias():
    """experiments.offline_moving: 4 trials from 25 m on sigma_2 (noise 0.01): the model seeker
    sampling while moving ends within 0.3 m; a 0.5 s sensor lag moves the end by more than 1 m
    along the approach, and placing the readings 0.5 s back removes most of it."""
    import formation
    from experiments.offline_moving import simulate_moving

    source = np.array([0.0, 0.0, 20.0])
    rng = np.random.default_rng(3)
    d = rng.normal(size=(4, 3)) * [1.0, 1.0, 0.2]
    start = source + 25.0 * d / np.linalg.norm(d, axis=1, keepdims=True)
    offsets = formation.cvt_sphere(8, 4.0, seed=0)

    def final_error(**kw):
        run = simulate_moving(offsets, sigma2(source), start, "model", gamma_m=20.0, iterations=30,
                              noise_std=0.01, seed=0, **kw)
        assert run.readings[1:].min() > 8  # readings along the path, not one per vehicle
        return np.linalg.norm(run.centres[-1] - source, axis=-1), run

    plain, run = final_error()
    assert plain.max() < 0.3 and np.all(np.isfinite(run.time_within_s(1.0)))
    lagged, _ = final_error(sensor_tau_s=0.5)
    compensated, _ = final_error(sensor_tau_s=0.5, sensor_lag_s=0.5)
    assert lagged.min() > 1.0 and compensated.max() < 0.5, (lagged, compensated)
    with pytest.raises(ValueError, match="needs the newton or model seeker"):
        simulate_moving(offsets, sigma2(source), start, "gradient", gamma_m=1.0, iterations=3)


def test_simulate_cli_selects_moving_sampling(capsys):
    assert cli_main(["simulate", "--sampling", "moving", "--iterations", "5"]) == 2
    assert "--sampling moving needs --seeker model, newton or ste" in capsys.readouterr().err
    assert cli_main(["simulate", "--seeker", "model", "--gamma", "20", "--sampling", "moving", "--noise", "0.01",
                     "--iterations", "40", "--window", "12", "--tol", "0.3", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["sampling"] == "moving" and out["converged"] and out["estimate_error_m"] < 0.5, out
    assert out["time_within_1m_s"] is not None and out["time_within_1m_s"] > 0


def test_offline_moving_reads_a_time_dependent_field_at_mission_time_and_sizes_the_formation():
    """experiments.offline_moving with a seeker factory: a time-dependent field is read at each
    trial's mission time (plus the trial's offset), and a seeker's ``formation_radius_m`` moves
    every vehicle to its scaled slot under the speed limit."""
    import formation
    from experiments.offline_moving import simulate_moving

    class _Field:
        time_dependent = True

        def __init__(self):
            self.times = []

        def value(self, points, t_s=0.0):
            self.times.append(float(t_s))
            return np.zeros(np.shape(points)[:-1])

        def source_enu(self):
            return np.zeros(3)

    class _Sizer:
        name = "sizer"

        def reset(self):
            self.formation_radius_m = None

        def propose(self, c, p, v):
            last = p[0, -8:]  # the last sample tick's eight positions
            self.radii = getattr(self, "radii", []) + [float(np.linalg.norm(last - last.mean(axis=0), axis=1).mean())]
            self.formation_radius_m = np.array([2.0])
            return c + np.array([[1.0, 0.0, 0.0]])

    field = _Field()
    offsets = formation.cvt_sphere(8, 4.0, seed=0)
    run = simulate_moving(offsets, field, np.array([[0.0, 0.0, 10.0], [5.0, 0.0, 10.0]]), _Sizer, gamma_m=5.0,
                          iterations=6, rotate=False, trial_time_offset_s=1000.0)
    t = np.asarray(field.times)
    assert t[0] == 0.0 and np.all(np.diff(t[t < 1000.0]) > 0) and t.max() > 1000.0  # per trial, forward in time
    assert all(isinstance(s, _Sizer) for s in run.seekers) and run.seekers[0] is not run.seekers[1]
    radii = run.seekers[0].radii
    assert radii[0] == pytest.approx(np.linalg.norm(offsets - offsets.mean(axis=0), axis=1).mean(), rel=1e-6)
    assert radii[-1] == pytest.approx(2.0 * radii[0] / np.linalg.norm(offsets, axis=1).mean(), rel=0.02)  # shrunk
    # after the shrink the formation's centre (the vehicles' mean less the slots') still follows the commands
    np.testing.assert_allclose(run.formation_enu[-1, 0] - run.centres[-1, 0], 0.0, atol=0.6)
