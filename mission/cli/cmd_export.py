"""``swarmseek export LOG --kml OUT | --geojson OUT``: a flown mission for Google Earth or QGIS.

Writes the mission of a mission log (``mission.jsonl``, or the log directory holding it): every
vehicle's track, the formation centre's, the geofence, the start point, the estimate and its
95 % region, the true source of a simulated run (:mod:`mission.telemetry.geo_export`). Exit
status: 0 written; 2 a bad argument (no such log, not a mission log, one without a plan record,
an output that cannot be written).
"""
from __future__ import annotations

import argparse
from pathlib import Path

from mission.telemetry.geo_export import GeoExportError, mission_geometry, write_geojson, write_kml
from mission.telemetry.mission_log import read_mission_log
from wire.cli_args import path_arg, usage_error

__all__ = ["configure", "main"]

_PROG = "swarmseek export"


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``export`` options."""
    parser.add_argument("log", type=path_arg, help="mission log (mission.jsonl, or its log directory)")
    parser.add_argument("--kml", type=path_arg, default=None, metavar="OUT",
                        help="write a KML file (Google Earth; altitudes above sea level)")
    parser.add_argument("--geojson", type=path_arg, default=None, metavar="OUT",
                        help="write a GeoJSON file (RFC 7946, [lon, lat]; QGIS)")


def _output_problem(path: Path) -> str | None:
    """Why ``path`` cannot be written as an output file, or None."""
    if path.is_dir():
        return f"{path} is a directory, not an output file"
    if not path.parent.is_dir():
        return f"{path}: no such directory {str(path.parent)!r}"
    return None


def main(args) -> int:
    """Export the mission log; 0 written, 2 bad input."""
    if args.kml is None and args.geojson is None:
        return usage_error(_PROG, "give --kml OUT and/or --geojson OUT")
    log = args.log / "mission.jsonl" if args.log.is_dir() else args.log
    if not log.is_file():
        return usage_error(_PROG, f"{log}: no such mission log")
    for out in (args.kml, args.geojson):
        problem = None if out is None else _output_problem(out)
        if problem:
            return usage_error(_PROG, problem)
    try:
        geo = mission_geometry(read_mission_log(log))
    except OSError as exc:
        return usage_error(_PROG, f"{log}: cannot read: {exc.strerror or exc}")
    except (GeoExportError, ValueError) as exc:
        return usage_error(_PROG, f"{log}: {exc}")
    try:
        written = [w(geo, out) for w, out in ((write_kml, args.kml), (write_geojson, args.geojson)) if out is not None]
    except OSError as exc:
        return usage_error(_PROG, f"cannot write: {exc}")
    for path in written:
        print(path)
    return 0
