"""argparse argument types shared by the ground station's commands and the simulator's
(``mock``, ``sensor``) and the experiments: numbers in ranges, coordinates, paths, zenoh endpoints;
and the one way a command reports a problem it found after parsing (:func:`fail`,
:func:`usage_error`).

Each type raises :class:`argparse.ArgumentTypeError` with a message that names what was expected,
so a bad flag is a one-line argparse error (exit 2), never a traceback.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
from pathlib import Path

__all__ = [
    "finite_float",
    "float_in_range",
    "floats",
    "source_enu",
    "origin_geodetic",
    "positive_float",
    "nonnegative_float",
    "int_in_range",
    "zenoh_endpoint",
    "output_dir_problem",
    "path_arg",
    "path_problem",
    "fail",
    "usage_error",
    "USAGE_STATUS",
]

#: exit status of a command given invalid options or an invalid plan (argparse's own)
USAGE_STATUS = 2

#: longest path and path component the file systems we run on accept (Linux PATH_MAX, NAME_MAX)
_PATH_MAX_BYTES = 4095
_NAME_MAX_BYTES = 255


def floats(text: str, n: int, what: str) -> tuple[float, ...]:
    """``n`` comma-separated finite numbers, e.g. ``"1,2,3"``."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected {what} ({n} comma-separated finite numbers), got {text!r}")
    return values


def source_enu(text: str) -> tuple[float, ...]:
    """A source position ``E,N,U`` in metres."""
    return floats(text, 3, "E,N,U")


def origin_geodetic(text: str) -> tuple[float, ...]:
    """A geodetic origin ``LAT,LON,ALT`` (degrees, degrees, metres)."""
    lat, lon, alt = floats(text, 3, "LAT,LON,ALT")
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        raise argparse.ArgumentTypeError(
            f"origin latitude must be in [-90, 90] and longitude in [-180, 180], got {text!r}")
    return lat, lon, alt


def path_problem(text: str) -> str | None:
    """Why ``text`` cannot name a file at all (empty, a NUL byte, not encodable for the file
    system, a name or a path too long), or None: checked before any ``Path`` method, which would
    raise instead of answering."""
    if not text:
        return "expected a path, got ''"
    if "\x00" in text:
        return f"a path cannot hold a NUL byte, got {text[:60]!r}"
    try:
        raw = os.fsencode(text)
    except UnicodeError:
        return f"the path {text[:60]!r} cannot be encoded for the file system"
    if len(raw) > _PATH_MAX_BYTES or any(len(part) > _NAME_MAX_BYTES for part in raw.split(b"/")):
        return (f"the path {text[:40]!r}... is too long (at most {_NAME_MAX_BYTES} bytes a name, "
                f"{_PATH_MAX_BYTES} in all)")
    return None


def path_arg(text: str) -> Path:
    """A file or directory path that can be asked about (see :func:`path_problem`)."""
    problem = path_problem(text)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return Path(text)


def _number(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    return v


def positive_float(text: str) -> float:
    """A finite number > 0."""
    v = _number(text)
    if not (math.isfinite(v) and v > 0.0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return v


def nonnegative_float(text: str) -> float:
    """A finite number >= 0."""
    v = _number(text)
    if not (math.isfinite(v) and v >= 0.0):
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return v


def int_in_range(lo: int, hi: int | None, what: str):
    """An argument type for an integer in ``[lo, hi]`` (``hi`` None: no upper bound)."""

    def _parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if v < lo or (hi is not None and v > hi):
            bound = f"{lo}..{hi}" if hi is not None else f">= {lo}"
            raise argparse.ArgumentTypeError(f"{what} must be {bound}, got {v}")
        return v

    return _parse


def float_in_range(lo: float, hi: float):
    """An argument type for a number in ``[lo, hi]`` (NaN and infinities refused)."""

    def _parse(text: str) -> float:
        v = _number(text)
        if not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"expected a number in [{lo:g}, {hi:g}], got {text!r}")
        return v

    return _parse


def zenoh_endpoint(text: str) -> str:
    """A zenoh endpoint ``PROTO/ADDRESS`` (e.g. ``tcp/127.0.0.1:7447``), checked by zenoh's config."""
    from wire.zenoh_config import zenoh_config

    try:
        zenoh_config(listen=text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    except ImportError:  # zenoh missing: reported when the session is opened
        pass
    return text


def finite_float(text: str) -> float:
    """A finite number (NaN and infinities refused)."""
    v = _number(text)
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return v


def output_dir_problem(path: Path, what: str) -> str | None:
    """Create ``path`` (with its parents) and check that files can be written in it.

    Parameters
    ----------
    path : Path
        The directory (``--log-dir``, ``--out``).
    what : str
        What it is for, used in the message (``"log directory"``, ``"output directory"``).

    Returns
    -------
    str or None
        None when the directory exists and is writable, else a one-line reason.
    """
    path = Path(path)
    if os.path.exists(path) and not os.path.isdir(path):  # os.path: False, not OSError, for a name too long
        return f"the {what} {str(path)!r} exists and is not a directory"
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        return f"cannot create the {what} {str(path)!r}: {exc.strerror or exc}"
    try:
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        return f"cannot write in the {what} {str(path)!r}: {exc.strerror or exc}"
    return None


def fail(prog: str, message: str, status: int = USAGE_STATUS) -> int:
    """Print ``"{prog}: {message}"`` as one line on stderr and return ``status`` (the command's
    exit status: :data:`USAGE_STATUS` for invalid options or plans, 1 for a failure at run time)."""
    print(f"{prog}: {message}", file=sys.stderr)
    return status


def usage_error(prog: str, problem: str) -> int:
    """``"{prog}: error: {problem}"`` on stderr, as argparse words its own errors; returns 2."""
    return fail(prog, f"error: {problem}")
