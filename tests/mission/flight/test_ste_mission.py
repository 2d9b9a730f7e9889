"""The ``ste`` seeker in missions: plan keys, the seeker built from them, the moving path feeding
every reading once, the slots scaled to its formation radius, a collapse as a logged event, and a
whole lock-step ``swarmseek run --seeker ste --field intermittent``."""
from __future__ import annotations

import asyncio
import copy
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

import formation
from estimator.seekers import MOVING_SEEKERS, SEEKERS
from estimator.ste import SteSeeker
from mission.cli import main as cli_main
from mission.core.plan_types import PlanError
from mission.core.plan import parse_plan
from mission.flight.phases import seek
from mission.flight.phases.seek import scaled_slots
from mission.flight.seeking import MissionSeeker, make_seeker, ste_options
from mission.flight.phases.seek_moving import MovingSampling, thin_evenly
from mission.telemetry.mission_log import read_mission_log
from mission.telemetry.reading_format import Reading

SAMPLE = Path(__file__).resolve().parents[3] / "mission" / "examples" / "sitl_plan.toml"
_STE = {"seeker": "ste", "sampling": "moving", "gamma_m": 20.0}


def _with(doc: dict, **seeking) -> dict:
    out = copy.deepcopy(doc)
    out["seeking"].update(seeking)
    return out


# ----------------------------------------------------------------------------- plan
def test_ste_is_a_plan_seeker_that_samples_while_moving(doc):
    assert "ste" in SEEKERS and "ste" in MOVING_SEEKERS
    plan = parse_plan(_with(doc, **_STE, plume_mode="intermittent", wind_from_deg=250.0, wind_std_deg=15.0,
                            sensor_noise_std=0.02, sensor_detection_floor=0.001, ground_alt_m=-1.0,
                            stability="D", region_m=0.8))
    sk = plan.seeking
    assert (sk.seeker, sk.sampling, sk.plume_mode, sk.wind_from_deg, sk.region_m) == (
        "ste", "moving", "intermittent", 250.0, 0.8)
    built = make_seeker(sk.seeker, sk.wind_from_deg, sk.plume_mode, **ste_options(sk)).seeker
    assert isinstance(built, SteSeeker)
    assert built.patchy and built.wind_from_deg == 250.0 and built.region_m == 0.8
    assert math.isclose(np.rad2deg(built.wind_std_rad), 15.0)
    assert built.steady_kw["noise_std"] == 0.02 and built.threshold == max(3 * 0.02, 0.001)
    assert built.model["stability"] == "D" and built.model["ground_alt_m"] == -1.0
    defaults = parse_plan(_with(doc, **_STE)).seeking  # no wind: estimated; the steady likelihood
    plain = make_seeker("ste", defaults.wind_from_deg, defaults.plume_mode, **ste_options(defaults)).seeker
    assert plain.wind_from_deg is None and not plain.patchy and plain.region_m == 1.0


@pytest.mark.parametrize("changes, key, why", [
    ({"stability": "G"}, "seeking.stability", "must be one of A, B, C, D, E, F"),
    ({"sensor_noise_std": 0.0}, "seeking.sensor_noise_std", "must be > 0"),
    ({"sensor_noise_std": float("nan")}, "seeking.sensor_noise_std", "must be finite"),
    ({"region_m": float("inf")}, "seeking.region_m", "must be finite"),
    ({"region_m": -1.0}, "seeking.region_m", "must be > 0"),
    ({"sensor_detection_floor": -0.1}, "seeking.sensor_detection_floor", "must be >= 0"),
    ({"wind_from_deg": 400.0}, "seeking.wind_from_deg", "must be <= 360"),
    ({"wind_std_deg": 10.0}, "seeking.wind_std_deg", "give wind_from_deg too"),
    ({"wind_from_deg": 270.0, "wind_std_deg": 200.0}, "seeking.wind_std_deg", "must be <= 180"),
    ({"ground_alt_m": "low"}, "seeking.ground_alt_m", "expected a number"),
])
def test_bad_ste_keys_are_refused_with_their_key(doc, changes, key, why):
    with pytest.raises(PlanError, match=re.escape(key)) as info:
        parse_plan(_with(doc, **_STE, **changes))
    assert any(k == key and why in w for k, w in info.value.problems), info.value.problems


@pytest.mark.parametrize("key, value", [("region_m", 1.0), ("stability", "C"), ("sensor_noise_std", 0.01),
                                        ("wind_std_deg", 5.0), ("prior_box", "fence")])
