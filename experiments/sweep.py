"""Sweeps over seeds: one mission (``swarmseek run --seeds``) or offline trial (``swarmseek
simulate --seeds``) per seed, one after another or ``--jobs J`` at a time in worker processes,
each result a row written as it finishes (CSV or JSON lines, :class:`RowWriter`), a progress
line on stderr (:class:`Progress`) and a summary at the end (:func:`summary`).

The command gives :func:`run_sweep` a picklable function ``one(seed) -> dict`` (a module-level
function bound to plain options with :func:`functools.partial`, so that a worker process can
import it); a seed whose run raises gives a row with ``outcome = "error"`` and the reason
(:func:`error_row`) and the sweep goes on.
"""
from __future__ import annotations

import argparse
import csv
import json
import multiprocessing
import os
import signal
import sys
import threading
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path

import numpy as np

from wire.cli_args import int_in_range, path_arg

__all__ = ["RUN_COLUMNS", "SIMULATE_COLUMNS", "SWEEP_EXTENSIONS", "add_sweep_arguments", "seed_list",
           "sweep_out_path", "RowWriter", "Progress", "error_row", "run_sweep", "summary", "summary_lines",
           "sweep_flag_problem", "seeds_text", "rows_file_problem"]

#: the columns of a ``swarmseek run --seeds`` row, in order (docs/mission.md, "Sweeps")
RUN_COLUMNS = ("seed", "n", "field", "seeker", "outcome", "error_m", "estimate_region95_m", "iterations", "seek_s",
               "straight_line_ratio", "distance_flown_m", "landed", "wall_s", "reason", "log_path")
#: the columns of a ``swarmseek simulate --seeds`` row (no seek time nor straight-line ratio offline;
#: ``final_distance_m``: the centre after the run, as ``simulate`` reports it)
SIMULATE_COLUMNS = ("seed", "n", "field", "seeker", "outcome", "error_m", "estimate_region95_m", "iterations",
                    "distance_flown_m", "final_distance_m", "wall_s", "reason")
#: ``--sweep-out`` file kinds, by extension
SWEEP_EXTENSIONS = (".csv", ".jsonl")
#: the row values the summary gives percentiles of (those present in a row)
_NUMERIC = ("error_m", "estimate_region95_m", "iterations", "seek_s", "straight_line_ratio", "distance_flown_m",
            "final_distance_m", "wall_s")
_MAX_SEEDS = 100_000
_MAX_JOBS = 64


def seed_list(text: str) -> list[int]:
    """An argparse type: ``"0-19"``, ``"3"``, ``"0,4,7-9"`` (ranges inclusive) -> the seeds, in order.

    Raises
    ------
    argparse.ArgumentTypeError
        Empty, not an integer, negative, a range whose end is below its start, a seed twice, or
        more than 100000 seeds.
    """
    seeds: list[int] = []
    for part in text.split(","):
        lo, dash, hi = part.strip().partition("-")
        try:
            first, last = int(lo), int(hi) if dash else int(lo)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected seeds as N, A-B or a comma-separated list of them (e.g. 0-19 or 0,3,5-7), got {text!r}"
            ) from None
        if last < first:
            raise argparse.ArgumentTypeError(f"the range {part.strip()!r} ends below its start (give A-B with A <= B)")
        if len(seeds) + last - first + 1 > _MAX_SEEDS:
            raise argparse.ArgumentTypeError(f"at most {_MAX_SEEDS} seeds, got more in {text!r}")
        seeds.extend(range(first, last + 1))
    seen: set = set()
    for seed in seeds:
        if seed in seen:
            raise argparse.ArgumentTypeError(f"seed {seed} is given twice in {text!r}")
        seen.add(seed)
    return seeds


def seeds_text(seeds: list[int]) -> str:
    """``[0, 1, 2, 5]`` -> ``"0-2,5"``."""
    parts, i = [], 0
    while i < len(seeds):
        j = i
        while j + 1 < len(seeds) and seeds[j + 1] == seeds[j] + 1:
            j += 1
        parts.append(str(seeds[i]) if i == j else f"{seeds[i]}-{seeds[j]}")
        i = j + 1
    return ",".join(parts)


