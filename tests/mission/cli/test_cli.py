"""CLI commands of the coordinator: plot, dry-run, fly and run argument handling (in-process)."""
from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from mission.cli import main as cli_main
from mission.telemetry.mission_log import MissionLog

SAMPLE = Path(__file__).resolve().parents[3] / "mission" / "examples" / "sitl_plan.toml"


class _Clock:
    speedup = 1.0

    def __init__(self):
        self.t = 1000.0

    def time(self):
        return self.t


def _write_plan(path: Path, **changes) -> Path:
    """The sample plan with top-level or dotted changes, written as TOML."""
    doc = tomllib.loads(SAMPLE.read_text())
    for key, value in changes.items():
        target = doc
        parts = key.split("__")
        for p in parts[:-1]:
            target = target[p]
        if value is None:
            target.pop(parts[-1], None)
        else:
            target[parts[-1]] = value
    path.write_text(_to_toml(doc))
    return path


def _to_toml(doc: dict) -> str:
    def val(v):
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, list):
            return "[" + ", ".join(val(x) for x in v) + "]"
        return repr(v)

    lines, tables = [], []
    for k, v in doc.items():
        if isinstance(v, dict):
            tables.append((k, v))
        elif isinstance(v, list) and v and isinstance(v[0], dict):
            tables.extend((f"[{k}]", item) for item in v)
        else:
            lines.append(f"{k} = {val(v)}")
    for name, t in tables:
        lines.append(f"[{name}]")
        for k, v in t.items():
            if isinstance(v, dict):
                continue
            lines.append(f"{k} = {val(v)}")
        for k, v in t.items():
            if isinstance(v, dict):
                lines.append(f"[{name}.{k}]")
                lines.extend(f"{kk} = {val(vv)}" for kk, vv in v.items())
    return "\n".join(lines) + "\n"


def test_round_trip_of_the_test_toml_writer(tmp_path):
    from mission.core.plan import load_plan

    plan = load_plan(_write_plan(tmp_path / "p.toml"))
    assert plan == load_plan(SAMPLE)


# ----------------------------------------------------------------------------------- plot
def _synthetic_log(path: Path, iterations: int = 20) -> Path:
    log = MissionLog(path, _Clock())
    log.phase("seek")
    source = np.array([5.0, 5.0, 12.0])
    c = np.array([-10.0, 0.0, 10.0])
    for k in range(1, iterations + 1):
        g = (source - c) * 0.01
        new = c + 0.3 * (source - c)
        log.write("iteration", k=k, centre_enu=c, new_centre_enu=new, gradient=g, estimate_enu=new,
                  positions_enu={1: c + [4, 0, 0], 2: c - [4, 0, 0], 3: c + [0, 4, 0], 4: c - [0, 0, 4]})
        c = new
    log.write("summary", outcome="converged", estimate_enu=c, true_source_enu=source)
    log.close()
    return path