def test_ste_keys_are_refused_for_another_seeker(doc, key, value):
    with pytest.raises(PlanError, match=r'applies only with seeker = "ste"'):
        parse_plan(_with(doc, seeker="model", sampling="moving", gamma_m=20.0, **{key: value}))


def test_prior_box_fence_bounds_the_ste_prior_by_the_geofence_box(doc):
    """``prior_box = "fence"`` (the default): the seeker's prior box is the fence polygon's bounding
    box, from the lower of the ground and the fence's floor up to its ceiling; ``none``: no box."""
    plan = parse_plan(_with(doc, **_STE, prior_box="fence", ground_alt_m=0.5))
    sk, fence = plan.seeking, plan.geofence
    built = make_seeker(sk.seeker, sk.wind_from_deg, sk.plume_mode, **ste_options(sk, fence)).seeker
    en = np.asarray(fence.polygon_en_m)
    want = [[*en.min(axis=0), min(0.5, fence.min_alt_m)], [*en.max(axis=0), fence.max_alt_m]]
    np.testing.assert_allclose(built.prior_box_enu, want)
    start = sk.start_point()
    built.propose(start[None], (start + formation.cvt_sphere(4, 2.0, seed=0))[None], np.zeros((1, 4)))
    assert np.all((built.parts[0, :, :3] >= built.prior_box_enu[0]) & (built.parts[0, :, :3] <= built.prior_box_enu[1]))
    assert parse_plan(_with(doc, **_STE)).seeking.prior_box == "fence"
    plain = parse_plan(_with(doc, **_STE, prior_box="none")).seeking
    assert make_seeker("ste", None, "steady", **ste_options(plain, fence)).seeker.prior_box_enu is None


@pytest.mark.parametrize("changes, why", [
    ({"prior_box": "fense"}, "must be one of"),
    ({"prior_box": 1}, "expected a non-empty string"),
    ({"prior_box": "fence", "ground_alt_m": 500.0}, "above seeking.ground_alt_m"),
])
def test_a_bad_prior_box_is_refused_with_its_key(doc, changes, why):
    with pytest.raises(PlanError, match=re.escape("seeking.prior_box")) as info:
        parse_plan(_with(doc, **_STE, **changes))
    assert any(k == "seeking.prior_box" and why in w for k, w in info.value.problems), info.value.problems


def test_a_prior_box_out_of_range_exits_2_with_one_line(tmp_path, capsys):
    text = re.sub(r"^seeker = .*\n", "", SAMPLE.read_text(), count=1, flags=re.M)
    text = text.replace("[seeking]\n", '[seeking]\nseeker = "ste"\nsampling = "moving"\nprior_box = "geofence"\n', 1)
    path = tmp_path / "p.toml"
    path.write_text(text)
    assert cli_main(["dry-run", "--plan", str(path)]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if "prior_box" in line]
    assert len(err) == 1 and "seeking.prior_box" in err[0] and "fence" in err[0] and "none" in err[0], err


def test_a_bad_ste_plan_exits_2_before_connecting(tmp_path, doc, capsys):
    """``fly`` with a NaN noise: one line naming the key, exit 2 (nothing connected: the plan's
    vehicles are not listening anywhere)."""
    text = re.sub(r"^seeker = .*\n", "", SAMPLE.read_text(), count=1, flags=re.M)
    text = text.replace("[seeking]\n", '[seeking]\nseeker = "ste"\nsampling = "moving"\n'
                                      "sensor_noise_std = nan\n", 1)
    path = tmp_path / "p.toml"
    path.write_text(text)
    assert cli_main(["fly", "--plan", str(path)]) == 2
    err = capsys.readouterr().err
    assert "seeking.sensor_noise_std" in err and "must be finite" in err


def test_run_cli_passes_the_sensor_not_the_truth():
    import argparse

    from mission.cli.cmd_run import _check_args, _seeking_options, configure
    from sitl_mock.cli_args import field_from_args

    ap = argparse.ArgumentParser()
    configure(ap)
    args = ap.parse_args(["--seeker", "ste", "--field", "intermittent", "--noise", "0.02", "--detection-floor",
                          "0.005", "--seek-wind-from", "260"])
    assert _check_args(args) is None
    args.field, _, args.sensor_response = field_from_args(args, (0.0, 0.0, 15.0))  # as the mission's setup
    opts = _seeking_options(args)
    assert (opts["sampling"], opts["plume_mode"], opts["wind_from_deg"]) == ("moving", "intermittent", 260.0)
    assert (opts["sensor_noise_std"], opts["sensor_detection_floor"]) == (0.02, 0.005)
    assert "stability" not in opts and "ground_alt_m" not in opts  # the simulated world's, not given
    args = ap.parse_args(["--seeker", "model", "--seek-wind-from", "260"])
    assert "plume and ste seekers only" in _check_args(args)