def sweep_out_path(text: str) -> Path:
    """An argparse type: a ``.csv`` or ``.jsonl`` file name (whether it can be written: :class:`RowWriter`)."""
    path = path_arg(text)
    if path.suffix.lower() not in SWEEP_EXTENSIONS:
        raise argparse.ArgumentTypeError(
            f"the rows file must end in .csv or .jsonl (its format), got {text!r}")
    return path


def add_sweep_arguments(parser: argparse.ArgumentParser, seed_group, what: str) -> None:
    """``--seeds`` (in ``seed_group``, the mutually exclusive group that holds ``--seed``), ``--jobs``
    and ``--sweep-out``; ``what`` names one run (``mission``, ``trial``)."""
    seed_group.add_argument("--seeds", type=seed_list, default=None, metavar="SEEDS",
                            help=f"a sweep: one {what} per seed, e.g. 0-19 or 0,3,5-7 (not with --seed); a summary "
                                 "at the end, exit 1 if any failed (docs/mission.md, \"Sweeps\")")
    parser.add_argument("--jobs", type=int_in_range(1, _MAX_JOBS, "--jobs"), default=None, metavar="J",
                        help=f"with --seeds: {what}s run J at a time in worker processes (default 1: one after "
                             "another in this process)")
    parser.add_argument("--sweep-out", type=sweep_out_path, default=None, metavar="FILE",
                        help=f"with --seeds: one row per {what} written to FILE as each finishes, CSV (.csv) or "
                             "JSON lines (.jsonl)")


def rows_file_problem(path: Path | None, exc: OSError | None = None) -> str | None:
    """The one-line reason the rows file ``path`` cannot be written: ``exc`` when given (its
    opening failed), else found by opening it for appending (an existing file is left as it was, a
    new one removed again); None when it can be (or ``path`` is None)."""
    if exc is None and path is not None:
        existed = os.path.lexists(path)
        try:
            with open(path, "a", encoding="utf-8"):
                pass
        except OSError as err:
            exc = err
        else:
            if not existed:
                os.unlink(path)
    if exc is None:
        return None
    return f"cannot write the rows file (--sweep-out) {str(path)!r}: {exc.strerror or exc}"


def sweep_flag_problem(args) -> str | None:
    """``--jobs`` or ``--sweep-out`` without ``--seeds`` (they apply to a sweep only), or None."""
    if getattr(args, "seeds", None) is None:
        for flag, dest in (("--jobs", "jobs"), ("--sweep-out", "sweep_out")):
            if getattr(args, dest, None) is not None:
                return f"{flag} applies to a sweep only (give --seeds, e.g. --seeds 0-9)"
    return None


class _TerminateAsInterrupt:
    """While the workers run (this process only waits), SIGTERM is handled as Ctrl-C
    (KeyboardInterrupt: the runs under way finish and their rows are kept) instead of ending this
    process at once with its workers left running. Only in the main thread (signals)."""

    def __enter__(self):
        self._old = None
        if threading.current_thread() is threading.main_thread():
            self._old = signal.signal(signal.SIGTERM, self._raise)
        return self

    @staticmethod
    def _raise(signum, frame):
        raise KeyboardInterrupt("SIGTERM")

    def __exit__(self, *exc):
        if self._old is not None:
            signal.signal(signal.SIGTERM, self._old)
        return False


class RowWriter:
    """Rows written to a ``.csv`` (header first) or ``.jsonl`` file, each flushed as it comes.

    Parameters
    ----------
    path : Path or None
        The file (created or truncated when opened); None: rows are kept, not written.
    columns : tuple of str
        The columns, in order.

    Raises
    ------
    OSError
        The file cannot be created or written (a usage error before the sweep starts).
    """

    def __init__(self, path: Path | None, columns: tuple):
        self.path, self.columns = path, columns
        self._file = None if path is None else open(path, "w", encoding="utf-8", newline="")
        self._csv = None
        if self._file is not None and path.suffix.lower() == ".csv":
            self._csv = csv.DictWriter(self._file, fieldnames=list(columns), extrasaction="ignore")
            self._csv.writeheader()
            self._file.flush()

    def write(self, row: dict) -> None:
        """Write one row (missing columns empty in CSV, null in JSON lines) and flush it."""
        if self._file is None:
            return
        full = {c: row.get(c) for c in self.columns}
        if self._csv is not None:
            self._csv.writerow({c: "" if v is None else v for c, v in full.items()})
        else:
            self._file.write(json.dumps(full) + "\n")
        self._file.flush()

    def close(self) -> None:
        """Close the file (once)."""
        if self._file is not None:
            self._file.close()
            self._file = None


