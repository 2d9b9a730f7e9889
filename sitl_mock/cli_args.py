"""argparse argument types shared by the ``mock`` and ``sensor`` commands.

Each raises :class:`argparse.ArgumentTypeError` with a message that names what was expected,
so a bad flag is a one-line argparse error (exit 2), never a traceback.
"""
from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path

__all__ = [
    "floats",
    "source_enu",
    "origin_geodetic",
    "positive_float",
    "nonnegative_float",
    "int_in_range",
    "zenoh_endpoint",
    "output_dir_problem",
]


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


def zenoh_endpoint(text: str) -> str:
    """A zenoh endpoint ``PROTO/ADDRESS`` (e.g. ``tcp/127.0.0.1:7447``), checked by zenoh's config."""
    from sitl_mock.sensor import zenoh_config

    try:
        zenoh_config(listen=text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    except ImportError:  # zenoh missing: reported when the session is opened
        pass
    return text


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
    if path.exists() and not path.is_dir():
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