def test_sitl_plan_writer_offers_ste(tmp_path):
    """``swarmseek sitl --seeker ste`` writes a plan that loads, sampling while moving."""
    import argparse
    from types import SimpleNamespace

    from mission.cli import cmd_sitl
    from mission.core.plan import load_plan
    from mission.sim.sitl_plan import seeker_settings, write_plan

    parser = argparse.ArgumentParser()
    cmd_sitl.configure(parser)
    args = parser.parse_args(["--flavour", "px4", "--seeker", "ste"])
    vehicles = [SimpleNamespace(sysid=i + 1, connection=f"udpin:127.0.0.1:{20000 + i}") for i in range(4)]
    plan = load_plan(write_plan(tmp_path / "p.toml", vehicles, (47.397742, 8.545594, 489.4), flavour="px4",
                                overrides={"seeking": seeker_settings(args.seeker)}))
    assert (plan.seeking.seeker, plan.seeking.gamma_m, plan.seeking.sampling) == ("ste", 20.0, "moving")


# ----------------------------------------------------------------------------- the moving path
def _reading(sysid, seq, t_s, value=0.0):
    return Reading(sysid=sysid, seq=seq, time_s=t_s, lat_deg=0.0, lon_deg=0.0, alt_m=0.0, value=value,
                   position_enu_m=np.array([0.1 * seq, float(sysid), 10.0]), received_s=t_s)


class _Store:
    def __init__(self):
        self.hist: dict[int, list] = {}

    def add(self, r):
        h = self.hist.setdefault(r.sysid, [])
        h.append(r)
        h.sort(key=lambda x: x.time_s)  # a late reading is inserted in time order, as ReadingStore does

    def history(self, sysid):
        return list(self.hist.get(sysid, ()))


class _Co:
    def __init__(self):
        self.store, self.t_s, self.events = _Store(), 0.0, []
        self.clock = self

    def time(self):
        return self.t_s

    def event(self, message, level="info", **fields):
        self.events.append((level, message))


def test_moving_path_gives_every_reading_since_takeoff_once():
    """ste's sampling starts at -inf (everything since takeoff, taken before the seek started); over
    several collects, with a reading that arrives late (older than ones already given) and one
    vehicle joining later, the union is every reading exactly once."""
    co = _Co()
    moving = MovingSampling(co.clock, co.store, co, 0.5, since_s=-np.inf)
    for i in range(30):  # 3 s of readings before the seek starts, two vehicles at 10 Hz
        for s in (1, 2):
            co.store.add(_reading(s, i, 0.1 * i))
    co.t_s = 3.0
    given = list(moving.collect([1, 2]))
    assert len(given) == 60
    for i in range(30, 50):
        for s in (1, 2, 3):
            co.store.add(_reading(s, i, 0.1 * i))
    co.store.add(_reading(2, 1000, 0.05))  # late: taken at 0.05 s, arrives after the first collect
    co.t_s = 5.0
    given += moving.collect([1, 2, 3])
    given += moving.collect([1, 2, 3])  # nothing new: nothing given
    keys = [(r.sysid, r.seq) for r in given]
    assert len(keys) == len(set(keys)), "a reading given twice"
    everything = {(s, r.seq) for s in (1, 2, 3) for r in co.store.history(s)}
    assert set(keys) == everything, "a reading never given"
    assert len(moving.positions_enu) == 0 and not co.events


def test_readings_that_left_the_store_first_are_reported():
    co = _Co()
    moving = MovingSampling(co.clock, co.store, co, 0.5, since_s=-np.inf)
    co.store.add(_reading(1, 0, 0.0))
    moving.collect([1])
    co.store.hist[1] = [_reading(1, i, 0.1 * i) for i in range(50, 60)]  # 1..49 fell out of the history
    assert len(moving.collect([1])) == 10
    assert co.events and "left the reading store's history" in co.events[0][1]