class Progress:
    """The sweep's progress on ``stream``: a bar redrawn in place on a terminal, else one plain line
    per finished run. Best effort: a closed stream stops nothing."""

    def __init__(self, prog: str, total: int, stream=None):
        self.prog, self.total, self.done, self.failed = prog, total, 0, 0
        self.stream = sys.stderr if stream is None else stream
        self.t0_s = time.monotonic()
        try:
            self.tty = self.stream.isatty()
        except (AttributeError, ValueError):  # a closed or bare stream
            self.tty = False

    def update(self, row: dict) -> None:
        """Count one finished row and show it."""
        self.done += 1
        self.failed += row.get("outcome") == "error"
        err = row.get("error_m")
        what = f"seed {row['seed']} {row.get('outcome')}" + ("" if err is None else f", error {err:.3f} m")
        text = (f"{self.prog}: {self.done}/{self.total} done" + (f" ({self.failed} failed)" if self.failed else "")
                + f", {time.monotonic() - self.t0_s:.0f} s; {what}")
        if self.tty:
            width = 20
            filled = round(width * self.done / self.total)
            text = f"\r[{'#' * filled}{'.' * (width - filled)}] {text}"
            end = "\n" if self.done == self.total else ""
            self._emit(text + "\x1b[K" + end)
        else:
            self._emit(text + "\n")

    def _emit(self, text: str) -> None:
        try:
            self.stream.write(text)
            self.stream.flush()
        except (OSError, ValueError):  # closed pipe / closed file: the rows file is the record
            pass


def error_row(seed: int, exc: BaseException, wall_s: float, base: dict | None = None) -> dict:
    """The row of a seed whose run raised ``exc``: ``outcome = "error"`` and the reason."""
    reason = f"{type(exc).__name__}: {exc}".replace("\n", " ")
    return {**(base or {}), "seed": seed, "outcome": "error", "reason": reason, "wall_s": round(wall_s, 3)}


def _guarded(one, base: dict, seed: int) -> dict:
    """``one(seed)``, or its error row when it raises (run in this process or in a worker)."""
    t0_s = time.perf_counter()
    try:
        return one(seed)
    except Exception as exc:  # noqa: BLE001 - any failure of one run is that run's row, the sweep goes on
        return error_row(seed, exc, time.perf_counter() - t0_s, base)


def run_sweep(seeds: list[int], one, *, jobs: int = 1, on_row=None, base: dict | None = None,
              stop=None) -> list[dict]:
    """Run ``one(seed)`` for every seed; the rows, in seed order.

    Parameters
    ----------
    seeds : list of int
    one : callable
        ``one(seed) -> dict`` (a row); picklable when ``jobs > 1``.
    jobs : int
        1: one after another in this process; more: that many worker processes (``spawn``: a
        fresh interpreter each, nothing of this process's threads or sockets inherited).
    on_row : callable, optional
        Called with each row as it finishes (in finishing order).
    base : dict, optional
        Columns an error row starts from (``n``, ``field``, ``seeker``).
    stop : callable, optional
        ``stop(row) -> bool``: True (e.g. the operator interrupted that run) starts no further
        seed; the runs under way finish and their rows are kept. Seeds never run have no row.
    """
    rows: list[dict] = []

    def finished(row) -> bool:
        rows.append(row)
        if on_row is not None:
            on_row(row)
        return stop is not None and bool(stop(row))

    if jobs <= 1 or len(seeds) == 1:
        for seed in seeds:
            if finished(_guarded(one, base, seed)):
                break
        return rows
    _pool_sweep(seeds, one, jobs, base, finished)
    order = {seed: i for i, seed in enumerate(seeds)}
    return sorted(rows, key=lambda r: order[r["seed"]])


