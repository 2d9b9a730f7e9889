"""Typed value checks for the plan parser: every problem collected with its key path.

Private helpers of :mod:`mission.core.plan` (kept apart to keep the modules short).
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["Checker", "check_connection", "check_prior_box", "check_start_in_fence", "polygon_area", "polygon_margin_m", "join_key",
           "show_value"]


class Checker:
    """Collects problems while reading typed values out of nested mappings."""

    def __init__(self):
        self.problems: list[tuple[str, str]] = []

    def bad(self, key: str, why: str) -> None:
        self.problems.append((key, why))

    def unknown(self, table: dict, allowed: tuple[str, ...], prefix: str) -> None:
        for key in table:
            if key not in allowed:
                self.bad(join_key(prefix, key), f"unknown key (allowed: {', '.join(allowed)})")

    def number(self, table, key, prefix, default=None, *, low=None, high=None, low_open=False,
               required=False, integer=False):
        path = join_key(prefix, key)
        if key not in table:
            if required:
                self.bad(path, "required")
            return default
        v = table[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.bad(path, f"expected {'an integer' if integer else 'a number'}, got {show_value(v)}")
            return default
        if integer and not isinstance(v, int):
            self.bad(path, f"expected an integer, got {show_value(v)}")
            return default
        if not math.isfinite(v):
            self.bad(path, f"must be finite, got {v}")
            return default
        if low is not None and (v <= low if low_open else v < low):
            self.bad(path, f"must be {'>' if low_open else '>='} {low}, got {v}")
            return default
        if high is not None and v > high:
            self.bad(path, f"must be <= {high}, got {v}")
            return default
        return int(v) if integer else float(v)

    def string(self, table, key, prefix, default=None, *, choices=None, required=False):
        path = join_key(prefix, key)
        if key not in table:
            if required:
                self.bad(path, "required")
            return default
        v = table[key]
        if not isinstance(v, str) or not v.strip():
            self.bad(path, f"expected a non-empty string, got {show_value(v)}")
            return default
        if choices is not None and v not in choices:
            self.bad(path, f"must be one of {', '.join(choices)}, got {v!r}")
            return default
        return v

    def table(self, doc, key, prefix="", required=False) -> dict:
        path = join_key(prefix, key)
        if key not in doc:
            if required:
                self.bad(path, "required table missing")
            return {}
        v = doc[key]
        if not isinstance(v, dict):
            self.bad(path, f"expected a table, got {show_value(v)}")
            return {}
        return v

    def strings(self, table, key, prefix) -> tuple[str, ...]:
        path = join_key(prefix, key)
        v = table.get(key, [])
        if not isinstance(v, list) or not all(isinstance(s, str) and s for s in v):
            self.bad(path, f"expected a list of non-empty strings, got {show_value(v)}")
            return ()
        return tuple(v)

    def point(self, table, key, prefix, dims):
        path = join_key(prefix, key)
        if key not in table:
            return None
        v = table[key]
        if (not isinstance(v, list) or len(v) != dims
                or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
                           for x in v)):
            self.bad(path, f"expected {dims} finite numbers, got {show_value(v)}")
            return None
        return tuple(float(x) for x in v)


def join_key(prefix: str, key: str) -> str:
    """``prefix.key`` (or ``key`` at top level)."""
    return f"{prefix}.{key}" if prefix else key


def show_value(v: Any) -> str:
    """A short repr of a value for error messages."""
    text = repr(v)
    return text if len(text) <= 60 else text[:57] + "..."


def check_connection(uri: str) -> str | None:
    """A reason the connection string is invalid, or None; uses LINKS' parser when present."""
    try:
        from mission.core.uri import parse_connection
    except ImportError:
        parse_connection = None
    if parse_connection is not None:
        try:
            parse_connection(uri)
        except ValueError as exc:
            return str(exc)
        return None
    kinds = ("udpin:", "udpout:", "udp:", "tcp:", "tcpin:", "serial:", "/dev/")
    if not uri.startswith(kinds):
        return f"unknown connection {uri!r}; expected udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, serial:/dev/ttyX"
    return None


def polygon_area(points) -> float:
    """Signed area of a polygon given as (K, 2) vertices."""
    a = np.asarray(points, dtype=float)
    x, y = a[:, 0], a[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def polygon_margin_m(point_en, points) -> float:
    """Signed horizontal distance of ``point_en`` to a polygon's boundary: positive inside,
    negative outside (even-odd rule; (K, 2) vertices, either orientation)."""
    p = np.asarray(point_en, dtype=float)[:2]
    a = np.asarray(points, dtype=float)
    b = np.roll(a, -1, axis=0)
    inside = False
    for (x0, y0), (x1, y1) in zip(a, b):
        if (y0 > p[1]) != (y1 > p[1]) and p[0] < x0 + (p[1] - y0) * (x1 - x0) / (y1 - y0):
            inside = not inside
    d = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-12), 0.0, 1.0)
    dist = float(np.min(np.linalg.norm(a + t[:, None] * d - p, axis=1)))
    return dist if inside else -dist


def check_prior_box(c: Checker, prior_box: str, ground_alt_m: float, max_alt_m: float) -> None:
    """``[seeking] prior_box = "fence"`` needs the fence's ceiling above the ground (the box the
    ``ste`` prior is drawn in runs from the ground up to it)."""
    if prior_box == "fence" and not ground_alt_m + 0.1 < max_alt_m:
        c.bad("seeking.prior_box", f'"fence" needs the geofence ceiling ({max_alt_m:g} m) above '
              f"seeking.ground_alt_m ({ground_alt_m:g} m) + 0.1 m: no release could be inside the fence")


def check_start_in_fence(c: Checker, radius_m: float, start_enu, polygon_en_m) -> None:
    """The seeking start, and the formation of radius ``radius_m`` about it, inside the fence
    polygon (a start outside the geofence is a plan error, not a flight-time surprise)."""
    if not polygon_en_m or radius_m is None:
        return
    margin = polygon_margin_m(start_enu, polygon_en_m)
    e, n = float(start_enu[0]), float(start_enu[1])
    if margin < 0:
        c.bad("seeking.start_enu_m", f"start ({e:.1f}, {n:.1f}) m is outside the geofence polygon "
              f"({-margin:.1f} m beyond its edge)")
    elif margin < radius_m:
        c.bad("seeking.start_enu_m", f"start ({e:.1f}, {n:.1f}) m is {margin:.1f} m from the geofence edge: "
              f"the formation (radius {radius_m} m) would cross it")
