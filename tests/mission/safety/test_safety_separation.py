"""Separation is enforced by the safety envelope: no setpoint batch that breaks it leaves
:meth:`SafetyEnvelope.clamp_setpoints`; the ramp streams the held setpoints, counts and reports
the interventions (aggregated), and the mission result carries the count."""
from __future__ import annotations

import asyncio

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mission.flight.result import MissionResult
from mission.safety.envelope import SafetyEnvelope, pairwise_path_separation
from mission.safety.fence import Geofence
from mission.safety.gate import SafetyGate
from mission.safety.separation import hold_for_separation

SQUARE = np.array([(0.0, 0.0), (100.0, 0.0), (100.0, 100.0), (0.0, 100.0)])
L_SHAPE = np.array([(0.0, 0.0), (100.0, 0.0), (100.0, 50.0), (50.0, 50.0), (50.0, 100.0), (0.0, 100.0)])
SEP = 1.5


def _env(poly=SQUARE, speed=3.0, sep=SEP):
    return SafetyEnvelope(Geofence(poly, 5.0, 60.0), max_speed_m_s=speed, min_separation_m=sep,
                          formation_radius_m=0.0)


def _min_path_sep(prev, out):
    return float(pairwise_path_separation(prev, out).min())


# ------------------------------------------------------------------ clamp_setpoints, by case
@pytest.mark.parametrize("prev, new", [
    # one vehicle flies to 0.5 m of a hovering one
    ([[10, 10, 20], [12, 10, 20]], [[10, 10, 20], [10.5, 10, 20]]),
    # both fly towards each other and end 0.5 m apart
    ([[10, 10, 20], [13, 10, 20]], [[11.25, 10, 20], [11.75, 10, 20]]),
    # one climbs to 0.5 m under the other
    ([[10, 10, 20], [10, 10, 22]], [[10, 10, 21.5], [10, 10, 22]]),
], ids=["into_hovering", "head_on", "vertical"])
def test_setpoints_half_a_metre_apart_are_held(prev, new):
    env = _env()
    prev, new = np.array(prev, float), np.array(new, float)
    assert np.linalg.norm(new[0] - new[1]) == pytest.approx(0.5)
    res = env.clamp_setpoints(prev, new, dt_s=1.0)
    out = res.positions_enu
    assert np.linalg.norm(out[0] - out[1]) >= SEP
    assert _min_path_sep(prev, out) >= SEP * (1 - 1e-9)
    assert res.separation_interventions >= 1 and res.report.ok
    moving = np.any(prev != new, axis=1)
    held, aside = res.separation_held, res.separation_aside
    assert not ((held | aside) & ~moving).any() and not (held & aside).any()  # movers were held or moved aside
    assert np.array_equal(out[~(held | aside)], new[~(held | aside)])         # the others flew as asked
    assert np.array_equal(out[held], prev[held])                # held: at their previous setpoints
    assert not np.any(np.all(out[aside] == prev[aside], axis=1) | np.all(out[aside] == new[aside], axis=1))
    assert "would come closer than 1.5 m" in res.separation_note


@pytest.mark.parametrize("prev, new", [
    # a cross: both fly through (20, 20) at the same time; end points 5.66 m apart
    ([[18, 18, 20], [22, 18, 20]], [[22, 22, 20], [18, 22, 20]]),
    # a swap along a line, end points as far apart as the start
    ([[18, 20, 20], [21, 20, 20]], [[21, 20, 20], [18, 20, 20]]),
], ids=["cross", "swap"])
def test_crossing_paths_are_caught(prev, new):
    env = _env(speed=10.0)
    prev, new = np.array(prev, float), np.array(new, float)
    assert np.linalg.norm(new[0] - new[1]) >= SEP                # end points alone look fine
    assert _min_path_sep(prev, new) < SEP
    res = env.clamp_setpoints(prev, new, dt_s=1.0)
    assert _min_path_sep(prev, res.positions_enu) >= SEP * (1 - 1e-9)
    assert res.separation_interventions >= 1 and res.report.ok


@pytest.mark.parametrize("n, step", [(2, 0.2), (8, 0.25), (30, 0.3)])
def test_a_safe_batch_passes_unchanged(n, step):
    env = _env()
    rng = np.random.default_rng(n)
    prev = np.c_[np.arange(n) * 3.0 + 10, np.full(n, 20.0), np.full(n, 20.0)]
    new = prev + rng.uniform(-step, step, prev.shape)
    res = env.clamp_setpoints(prev, new, dt_s=0.5)          # steps within the speed limit
    np.testing.assert_allclose(res.positions_enu, new, rtol=0, atol=1e-12)
    assert res.separation_interventions == 0 and not res.separation_held.any()
    assert res.separation_note == "" and res.report.ok


