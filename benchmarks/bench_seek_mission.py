"""Whole missions per seeker in lock-step: time to the source against the straight-line limit.

Flies the default ``swarmseek run`` mission (8 mock PX4 vehicles, CVT radius 4 m, sigma_2,
noise 0.01, start 25 m from the source) once per seeker and seed in this process on the
lock-step clock (:func:`mission.cli.cmd_run.run_embedded`), and reads each mission log:

* ``t_1m_s``: seek time (from the start of the seek phase) of the first iteration from which
  on the centroid of the vehicles' actual reading positions stays within 1 m of the source;
* ``ratio``: ``t_1m_s`` over the straight-line limit ``|start - source| / max_speed_m_s``;
* seek time and iterations until the convergence test passed, the final error of the estimated
  source, the readings used, the distance flown by the centre and per vehicle (from the
  iteration records' positions: mean and max over vehicles);
* ``end_centroid_m``: the last iteration's centroid to the source (where the formation is when
  the seek ends; with ``moving`` sampling the commanded centre can lead it);
* ``model_t_1m_s``: the offline time model (:class:`experiments.offline_seek.StopAndGo`) applied
  to the same mission's centre moves, to check the model against the whole mission (stop and go
  only: ``-`` for ``moving`` sampling, ``--sampling``, :mod:`mission.flight.phases.seek_moving`).

Usage::

    python benchmarks/bench_seek_mission.py                    # seeds 11-13, all seekers
    python benchmarks/bench_seek_mission.py --seeds 0,11 --seekers model --json out.json
    python benchmarks/bench_seek_mission.py --seeds 0,11,12,13 --seekers model --sampling stop_and_go,moving
    python benchmarks/bench_seek_mission.py --seeds 0-9 --seekers plume,ste --sampling default \
        --run-args "--field intermittent"      # ste against the plume fields' default seeker
    python benchmarks/bench_seek_mission.py --seeds 0-9 --seekers ste --sampling default \
        --run-args "--field intermittent" --ste-readings 1   # ste as before it took reading times
    python benchmarks/bench_seek_mission.py --seeds 0-4 --seekers ste --sampling default \
        --run-args "--field plume" --ste-args timed=1          # more ste keywords (estimator.ste.SteSeeker)

``region95_m`` is the ``ste`` seeker's last 95 % region (its posterior; ``-`` for the others);
``seeker CPU per update`` the thread CPU time of each seeker update (the mission adapter's
``step``; on the lock-step loop the executor runs it inline), median and 90th percentile.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

__all__ = ["main", "mission_measures"]


def _records(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]


def mission_measures(log_path: Path, max_speed_m_s: float = 3.0, tol_m: float = 1.0) -> dict:
    """The measures of one mission log (:func:`mission.telemetry.log_measures.mission_measures`) and
    ``model_t_1m_s``, the offline stop-and-go time model on the same mission's centre moves."""
    from experiments.offline_seek import StopAndGo
    from mission.telemetry.log_measures import centre_moves_enu
    from mission.telemetry.log_measures import mission_measures as log_measures

    row = log_measures(log_path, max_speed_m_s, tol_m)
    moves = centre_moves_enu(_records(Path(log_path)))
    model_t = np.concatenate([[0.0], np.cumsum(StopAndGo(max_speed_m_s=max_speed_m_s).iteration_s(moves))])
    k = row["iterations_1m"]
    row["model_t_1m_s"] = float(model_t[k - 1]) if k is not None else None
    return row


