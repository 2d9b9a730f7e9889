"""Output paths of the ``swarmseek`` commands, checked before anything starts.

A log or figure directory that cannot be created or written is an invalid option (exit status 2)
with a message that names the directory and the reason, not a failure blamed on the fleet,
zenoh or the plot after the vehicles were contacted.

Mission log directories never collide (:func:`mission_log_dir`): a default one
(``swarmseek-logs/run-YYYYMMDD-HHMMSS``) is created exclusively (``os.mkdir``), with ``-2``,
``-3``, ... appended when a run started in the same second took the name; an explicit
``--log-dir`` that already holds a non-empty ``mission.jsonl`` is refused (another mission's
log: ``resume`` continues it), and its ``mission.jsonl`` is created exclusively, so two missions
started together on the same ``--log-dir`` cannot both take it.
"""
from __future__ import annotations

import os
import time
from pathlib import Path

from wire.cli_args import output_dir_problem

__all__ = ["writable_file_problem", "mission_log_dir", "new_log_dir", "DEFAULT_LOG_ROOT",
           "announce_log", "summary_log_line"]

#: where ``run`` and ``fly`` put their log directories when ``--log-dir`` is not given
DEFAULT_LOG_ROOT = Path("swarmseek-logs")
_MAX_SAME_SECOND = 1000                 # directories of one prefix started within one second


def new_log_dir(root: Path, prefix: str, now_s: float | None = None) -> Path:
    """Create a new directory ``root/PREFIX-YYYYMMDD-HHMMSS`` (local time), or ``...-k`` (k = 2, 3, ...)
    when that name is taken: exclusive creation, so two calls never return the same directory.

    Parameters
    ----------
    root : Path
        The parent (created if missing).
    prefix : str
        ``run``, ``fly``.
    now_s : float, optional
        Unix time of the name (default: now).

    Returns
    -------
    Path
        The directory, just created by this call.

    Raises
    ------
    OSError
        The parent cannot be created or written, or 1000 names of this second are taken.
    """
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(time.time() if now_s is None else now_s))
    Path(root).mkdir(parents=True, exist_ok=True)
    for k in range(1, _MAX_SAME_SECOND + 1):
        path = Path(root) / (f"{prefix}-{stamp}" if k == 1 else f"{prefix}-{stamp}-{k}")
        try:
            os.mkdir(path)  # atomic: exactly one caller creates it
        except FileExistsError:
            continue
        return path
    raise FileExistsError(f"{_MAX_SAME_SECOND} log directories {prefix}-{stamp}-* exist already in {str(root)!r}")


def mission_log_dir(log_dir: Path | None, prefix: str, now_s: float | None = None) -> tuple[Path | None, str | None]:
    """The log directory of a new mission: ``log_dir`` (``--log-dir``) or a new default one.

    Parameters
    ----------
    log_dir : Path or None
        The operator's ``--log-dir``; None: a new ``swarmseek-logs/PREFIX-TIME[-k]``.
    prefix : str
        The command (``run``, ``fly``).
    now_s : float, optional
        Unix time of a default directory's name (default: now).

    Returns
    -------
    tuple
        ``(directory, None)``, the directory created and writable with its ``mission.jsonl``
        ours (created here, or an empty one left by a mission that wrote nothing), or
        ``(None, reason)``: a one-line reason (an invalid option, exit status 2).
    """
    if log_dir is None:
        try:
            log_dir = new_log_dir(DEFAULT_LOG_ROOT, prefix, now_s)
        except OSError as exc:
            return None, f"cannot create a log directory in {str(DEFAULT_LOG_ROOT)!r}: {exc.strerror or exc}"
    problem = output_dir_problem(log_dir, "log directory (--log-dir)")
    if problem:
        return None, problem
    log = Path(log_dir) / "mission.jsonl"
    try:
        with open(log, "x"):  # exclusive: a mission started at the same time on this --log-dir fails here
            pass
    except FileExistsError:
        if log.is_file() and log.stat().st_size == 0:
            return Path(log_dir), None
        return None, (f"the log directory {str(log_dir)!r} already holds a mission log (mission.jsonl): give a new "
                      f"--log-dir (`swarmseek resume {log}` continues that mission)")
    except OSError as exc:
        return None, f"cannot create {str(log)!r}: {exc.strerror or exc}"
    return Path(log_dir), None


def writable_file_problem(path: Path, what: str) -> str | None:
    """Check that an existing file ``path`` can be appended to and that its directory is writable.

    Returns
    -------
    str or None
        None when writable; else a one-line reason (a missing file is left to the caller).
    """
    path = Path(path)
    if not os.path.exists(path):  # os.path: False, not OSError, for a name too long
        return None
    if os.path.isdir(path):
        return f"the {what} {str(path)!r} is a directory, not a file"
    if not os.access(path, os.W_OK):
        return f"cannot write to the {what} {str(path)!r}: permission denied"
    return output_dir_problem(path.parent, f"directory of the {what}")


def announce_log(command: str, log_path: Path, json_mode: bool) -> bool:
    """Tell the operator where the mission log is, before the mission starts: on stdout, or on
    stderr with ``--json`` (stdout is then the JSON summary only).

    The terminal is best effort: a closed stream is not a reason to stop (the log itself is the
    record); returns False when the line could not be written.
    """
    import sys

    stream = sys.stderr if json_mode else sys.stdout
    try:
        print(f"swarmseek {command}: mission log: {log_path}", file=stream, flush=True)
    except (OSError, ValueError):  # closed pipe / closed file: nothing to show it on
        return False
    return True


def summary_log_line(log_path: Path, json_mode: bool) -> bool:
    """The final summary's last line: where the mission log is and what to do with it (not with
    ``--json``: stdout is the JSON). Best effort, as :func:`announce_log`."""
    if json_mode:
        return True
    try:
        print(f"  mission log: {log_path}  (swarmseek plot {log_path} --out DIR; "
              f"swarmseek audit {Path(log_path).parent})", flush=True)
    except (OSError, ValueError):  # closed pipe / closed file
        return False
    return True
