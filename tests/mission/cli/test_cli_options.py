"""Top-level CLI behaviour: --version, a subcommand's own usage on a bad option, output paths
that cannot be written (exit 2 with the path and the reason), plot titles and equal scales."""
from __future__ import annotations

import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

import numpy as np
import pytest

from mission.cli import main as cli_main
from mission.telemetry.mission_log import MissionLog

ROOT = Path(__file__).resolve().parents[3]
SAMPLE = ROOT / "mission" / "examples" / "sitl_plan.toml"


class _Clock:
    speedup = 1.0

    def __init__(self):
        self.t = 1000.0

    def time(self):
        return self.t


def test_version_comes_from_the_package_metadata(capsys):
    with pytest.raises(SystemExit) as exc:
        cli_main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"swarmseek {version('swarmseek')}"


@pytest.mark.parametrize("command", ["run", "fly", "plot", "mock", "simulate", "audit"])
def test_an_unknown_option_prints_the_subcommands_usage(command, capsys):
    with pytest.raises(SystemExit) as exc:
        cli_main([command, "--bogus"])
    err = capsys.readouterr().err
    assert exc.value.code == 2
    assert f"usage: swarmseek {command} " in err
    assert f"swarmseek {command}: error: unrecognized arguments: --bogus" in err \
        or f"swarmseek {command}: error: the following arguments are required" in err
    assert "COMMAND" not in err  # not the top-level usage


def test_run_bogus_in_a_subprocess_exits_2_with_runs_usage():
    proc = subprocess.run([sys.executable, "-m", "mission", "run", "--bogus"], capture_output=True, text=True,
                          timeout=60, cwd=ROOT)
    assert proc.returncode == 2
    assert proc.stderr.startswith("usage: swarmseek run ")
    assert "swarmseek run: error: unrecognized arguments: --bogus" in proc.stderr
    assert "Traceback" not in proc.stderr


def _unwritable(tmp_path: Path, kind: str) -> tuple[Path, str]:
    if kind == "proc":
        return Path("/proc/nope/logs"), "cannot create"
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    if kind == "file":
        return blocker, "exists and is not a directory"
    return blocker / "sub", "cannot create"


@pytest.mark.parametrize("kind", ["proc", "file", "under_a_file"])
@pytest.mark.parametrize("argv", [["run"], ["fly", "--plan", str(SAMPLE)]])
def test_a_log_dir_that_cannot_be_written_is_an_invalid_option(tmp_path, capsys, argv, kind):
    path, why = _unwritable(tmp_path, kind)
    assert cli_main([*argv, "--log-dir", str(path)]) == 2
    err = capsys.readouterr().err
    assert "log directory (--log-dir)" in err and str(path) in err and why in err
    assert "fleet" not in err and "zenoh" not in err


def test_plot_out_that_cannot_be_written_exits_2(tmp_path, capsys):
    log = _log(tmp_path / "run-x" / "mission.jsonl")
    assert cli_main(["plot", str(log), "--out", "/proc/nope/figs"]) == 2
    assert "cannot create the output directory (--out) '/proc/nope/figs'" in capsys.readouterr().err


def test_plot_of_a_directory_says_so(tmp_path, capsys):
    assert cli_main(["plot", str(tmp_path)]) == 1
    assert "is a directory, not a mission log" in capsys.readouterr().err


def test_paper_out_that_cannot_be_written_exits_2(capsys):
    assert cli_main(["paper", "--out", "/proc/nope/figs"]) == 2
    assert "cannot create the output directory (--out)" in capsys.readouterr().err


def test_resume_of_a_read_only_log_exits_2(tmp_path, capsys):
    log = _log(tmp_path / "mission.jsonl")
    log.chmod(0o444)
    try:
        import os

        if os.access(log, os.W_OK):  # running as root: permissions do not bind, use a directory
            target = tmp_path
            why = "is a directory"
        else:
            target, why = log, "permission denied"
        assert cli_main(["resume", str(target)]) == 2
        assert why in capsys.readouterr().err
    finally:
        log.chmod(0o644)


# ------------------------------------------------------------------------------------ plots
def _log(path: Path, *, seed: int | None = 4, error_m: float | None = 0.31) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    log = MissionLog(path, _Clock())
    log.write("plan", plan={"fleet": "alpha", "origin": [45.0, 5.0, 200.0]})
    if seed is not None:
        log.event("embedded mock fleet", seed=seed)
    source = np.array([5.0, 5.0, 12.0])
    c = np.array([-30.0, 0.0, 10.0])
    for k in range(1, 15):
        new = c + 0.3 * (source - c)
        log.write("iteration", k=k, centre_enu=c, new_centre_enu=new, gradient=(source - c) * 0.01,
                  estimate_enu=new, positions_enu={1: c + [4, 0, 0], 2: c - [4, 0, 0], 3: c + [0, 4, 0]})
        c = new
    log.write("summary", outcome="converged", estimate_enu=c,
              estimate_geodetic={"lat_deg": 45.0000449, "lon_deg": 5.0000634, "alt_m": 212.0})
    if error_m is not None:
        log.write("truth", source_enu=source, error_m=error_m)
    log.close()
    return path