def fly(seeker: str, seed: int, log_dir: Path, sampling: str = "stop_and_go", extra=(), ste_args: dict | None = None,
        ste_readings: int | None = None) -> dict:
    """One default mission with ``seeker``, ``seed`` and ``sampling`` (plus ``run`` options ``extra``); its measures.
    ``ste_args``: more keywords of the ``ste`` seeker; ``ste_readings``: each vehicle's readings per update
    given to it (``seek.STE_READINGS_PER_VEHICLE``; with a number the readings' times are withheld, as
    before the filter took them)."""
    from mission.cli.cmd_run import configure, run_embedded
    from mission.telemetry.display import Display

    from mission.flight import seeking
    from mission.flight.phases import seek

    ap = argparse.ArgumentParser()
    configure(ap)
    chosen = [] if sampling == "default" else ["--sampling", sampling]
    args = ap.parse_args(["--seeker", seeker, "--seed", str(seed), *chosen, "--json", "--no-tlog",
                          "--log-dir", str(log_dir), *extra])
    seen: list = []  # the mission's seeker adapter, for its last 95 % region (ste; None for the others)
    cpu_s: list = []  # thread CPU time of each seeker update (lock-step: its executor runs inline)
    step = seeking.MissionSeeker.step

    def _step(self, *a, **kw):
        seen[:] = [self]
        if ste_readings is not None:  # the readings' times withheld: the per-update tempering
            a, kw = a[:4], {}
        t0 = time.thread_time()
        try:
            return step(self, *a, **kw)
        finally:
            cpu_s.append(time.thread_time() - t0)

    options, thin = seek.ste_options, seek.STE_READINGS_PER_VEHICLE
    seeking.MissionSeeker.step = _step
    seek.ste_options = lambda sk, *fence: {**options(sk, *fence), **(ste_args or {})}  # the name the seek phase calls
    seek.STE_READINGS_PER_VEHICLE = ste_readings
    try:
        result = run_embedded(args, display=Display(quiet=True))
    finally:
        seeking.MissionSeeker.step = step
        seek.ste_options, seek.STE_READINGS_PER_VEHICLE = options, thin
    row = mission_measures(Path(result.log_path))
    if sampling != "stop_and_go":
        row["model_t_1m_s"] = None  # the time model is stop and go's
    row.update(seeker=seeker, seed=seed, sampling=args.sampling if sampling != "default" else
               seek_sampling(result.log_path), outcome=result.outcome, error_m=result.error_m,
               mission_seek_time_s=result.seek_time_s,
               region95_m=seen[0].region95_m if seen else None,
               seeker_cpu_ms_median=1e3 * float(np.median(cpu_s)) if cpu_s else None,
               seeker_cpu_ms_p90=1e3 * float(np.percentile(cpu_s, 90)) if cpu_s else None)
    return row


def seek_sampling(log_path) -> str:
    """The sampling the mission used (its plan, as logged)."""
    for r in _records(Path(log_path)):
        if r["type"] == "event" and "sampling" in r and r.get("seeker") is not None:
            return r["sampling"]
    return "?"


def _fmt(row: dict) -> str:
    def f(x, spec=".1f"):
        return "-" if x is None else format(x, spec)

    return (f"| {row['seeker']} | {row['sampling']} | {row['seed']} | {row['outcome']} | {f(row['t_1m_s'])} | {f(row['straight_s'])} "
            f"| {f(row['ratio'], '.2f')} | {f(row['model_t_1m_s'])} | {f(row['iterations_1m'], 'd')} | {f(row['mission_seek_time_s'])} "
            f"| {row['iterations']} | {f(row['error_m'], '.2f')} | {f(row['region95_m'], '.2f')} | {row['readings']} "
            f"| {f(row['centre_flown_m'])} "
            f"| {f(row['vehicle_flown_m_mean'])} / {f(row['vehicle_flown_m_max'])} | {f(row['end_centroid_m'], '.2f')} "
            f"| {f(row.get('seeker_cpu_ms_median'))} / {f(row.get('seeker_cpu_ms_p90'))} |")


def _seeds(text: str) -> list[int]:
    """``"11,12,13"`` or ``"0-9"`` (inclusive) or a mix."""
    out = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out.extend(range(int(lo), int(hi) + 1) if hi else [int(lo)])
    return out


def main(argv=None) -> int:
    """Fly the missions; print one markdown row each (and ``--json`` the rows)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="11,12,13")
    ap.add_argument("--seekers", default="gradient,newton,model")
    ap.add_argument("--sampling", default="stop_and_go",
                    help="comma-separated: stop_and_go, moving, default (each seeker's `run` default: moving for "
                         "newton/model/ste; the gradient seeker is flown stop and go only)")
    ap.add_argument("--run-args", default="", help="extra `swarmseek run` options, e.g. '--sensor-tau 0.5'")
    ap.add_argument("--ste-args", default=None, help="keyword arguments of the ste seeker, e.g. time_temper=0.5")
    ap.add_argument("--ste-readings", type=int, default=None,
                    help="each vehicle's readings per update given to ste, without their times (1: as before "
                         "the filter took reading times); default every reading with its time")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    from bench_seekers import _ste_kwargs
    try:
        ste_kwargs = _ste_kwargs(args.ste_args)
    except ValueError as exc:
        ap.error(str(exc))
    print("| seeker | sampling | seed | outcome | time to stay within 1 m, s | straight line, s | ratio | time model, s "
          "| iterations to 1 m | seek time, s | iterations | error, m | region95, m | readings | centre flown, m "
          "| vehicle flown, m (mean / max) | last centroid to source, m | seeker CPU per update, ms (median / p90) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for seeker in args.seekers.split(","):
            for sampling in args.sampling.split(","):
                if sampling == "moving" and seeker == "gradient":
                    continue
                for seed in _seeds(args.seeds):
                    row = fly(seeker, seed, Path(tmp) / f"{seeker}-{sampling}-{seed}", sampling, args.run_args.split(),
                              ste_kwargs, args.ste_readings)
                    rows.append(row)
                    print(_fmt(row), flush=True)
    if args.json is not None:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