def test_thin_evenly_keeps_each_vehicles_first_and_last():
    readings = [_reading(s, i, 0.1 * i) for i in range(10) for s in (1, 2)] + [_reading(3, 0, 0.0)]
    pos = np.array([r.position_enu_m for r in readings])
    kept, kept_pos = thin_evenly(readings, pos, 4)
    by = {s: [r.seq for r in kept if r.sysid == s] for s in (1, 2, 3)}
    assert by == {1: [0, 3, 6, 9], 2: [0, 3, 6, 9], 3: [0]}
    np.testing.assert_array_equal(kept_pos, [r.position_enu_m for r in kept])
    assert thin_evenly(readings[:3], pos[:3], 4)[0] == readings[:3]
    assert [(r.sysid, r.seq) for r in thin_evenly(readings, pos, 1)[0]] == [(1, 0), (2, 0), (3, 0)]


# ----------------------------------------------------------------------------- formation radius
def test_scaled_slots_honour_the_radius_within_the_separation_and_the_plan():
    import formation

    off = formation.cvt_sphere(8, 4.0, seed=0)
    slots = {s + 1: o for s, o in enumerate(off)}

    def closest(d):
        a = np.array(list(d.values()))
        dist = np.linalg.norm(a[:, None] - a[None], axis=-1)
        return dist[np.triu_indices(len(a), 1)].min()

    def mean_r(d):
        return np.linalg.norm(np.array(list(d.values())), axis=1).mean()

    tight = scaled_slots(slots, 1.5, 1.5, 4.0)
    assert closest(tight) >= 1.2 * 1.5 - 1e-9 and mean_r(tight) < mean_r(slots)
    np.testing.assert_allclose(tight[1] / np.linalg.norm(tight[1]), off[0] / np.linalg.norm(off[0]))  # shape kept
    wide = scaled_slots(tight, 6.0, 1.5, 4.0)
    assert math.isclose(mean_r(wide), 4.0)  # never wider than the plan's radius
    assert scaled_slots(slots, 4.02, 1.5, 4.0) is None  # under 5 %: left as it is
    uneven = {1: np.array([2.0, 0, 0]), 2: np.array([-1.0, 0, 0]), 3: np.array([0, 1.0, 0]), 4: np.array([0, -1.0, 0])}
    wide = scaled_slots(uneven, 6.0, 0.5, 4.0)  # the farthest slot, not the mean, bounded by the plan's radius
    assert max(np.linalg.norm(o) for o in wide.values()) == pytest.approx(4.0)


# ----------------------------------------------------------------------------- errors and collapse
class _EventCo:
    def __init__(self):
        self.events = []

    def event(self, message, level="info", **fields):
        self.events.append((level, message, fields))


def _seek_with(seeker):
    run = object.__new__(seek.Seek)  # only what _propose reads
    run.events, run.seeker, run.centre = _EventCo(), seeker, np.array([0.0, 0.0, 10.0])
    run.sk = type("Sk", (), {"gamma_m": 20.0, "seeker": "ste"})()
    return run


def test_a_collapse_is_an_event_and_the_mission_goes_on():
    """Readings no particle can explain (1000 where the prior's plumes give at most ~20): the
    posterior collapses, is re-seeded, and the mission log gets a warning naming it."""
    run = _seek_with(MissionSeeker("ste", particles=300, info_particles=64))
    rng = np.random.default_rng(0)
    pos = np.array([0.0, 0.0, 10.0]) + rng.normal(size=(8, 3)) * 3.0
    centre = asyncio.run(run._propose(0, pos, np.full(8, 1000.0)))
    assert np.all(np.isfinite(centre))
    assert run.seeker.collapsed and run.seeker.collapses == 1 and run.seeker.arrival is False
    level, message, fields = run.events.events[-1]
    assert level == "warning" and "posterior collapsed" in message and fields["collapses"] == 1


def test_every_reading_goes_to_ste_with_its_time_and_vehicle():
    """The mission no longer thins ste's readings (STE_READINGS_PER_VEHICLE None): each update's readings,
    every one, reach the filter with their times and vehicles, which weigh them
    (estimator.ste_tempering: 3 s of 10 Hz readings per vehicle about 1.6 units each, not 30)."""
    assert seek.STE_READINGS_PER_VEHICLE is None
    run = _seek_with(MissionSeeker("ste", 270.0, "intermittent", particles=300, info_particles=64))
    rng = np.random.default_rng(1)
    sysids = np.repeat([11, 12, 13, 14], 30)
    times = 1767225600.0 + np.tile(np.arange(30) * 0.1, 4)
    hover = np.array([[20.0, 3.0, 10.0], [20.0, -3.0, 10.0], [23.0, 0.0, 10.0], [17.0, 0.0, 10.0]])
    pos = np.repeat(hover, 30, axis=0) + rng.normal(size=(120, 3)) * 0.05
    centre = asyncio.run(run._propose(0, pos, np.zeros(120), list(times), list(sysids)))
    assert np.all(np.isfinite(centre))
    filt = run.seeker.seeker
    assert sorted(filt._last[0]) == [11, 12, 13, 14]
    assert filt._buf[-1][0].shape == (1, 120, 3)  # every reading in the update
    assert filt._buf[-1][3].sum() == pytest.approx(4 * (1.0 + 2.9 / 5.0), rel=0.05)