def test_run_title_names_the_run_fleet_seed_outcome_error_and_position(tmp_path):
    from mission.cli.cmd_plot import run_title
    from mission.telemetry.mission_log import read_mission_log

    log = _log(tmp_path / "run-20260101-000000" / "mission.jsonl")
    title = run_title(read_mission_log(log), log)
    assert title.startswith("run-20260101-000000 | fleet alpha | seed 4 | converged | error 0.31 m")
    assert "estimated source 45.0000449, 5.0000634, 212.0 m AMSL" in title
    log2 = _log(tmp_path / "fly-1" / "mission.jsonl", seed=None, error_m=None)  # a flown mission
    title2 = run_title(read_mission_log(log2), log2)
    assert title2.startswith("fly-1 | fleet alpha | converged") and "seed" not in title2 and "error" not in title2


def test_figures_are_titled_and_trajectories_have_equal_scales(tmp_path, monkeypatch):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mission.cli.cmd_plot import plot_mission

    closed = []
    monkeypatch.setattr(plt, "close", lambda fig=None: closed.append(fig))
    log = _log(tmp_path / "run-7" / "mission.jsonl")
    paths = plot_mission(log, tmp_path / "fig")
    assert [p.name for p in paths] == ["trajectory_3d.png", "trajectory_top.png", "distance.png", "gradient.png"]
    assert len(closed) == 4
    for fig in closed:
        assert "run-7 | fleet alpha | seed 4 | converged | error 0.31 m" in fig.axes[0].get_title()
    ax3d = closed[0].axes[0]
    spans = [np.diff(lim)[0] for lim in (ax3d.get_xlim(), ax3d.get_ylim(), ax3d.get_zlim())]
    assert spans == pytest.approx([spans[0]] * 3)  # the path spans 35 m east, 5 m north, 2 m up
    assert np.ptp(np.asarray(ax3d.get_box_aspect(), dtype=float)) < 1e-9  # a cube, not a default box
    assert closed[1].axes[0].get_aspect() == 1.0
    plt.close("all")


def test_plot_command_prints_the_four_files(tmp_path, capsys):
    log = _log(tmp_path / "run-8" / "mission.jsonl")
    assert cli_main(["plot", str(log), "--out", str(tmp_path / "f")]) == 0
    printed = capsys.readouterr().out.split()
    assert [Path(p).name for p in printed] == ["trajectory_3d.png", "trajectory_top.png", "distance.png",
                                               "gradient.png"]


def test_mock_samples_the_same_field_as_run_by_default():
    """``mock`` stands in for the sample plan's vehicles, whose eps is chosen for sigma_2, like ``run``."""
    import tomllib

    from sitl_mock.cli_args import field_from_args

    mock = build_args(["mock"])
    run = build_args(["run"])
    assert field_from_args(mock, None)[0] == field_from_args(run, None)[0] == "sigma2"
    plan_text = SAMPLE.read_text()
    assert "sigma_2" in plan_text and tomllib.loads(plan_text)["seeking"]["eps"] == 50.0


def build_args(argv):
    from mission.cli import build_parser

    return build_parser(argv).parse_args(argv)


def test_an_unknown_option_before_the_command_is_a_top_level_error(capsys):
    with pytest.raises(SystemExit) as exc:
        cli_main(["--bogus", "run"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "swarmseek: error: unrecognized arguments: --bogus" in err


@pytest.mark.parametrize("argv", [["ctl", "f", "pause", "--timeout-s", "0"], ["ctl", "f", "pause", "--timeout-s", "nan"],
                                  ["watch", "f", "--wait-s", "-1"]])
def test_ctl_and_watch_refuse_a_non_positive_time(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        build_args(argv)
    assert exc.value.code == 2 and "expected a positive number" in capsys.readouterr().err


@pytest.mark.parametrize("argv, link_timeout_s", [
    ([], 1.0), (["--realtime"], 1.0), (["--speedup", "2"], 1.0), (["--speedup", "5"], 2.5), (["--speedup", "10"], 5.0),
])
def test_run_on_a_faster_wall_clock_declares_a_loss_after_half_a_wall_second(argv, link_timeout_s):
    """``run --speedup S``: the loss timeout (simulated s) is at least ``S`` x 0.5 s, so that a host
    stall (fleet and ground station alike) of under half a wall second loses no vehicle; lock-step
    and real time keep the plan's 1 s."""
    import argparse

    from mission.cli.cmd_run import WALL_STALL_S, _mission_setup, configure

    parser = argparse.ArgumentParser()
    configure(parser)
    args = parser.parse_args(["--n", "4", *argv])
    plan = _mission_setup(args)[0]
    assert WALL_STALL_S == 0.5 and plan.faults.link_timeout_s == link_timeout_s
