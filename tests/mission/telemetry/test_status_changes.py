"""The iteration records' vehicle status written as changes: read back the same as the old lists.

Old logs carry every vehicle's whole status in every ``iteration`` record (``status``); new ones
carry ``status_changes`` (:mod:`mission.telemetry.status_changes`). Both read back alike with
:func:`iteration_statuses`, and the log's readers (audit, replay, plots, export, measures,
resume) give the same results on a flown log and on the same log rewritten in the old form.
"""
from __future__ import annotations

import json
import os
import random
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mission.cli.cmd_plot import mission_tracks
from mission.safety.audit import audit_mission
from mission.telemetry.geo_export import mission_geometry
from mission.telemetry.log_measures import mission_measures
from mission.telemetry.map_replay import MissionLogReplay
from mission.telemetry.mission_log import read_mission_log
from mission.telemetry.status_changes import ITERATION_FIELDS, StatusChanges, iteration_statuses

ROOT = Path(__file__).resolve().parents[3]


def _random_fleet_statuses(rng: random.Random, n: int, steps: int) -> list[list[dict]]:
    """``steps`` successive vehicle_status() lists of ``n`` vehicles, slow fields changing now and then."""
    current = [{"sysid": s, "id": f"px4{s}", "status": "in formation", "sensor_retired": False,
                "flight_state": "flying", "flavour": "px4", "mode": "OFFBOARD", "armed": True} for s in range(1, n + 1)]
    out = []
    for _ in range(steps):
        for v in current:
            if rng.random() < 0.1:
                field = rng.choice(ITERATION_FIELDS[1:])
                v[field] = rng.choice({"status": ["holding", "lost (link)", "parked", "in formation"],
                                       "sensor_retired": [True, False], "flight_state": ["flying", "lost", "holding"],
                                       "flavour": ["px4", "ardupilot"], "mode": ["OFFBOARD", "LAND", "HOLD"],
                                       "armed": [True, False]}[field])
        # the fields that change every record, as the coordinator's status dicts have them
        out.append([dict(v, relative_alt_m=rng.uniform(0, 30), link_age_s=rng.uniform(0, 1),
                         position_enu=[rng.uniform(-50, 50) for _ in range(3)]) for v in current])
    return out


@pytest.mark.parametrize("seed", range(5))
def test_changes_read_back_as_the_old_full_lists(seed):
    rng = random.Random(seed)
    lists = _random_fleet_statuses(rng, rng.randrange(1, 12), 60)
    changes = StatusChanges()
    new = [{"type": "iteration", "k": k, "status_changes": json.loads(json.dumps(changes.changes(vs)))}
           for k, vs in enumerate(lists)]
    old = [{"type": "iteration", "k": k, "status": vs} for k, vs in enumerate(lists)]
    noise = [{"type": "status", "vehicles": []}, {"type": "event", "message": "x"}]
    got_new = iteration_statuses(noise + [r for pair in zip(new, noise * 30) for r in pair])
    got_old = iteration_statuses(old)
    assert len(got_new) == len(got_old) == len(lists)
    for a, b, vs in zip(got_new, got_old, lists):
        assert set(a) == set(b) == {v["sysid"] for v in vs}
        for s in a:
            assert a[s] == {"sysid": s, **{f: b[s][f] for f in ITERATION_FIELDS}}
            assert b[s] == next(v for v in vs if v["sysid"] == s)   # the old records read as they are
    # unchanged vehicles are not written again
    assert sum(len(r["status_changes"]) for r in new[1:]) < sum(len(vs) for vs in lists[1:])


@pytest.fixture(scope="module")
def flown(tmp_path_factory):
    """A lock-step ``run`` (seed 3, 8 vehicles, tlogs) and a copy of it with old-form iteration records."""
    base = tmp_path_factory.mktemp("status_changes")
    new_dir, old_dir = base / "new", base / "old"
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    done = subprocess.run([sys.executable, "-m", "mission", "run", "--seed", "3", "--json",
                           "--log-dir", str(new_dir)], cwd=ROOT, env=env, capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr[-2000:]
    shutil.copytree(new_dir, old_dir)
    records = read_mission_log(new_dir / "mission.jsonl")
    statuses = iter(iteration_statuses(records))
    with open(old_dir / "mission.jsonl", "w") as fh:
        for r in records:
            if r["type"] == "iteration":
                r = {k: v for k, v in r.items() if k != "status_changes"}
                r["status"] = [dict(v, position_enu=r["positions_enu"].get(str(s)), link_age_s=0.05)
                               for s, v in sorted(next(statuses).items())]
            fh.write(json.dumps(r, separators=(",", ":")) + "\n")
    return new_dir, old_dir


def test_the_new_log_writes_changes_only(flown):
    new_dir, old_dir = flown
    its = [r for r in read_mission_log(new_dir / "mission.jsonl") if r["type"] == "iteration"]
    assert len(its) >= 3 and all("status" not in r and "status_changes" in r for r in its)
    assert set(its[0]["status_changes"]) == {str(s) for s in range(1, 9)}   # the first: everyone
    assert all(set(v) == set(ITERATION_FIELDS) for v in its[0]["status_changes"].values())
    assert sum(len(r["status_changes"]) for r in its[1:]) < 8 * (len(its) - 1)
    assert (new_dir / "mission.jsonl").stat().st_size < (old_dir / "mission.jsonl").stat().st_size


def test_readers_give_the_same_results_on_old_and_new_logs(flown):
    new_dir, old_dir = flown
    new_log, old_log = new_dir / "mission.jsonl", old_dir / "mission.jsonl"
    new_recs, old_recs = read_mission_log(new_log), read_mission_log(old_log)
    new_audit, old_audit = audit_mission(new_dir), audit_mission(old_dir)
    assert new_audit.ok
    assert json.dumps(new_audit.to_dict()).replace(str(new_dir), "DIR") == \
        json.dumps(old_audit.to_dict()).replace(str(old_dir), "DIR")
    assert MissionLogReplay.load(new_log).frames == MissionLogReplay.load(old_log).frames
    for name, got in (("geometry", (mission_geometry(new_recs), mission_geometry(old_recs))),
                      ("tracks", (mission_tracks(new_recs), mission_tracks(old_recs))),
                      ("measures", (mission_measures(new_log), mission_measures(old_log)))):
        assert json.dumps(got[0], default=_plain, sort_keys=True) == json.dumps(got[1], default=_plain, sort_keys=True), name
    new_st, old_st = iteration_statuses(new_recs), iteration_statuses(old_recs)
    assert [{s: {"sysid": s, **{f: v[f] for f in ITERATION_FIELDS}} for s, v in it.items()} for it in old_st] == new_st


def _plain(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(type(obj).__name__)