def test_a_seeker_error_holds_and_is_logged():
    run = _seek_with(MissionSeeker("ste", particles=300, info_particles=64))
    held = asyncio.run(run._propose(3, np.zeros((8, 3)), np.full(8, np.nan)))
    np.testing.assert_array_equal(held, run.centre)
    assert run.seeker.estimate_enu is None
    assert run.events.events and "iteration 4: seeker ste proposed no centre" in run.events.events[-1][1]


def test_the_adapter_reports_the_posterior():
    ms = MissionSeeker("ste", particles=500, info_particles=64, wind_from_deg=270.0)
    rng = np.random.default_rng(1)
    pos = np.array([10.0, 0.0, 10.0]) + rng.normal(size=(8, 3)) * 3.0
    ms.step(np.array([10.0, 0.0, 10.0]), pos, np.zeros(8), 20.0)
    assert ms.estimate_enu.shape == (3,) and ms.region95_m > 0 and ms.collapses == 0
    assert ms.arrival is False and ms.misfit in (True, False) and 1.5 <= ms.formation_radius_m <= 6.0
    ms.reset()
    assert ms.estimate_enu is None and ms.region95_m is None


# ----------------------------------------------------------------------------- a whole mission
@pytest.mark.slow
@pytest.mark.timeout(600)  # every reading to the filter: ~6 s of its CPU per mission, more on a loaded machine
def test_run_ste_on_the_intermittent_plume_converges_near_the_source(tmp_path, capsys):
    """``swarmseek run --seeker ste --field intermittent`` (seed 1, lock-step; a typical seed of the
    ten in docs/seekers.md): converged on its posterior's 95 % region (at most the default 1 m), the
    estimate (the posterior mean, also the iteration records') within 1.5 times that region of the
    release, and the separation never needed the envelope."""
    log_dir = tmp_path / "ste"
    code = cli_main(["run", "--seeker", "ste", "--field", "intermittent", "--seed", "1", "--json", "--no-tlog",
                     "--log-dir", str(log_dir)])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and out["outcome"] == "converged", out["message"]
    region = float(re.search(r"95 % region ([0-9.]+) m", out["message"]).group(1))
    assert 0 < region <= 1.0
    assert out["error_m"] <= 1.5 * region, (out["error_m"], region)
    records = read_mission_log(log_dir / "mission.jsonl")
    plan = next(r for r in records if r["type"] == "plan")
    assert '"ste"' in json.dumps(plan) and out["separation_interventions"] == 0
    its = [r for r in records if r["type"] == "iteration"]
    np.testing.assert_allclose(its[-1]["estimate_enu"], out["estimate_enu"], atol=1e-3)


def test_ste_wind_prior_comes_from_the_plan_else_the_autopilots_else_none():
    """The plan's wind wins; without it the autopilots' estimates (fleet_wind_prior) give the
    prior; with neither the seeker estimates the direction (None), and each case says so."""
    from types import SimpleNamespace

    from mission.flight.seeking import ste_wind
    from mission.vehicle.state import VehicleState
    from mission.vehicle.wind import WindEstimate

    def vehicle(sysid, from_deg):
        v = VehicleState(sysid=sysid, flavour="px4")
        v.wind = WindEstimate(from_deg=from_deg, speed_m_s=3.0, down_m_s=0.0, time_s=99.0, message="WIND_COV")
        return v

    fleet = [vehicle(1, 268.0), vehicle(2, 272.0), VehicleState(sysid=3, flavour="px4")]
    planned = SimpleNamespace(wind_from_deg=250.0, wind_std_deg=5.0)
    assert ste_wind(planned, fleet, 100.0)[:2] == (250.0, 5.0)
    unplanned = SimpleNamespace(wind_from_deg=None, wind_std_deg=10.0)
    from_deg, std_deg, said = ste_wind(unplanned, fleet, 100.0)
    assert from_deg == pytest.approx(270.0, abs=0.5) and std_deg >= 10.0 and "autopilots" in said
    from_deg, _, said = ste_wind(unplanned, [VehicleState(sysid=1, flavour="px4")], 100.0)
    assert from_deg is None and "none" in said