def test_holding_cascades_to_a_vehicle_flying_into_a_held_one():
    # 0 and 1 cross; 2 flies to where 1 was (1 m from it): once 1 is held there, 2 must be held too
    env = _env(speed=10.0)
    prev = np.array([[18, 18, 20], [22, 18, 20], [25, 18, 20]], float)
    new = np.array([[22, 22, 20], [18, 22, 20], [23, 18, 20]], float)
    res = env.clamp_setpoints(prev, new, dt_s=1.0)
    assert res.separation_interventions >= 1
    assert _min_path_sep(prev, res.positions_enu) >= SEP * (1 - 1e-9) and res.report.ok
    # holding alone (the first stage, before any vehicle is moved aside) cascades to all three
    hold = hold_for_separation(prev, new, SEP, np.ones(3, dtype=bool), allowed=lambda a, b: np.zeros(len(a), bool))
    assert _min_path_sep(prev, hold.positions_enu) >= SEP * (1 - 1e-9)


def test_a_pair_already_too_close_may_part_but_not_close_in():
    env = _env()
    prev = np.array([[10, 10, 20], [11, 10, 20]], float)        # 1 m: e.g. re-admitted where heard
    closer = env.clamp_setpoints(prev, [[10, 10, 20], [10.6, 10, 20]], 1.0)
    assert closer.separation_interventions == 1                 # 1 held or moved aside, never closer in
    assert _min_path_sep(prev, closer.positions_enu) >= 1.0 * (1 - 1e-9)
    assert np.array_equal(closer.positions_enu[0], prev[0])
    apart = env.clamp_setpoints(prev, [[9, 10, 20], [12, 10, 20]], 1.0)
    assert apart.separation_interventions == 0
    assert np.linalg.norm(apart.positions_enu[0] - apart.positions_enu[1]) == pytest.approx(3.0)


def test_a_vehicle_outside_the_fence_is_not_held_and_the_fence_wins():
    env = _env()
    prev = np.array([[10, 10, 0.0], [10, 10, 6.0]], float)      # 0 below the band (on the ground)
    res = env.clamp_setpoints(prev, [[10, 10, 5.0], [10, 10, 6.0]], 0.1)
    assert np.all(env.fence.contains(res.positions_enu))       # 0 goes to the band: fence first
    assert not res.report.ok and "separation" in res.report.kinds()
    assert "UNRESOLVED" in res.separation_note


# ------------------------------------------------------------------ property: always safe
def _separated_points(rng, n, poly, sep):
    fence = Geofence(poly, 5.0, 60.0)
    pts = []
    while len(pts) < n:
        p = np.r_[rng.uniform(30, 70, 2), rng.uniform(5, 15)]
        if fence.contains(p) and all(np.linalg.norm(p - q) >= sep for q in pts):
            pts.append(p)
    return np.array(pts)


@settings(max_examples=150, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(2, 20), step_m=st.floats(0.0, 6.0),
       dt_s=st.floats(0.05, 1.0), poly=st.sampled_from([SQUARE, L_SHAPE]), spread=st.booleans())
def test_clamped_batches_are_always_separated_and_inside(seed, n, step_m, dt_s, poly, spread):
    env = _env(poly, speed=4.0)
    rng = np.random.default_rng(seed)
    prev = _separated_points(rng, n, poly, SEP)
    # small random steps, or everyone heading for a few common points (many conflicts)
    if spread:
        new = prev + rng.normal(0.0, step_m + 1e-9, prev.shape)
    else:
        new = rng.choice(prev, n) + rng.normal(0.0, 0.3, prev.shape)
    res = env.clamp_setpoints(prev, new, dt_s)
    out = res.positions_enu
    assert np.all(env.fence.contains(out))
    assert _min_path_sep(prev, out) >= SEP * (1 - 1e-9)
    ends = pairwise_path_separation(out, out)
    assert ends.min() >= SEP * (1 - 1e-9)
    assert np.all(np.linalg.norm(out - prev, axis=1) <= 4.0 * dt_s * (1 + 1e-9))
    assert res.report.ok, res.report
    held, aside = res.separation_held, res.separation_aside
    assert np.array_equal(out[held], prev[held])
    assert res.separation_interventions == int(held.sum()) + int(aside.sum())


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(2, 15))
def test_rows_only_recheck_equals_a_full_recheck(seed, n):
    # hold_for_separation re-checks only the pairs of newly held vehicles; a dense check agrees
    rng = np.random.default_rng(seed)
    prev = _separated_points(rng, n, SQUARE, SEP)
    new = rng.choice(prev, n) + rng.normal(0.0, 0.5, prev.shape)
    hold = hold_for_separation(prev, new, SEP, np.ones(n, dtype=bool))
    assert _min_path_sep(prev, hold.positions_enu) >= SEP * (1 - 1e-9)
    assert not hold.unresolved


