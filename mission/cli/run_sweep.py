"""``swarmseek run --seeds``: the same embedded lock-step mission once per seed (docs/mission.md,
"Sweeps").

Each mission is :func:`mission.cli.cmd_run.run_embedded`, as a single ``run``; its row is the
mission's own summary (:meth:`mission.flight.result.MissionResult.to_json`, what ``--json``
prints) and the straight-line ratio read back from its mission log
(:func:`mission.telemetry.log_measures.mission_measures`). Each mission's log goes to
``LOG_DIR/seed-K`` (``--log-dir``, default ``swarmseek-logs/sweep-TIME``). The sweep machinery
(seeds, rows file, progress, summary, worker processes) is :mod:`experiments.sweep`, shared with
``swarmseek simulate --seeds``.
"""
from __future__ import annotations

import argparse
import functools
import json
import sys
import time
from pathlib import Path

from experiments.sweep import RUN_COLUMNS, Progress, RowWriter, rows_file_problem, run_sweep, summary, summary_lines
from mission.cli.paths import DEFAULT_LOG_ROOT, mission_log_dir, new_log_dir
from mission.telemetry.log_measures import mission_measures
from wire.cli_args import fail, usage_error

__all__ = ["sweep_problem", "sweep_main", "sweep_mission", "mission_row"]

#: ``args`` names that are not options of one mission (the parser's, the sweep's own)
_NOT_MISSION_OPTIONS = ("command_module", "command_parser", "seeds", "jobs", "sweep_out")


def sweep_problem(args) -> str | None:
    """Why the options cannot make a sweep, or None: a sweep flies many missions, none of them
    reachable by a MAVLink client (``--out``) or ``watch``/``ctl`` (``--zenoh-listen``)."""
    if args.seeds is None:
        return None
    if args.out:
        return "--out forwards one mission's MAVLink; a sweep (--seeds) flies many: fly a single --seed to watch it"
    if args.zenoh_listen:
        return ("--zenoh-listen makes one mission reachable by watch/ctl; a sweep (--seeds) flies many: fly a "
                "single --seed to watch it")
    return None


def mission_row(result, args, wall_s: float) -> dict:
    """The sweep row of one flown mission (:data:`experiments.sweep.RUN_COLUMNS`)."""
    summ = result.to_json()
    ratio = None
    if result.log_path:
        ratio = mission_measures(Path(result.log_path))["ratio"]
    landed = not summ["still_armed"] and not summ["airborne_left"]
    return {"seed": args.seed, "n": args.n, "field": args.field_name, "seeker": args.seeker,
            "outcome": summ["outcome"], "error_m": summ["error_m"],
            "estimate_region95_m": summ["estimate_region95_m"], "iterations": summ["iterations"],
            "seek_s": summ["seek_time_s"], "straight_line_ratio": None if ratio is None else round(ratio, 4),
            "distance_flown_m": summ["distance_flown_m"], "landed": landed, "wall_s": round(wall_s, 3),
            "reason": "" if result.ok else summ["message"], "log_path": summ["log_path"],
            "interrupted_by": (summ["interrupted_by"] or [None])[0]}  # not a column: what stops the sweep


def sweep_mission(fly, options: dict, log_root: str, seed: int) -> dict:
    """Fly the mission of ``options`` (a ``run`` namespace's values) with ``seed`` through ``fly``
    (``run``'s :func:`mission.cli.cmd_run.run_embedded`); its row.

    Runs in this process or in a sweep's worker process (everything here is picklable).
    """
    from mission.telemetry.display import Display

    args = argparse.Namespace(**options)
    args.seed = seed
    args.log_dir = Path(log_root) / f"seed-{seed}"
    args.forward_addresses = ()
    t0_s = time.perf_counter()
    result = fly(args, display=Display(quiet=True))
    return mission_row(result, args, time.perf_counter() - t0_s)


def _log_root(args) -> tuple[Path | None, str | None]:
    """The sweep's log directory with one fresh ``seed-K`` directory per seed, or the reason it
    cannot be (a usage error before any mission)."""
    root = args.log_dir
    if root is None:
        try:
            root = new_log_dir(DEFAULT_LOG_ROOT, "sweep")
        except OSError as exc:
            return None, f"cannot create a log directory in {str(DEFAULT_LOG_ROOT)!r}: {exc.strerror or exc}"
    for seed in args.seeds:
        _, problem = mission_log_dir(Path(root) / f"seed-{seed}", "run")
        if problem:
            return None, problem
    return Path(root), None