def _pool_sweep(seeds: list[int], one, jobs: int, base: dict | None, finished) -> None:
    """:func:`run_sweep` in ``jobs`` worker processes, a seed handed to a worker only when one is
    free (nothing queued that a stop could not cancel); ``finished(row)`` True starts no further
    seed. Interrupted here (Ctrl-C reaching this process only, or SIGTERM), the running seeds'
    rows are collected before the interrupt goes on."""
    pool = ProcessPoolExecutor(max_workers=min(jobs, len(seeds)), mp_context=multiprocessing.get_context("spawn"))
    todo, running, t0_s = iter(seeds), {}, time.perf_counter()

    def start_next() -> None:
        seed = next(todo, None)
        if seed is not None:
            running[pool.submit(_guarded, one, base, seed)] = seed

    def row_of(fut) -> dict:
        try:
            return fut.result()
        except Exception as exc:  # noqa: BLE001 - the worker died (BrokenProcessPool) or the row did not pickle
            return error_row(running[fut], exc, time.perf_counter() - t0_s, base)

    with _TerminateAsInterrupt():
        try:
            for _ in range(jobs):
                start_next()
            stopping = False
            while running:
                done, _ = wait(running, return_when=FIRST_COMPLETED)
                for fut in done:
                    stopping = finished(row_of(fut)) or stopping
                    running.pop(fut)
                    if not stopping:
                        start_next()
        except KeyboardInterrupt:
            for fut in list(running):
                finished(row_of(fut))  # waits for it: its mission ends as it would have
                running.pop(fut)
            raise
        finally:
            pool.shutdown(wait=True, cancel_futures=True)


def _stats(values: list[float]) -> dict:
    a = np.asarray(values, dtype=float)
    return {"count": int(a.size), "median": float(np.median(a)), "p10": float(np.percentile(a, 10)),
            "p90": float(np.percentile(a, 90)), "min": float(a.min()), "max": float(a.max())}


def summary(rows: list[dict], wall_s: float, jobs: int, planned: int | None = None) -> dict:
    """The sweep's summary: runs by outcome and, for each numeric column, the count, median,
    10th and 90th percentiles, min and max over the rows that have it (error rows have none)."""
    outcomes: dict = {}
    for r in rows:
        outcomes[r["outcome"]] = outcomes.get(r["outcome"], 0) + 1
    stats = {}
    for col in _NUMERIC:
        values = [r[col] for r in rows if r.get("outcome") != "error" and r.get(col) is not None]
        if values:
            stats[col] = _stats(values)
    return {"runs": len(rows), "planned": len(rows) if planned is None else planned,
            "seeds": seeds_text([r["seed"] for r in rows]), "outcomes": outcomes,
            "failed": [{"seed": r["seed"], "reason": r.get("reason")} for r in rows if r["outcome"] == "error"],
            "stats": stats, "wall_s": round(wall_s, 3), "jobs": jobs}


def summary_lines(prog: str, summ: dict, out_path: Path | None) -> list[str]:
    """The summary as text: the outcomes, a line per numeric column, the failures, the rows file."""
    counts = ", ".join(f"{k} {v}" for k, v in sorted(summ["outcomes"].items()))
    runs = f"{summ['runs']}" if summ["runs"] == summ["planned"] else f"{summ['runs']} of {summ['planned']}"
    lines = [f"{prog}: sweep of {runs} seed{'s' if summ['planned'] != 1 else ''} ({summ['seeds']}) in "
             f"{summ['wall_s']:.1f} s wall (--jobs {summ['jobs']}): {counts}"]
    for col, s in summ["stats"].items():
        lines.append(f"  {col:20s} median {s['median']:.4g}  p10 {s['p10']:.4g}  p90 {s['p90']:.4g}  "
                     f"min {s['min']:.4g}  max {s['max']:.4g}  ({s['count']} values)")
    for f in summ["failed"]:
        lines.append(f"  seed {f['seed']} failed: {f['reason']}")
    if out_path is not None:
        lines.append(f"  rows: {out_path}")
    return lines