def test_plot_writes_four_pngs(tmp_path, capsys):
    log = _synthetic_log(tmp_path / "mission.jsonl")
    out = tmp_path / "fig"
    assert cli_main(["plot", str(log), "--out", str(out)]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == ["distance.png", "gradient.png", "trajectory_3d.png", "trajectory_top.png"]
    for p in out.iterdir():
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 5000
    assert "trajectory_3d.png" in capsys.readouterr().out


@pytest.mark.parametrize("content, why", [(None, "no such file"), ("hello\n", "not a swarmseek mission log"),
                                          ('{"t_s": 0, "type": "phase", "phase": "connect"}\n',
                                           "no seeking iteration")])
def test_plot_bad_logs_exit_1_with_a_reason(tmp_path, capsys, content, why):
    log = tmp_path / "mission.jsonl"
    if content is not None:
        log.write_text(content)
    assert cli_main(["plot", str(log), "--out", str(tmp_path / "o")]) == 1
    assert why in capsys.readouterr().err


# -------------------------------------------------------------------------------- dry-run
def test_dry_run_invalid_plan_lists_every_problem(tmp_path, capsys):
    plan = _write_plan(tmp_path / "bad.toml", version=3, formation__radius_m=-2.0, seeking__eps=0)
    assert cli_main(["dry-run", "--plan", str(plan)]) == 2
    err = capsys.readouterr().err
    for key in ("version", "formation.radius_m", "seeking.eps"):
        assert key in err


def test_dry_run_unreachable_vehicles_are_not_ready(tmp_path, capsys):
    from mission.sim.embedded import free_port_block

    base = free_port_block(4, kinds=("udp",))
    doc = tomllib.loads(SAMPLE.read_text())
    plan = tmp_path / "p.toml"
    for i, v in enumerate(doc["vehicles"]):
        v["connection"] = f"udpin:127.0.0.1:{base + i}"
    plan.write_text(_to_toml(doc))
    assert cli_main(["dry-run", "--plan", str(plan), "--timeout", "1", "--json"]) == 1
    out = json.loads(capsys.readouterr().out)
    assert out["outcome"] == "not_ready"
    assert len(out["readiness"]) == 4 and not any(r["ready"] for r in out["readiness"])
    assert all(r["problems"] for r in out["readiness"])


# ----------------------------------------------------------------------------- fly / run
def test_fly_needs_zenoh_endpoints(tmp_path, capsys):
    plan = _write_plan(tmp_path / "p.toml", zenoh=None)
    assert cli_main(["fly", "--plan", str(plan)]) == 2
    assert "no listen or connect endpoint" in capsys.readouterr().err


@pytest.mark.parametrize("argv, why", [(["--n", "3"], "at least 4"),
                                       (["--n", "7", "--formation", "symmetric"], "even"),
                                       (["--max-iterations", "0"], "max-iterations")])
def test_run_rejects_bad_options(argv, why, capsys):
    assert cli_main(["run", *argv]) == 2
    assert why in capsys.readouterr().err


@pytest.mark.parametrize("argv", [["--source", "1,2"], ["--speedup", "0"], ["--noise", "-1"],
                                  ["--personality", "betaflight"]])
def test_run_argparse_errors_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as info:
        cli_main(["run", *argv])
    assert info.value.code == 2
    assert "error" in capsys.readouterr().err


def test_fly_with_a_busy_zenoh_port_fails_clearly(tmp_path, capsys):
    import socket

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        plan = _write_plan(tmp_path / "p.toml", zenoh__listen=[f"tcp/127.0.0.1:{port}"])
        assert cli_main(["fly", "--plan", str(plan), "--log-dir", str(tmp_path / "log")]) == 1
    err = capsys.readouterr().err
    assert f"cannot listen on tcp/127.0.0.1:{port}" in err and "nothing armed" in err and ".rs:" not in err


def test_summary_lists_lost_vehicles_with_detection_latency():
    from mission.telemetry.display import format_summary

    lines = format_summary({
        "outcome": "converged", "message": "ok", "mission_time_s": 10.0, "seek_time_s": 5.0,
        "distance_flown_m": 3.0,
        "lost": [{"sysid": 3, "reason": "silent", "detail": "no frame for 1.0 s", "phase": "seek",
                  "latency_s": 1.08}],
    })
    assert any("lost vehicle 3 in seek: silent" in ln and "1.08 s" in ln for ln in lines)


def test_summary_lists_retired_sensors():
    from mission.telemetry.display import format_summary

    lines = format_summary({
        "outcome": "converged", "message": "ok", "mission_time_s": 10.0, "seek_time_s": 5.0,
        "distance_flown_m": 3.0,
        "retired": [{"sysid": 3, "reason": "noisy", "iteration": 29, "ratio": 3.62}],
    })
    assert any("sensor of vehicle 3 retired after iteration 29 (noisy, 3.6x the median noise)" in ln
               for ln in lines)