def sweep_main(args, prog: str, fly) -> int:
    """Fly one mission per seed of ``args.seeds`` (options checked by the caller) with ``fly``
    (``args, display -> MissionResult``, a module-level function: worker processes get it by
    name); 0 when every
    mission ran and ended with its vehicles down, 1 when one failed (an exception: its row's
    outcome is ``error``) or left a vehicle armed or airborne, 2 for an unusable log directory or
    rows file, a signal's status (130, 143) when the operator stopped the sweep."""
    problem = rows_file_problem(args.sweep_out)
    root, problem = (None, problem) if problem else _log_root(args)
    if problem:
        return usage_error(prog, problem)
    try:
        writer = RowWriter(args.sweep_out, RUN_COLUMNS)
    except OSError as exc:
        return usage_error(prog, rows_file_problem(args.sweep_out, exc))
    progress = Progress(prog, len(args.seeds))
    print(f"{prog}: sweep of {len(args.seeds)} missions, mission logs in {root}/seed-K", flush=True,
          file=progress.stream)
    t0_s, rows = time.perf_counter(), []

    def on_row(row):
        rows.append(row)
        writer.write(row)
        progress.update(row)

    try:
        stopped_by = _fly_all(args, root, on_row, fly)
    except OSError as exc:  # the rows file became unwritable (disk full...)
        return fail(prog, f"cannot write the rows file: {exc}", 1)
    finally:
        writer.close()
    order = {seed: i for i, seed in enumerate(args.seeds)}
    summ = summary(sorted(rows, key=lambda r: order[r["seed"]]), time.perf_counter() - t0_s, args.jobs or 1,
                   len(args.seeds))
    summ["log_dir"] = str(root)
    print(json.dumps(summ, indent=2) if args.json else "\n".join(summary_lines(prog, summ, args.sweep_out)))
    return _sweep_status(prog, rows, args.seeds, stopped_by)


def _fly_all(args, root: Path, on_row, fly) -> str | None:
    """Every seed's mission (rows to ``on_row``); the signal that stopped the sweep between
    missions or while workers flew them (``KeyboardInterrupt``: Ctrl-C, or SIGTERM in the
    workers' parent), else None."""
    options = {k: v for k, v in vars(args).items() if k not in _NOT_MISSION_OPTIONS}
    base = {"n": args.n, "field": args.field_name, "seeker": args.seeker}
    try:
        run_sweep(args.seeds, functools.partial(sweep_mission, fly, options, str(root)), jobs=args.jobs or 1,
                  on_row=on_row, base=base, stop=_interrupted)
    except KeyboardInterrupt as exc:
        return "SIGTERM" if exc.args == ("SIGTERM",) else "SIGINT"
    return None


def _interrupted(row: dict) -> bool:
    """A signal (Ctrl-C, SIGTERM) stopped this mission: the operator's stop ends the sweep too."""
    return bool(row.get("interrupted_by"))


def _sweep_status(prog: str, rows: list[dict], seeds: list[int], stopped_by: str | None = None) -> int:
    """The sweep's exit status: a signal's (as a single run's: 130 for SIGINT, 143 for SIGTERM) when
    one stopped a mission, with the seeds not flown named; else 1 when a mission failed or left a
    vehicle armed or airborne, 0 otherwise."""
    from experiments.sweep import seeds_text
    from mission.flight.result import SIGNAL_EXIT

    signal_name = stopped_by or next((r["interrupted_by"] for r in rows if r.get("interrupted_by")), None)
    if signal_name is not None:
        flown = {r["seed"] for r in rows}
        rest = [s for s in seeds if s not in flown]
        not_flown = f": {'seed' if len(rest) == 1 else 'seeds'} {seeds_text(rest)} not flown" if rest else ""
        print(f"{prog}: stopped by {signal_name}{not_flown}", file=sys.stderr)
        return SIGNAL_EXIT.get(signal_name, 130)
    bad = [r for r in rows if r["outcome"] == "error" or r.get("landed") is False]
    return 1 if bad else 0