# ------------------------------------------------------------------ the ramp and the result
class _Clock:
    def __init__(self):
        self.t = 0.0

    def time(self):
        return self.t


class _Streamer:
    rate_hz = 10.0

    def __init__(self):
        self.targets = {}
        self.history = []

    def set_target(self, sysid, p, yaw_rad=None):
        self.targets[sysid] = np.asarray(p, dtype=float).copy()
        self.history.append((sysid, self.targets[sysid]))

    def remove(self, sysid):
        self.targets.pop(sysid, None)

    def tick(self):
        return 0


def _tick(ramp, clock, n):
    for _ in range(n):
        clock.t += 0.1
        ramp.step(0.1)


def test_ramp_swap_is_not_frozen_and_reports_once_per_episode():
    """A head-on swap under the gate: held then moved aside (keep right), never closer than the
    separation on any pair of sent setpoints, both at their goals; one message when the episode
    starts, one when it is over. (Before the moves aside both were held for good: a deadlock.)"""
    env = _env(speed=3.0)
    clock, st_, messages = _Clock(), _Streamer(), []
    ramp = SafetyGate(st_, clock, 3.0, rate_hz=10, envelope=env, on_violation=messages.append,
                      max_vertical_speed_m_s=3.0)
    ramp.add(1, [10, 10, 20])
    ramp.add(2, [16, 10, 20])
    ramp.add(3, [40, 40, 20])
    ramp.set_goals({1: np.array([16.0, 10, 20]), 2: np.array([10.0, 10, 20])})   # a head-on swap
    _tick(ramp, clock, 60)
    assert ramp.at_goal(1) and ramp.at_goal(2)
    for s in (1, 2, 3):                              # the ramp's current setpoint is what was sent
        assert np.array_equal(ramp.setpoint(s), st_.targets[s])
    sent = {s: np.array([p for k, p in st_.history if k == s]) for s in (1, 2)}
    assert len(sent[1]) == len(sent[2])
    d = [float(pairwise_path_separation(np.array([a0, b0]), np.array([a1, b1])).min())
         for a0, a1, b0, b1 in zip(sent[1][:-1], sent[1][1:], sent[2][:-1], sent[2][1:])]
    assert min(d) >= SEP * (1 - 1e-9)
    assert ramp.separation_interventions > 0
    assert set(ramp.separation_held_by_vehicle) <= {1, 2}
    assert sum(ramp.separation_held_by_vehicle.values()) == ramp.separation_interventions
    started = [m for m in messages if m.startswith("separation enforced")]
    over = [m for m in messages if "separation enforcement over" in m]
    assert len(started) == 1 and len(over) == 1, messages
    assert f"{ramp.separation_interventions} in the mission so far" in over[0]
    _tick(ramp, clock, 30)                           # settled: nothing more
    assert len([m for m in messages if m.startswith("separation")]) == 2


def test_ramp_stop_reports_an_open_episode():
    env = _env()
    clock, messages = _Clock(), []
    ramp = SafetyGate(_Streamer(), clock, 3.0, rate_hz=10.0, envelope=env, on_violation=messages.append)
    ramp.add(1, [10, 10, 20])
    ramp.add(2, [12, 10, 20])
    ramp.set_goal(1, [12.0, 10, 20])         # onto a hovering vehicle: 2.0 m -> 1.7 m, then held or moved aside
    _tick(ramp, clock, 5)
    n = ramp.separation_interventions
    assert n >= 1 and ramp.separation_held_by_vehicle == {1: n}
    asyncio.run(ramp.stop())
    assert messages[0].startswith("separation enforced: pairs 1-2 1.40 m would come closer than 1.5 m: "
                                  "vehicle(s) [1] "), messages
    assert messages[-1].startswith(f"separation enforcement over: {n} intervention(s)"), messages


def test_mission_result_carries_the_count():
    res = MissionResult(outcome="converged", separation_interventions=7)
    assert res.to_json()["separation_interventions"] == 7
    assert MissionResult(outcome="aborted").to_json()["separation_interventions"] == 0
