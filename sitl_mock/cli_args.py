"""The simulated field's command-line flags, shared by ``mock``, ``sensor`` and ``run``.

:func:`add_field_arguments` adds them, :func:`field_from_args` builds the field; the argument
types are :mod:`wire.cli_args`'s.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from wire.cli_args import finite_float, int_in_range, nonnegative_float, path_arg, positive_float, source_enu

__all__ = ["add_field_arguments", "field_from_args"]

# ----------------------------------------------------------------------------- field flags
#: the horizontal fence whose corners probe a plug-in when the command has no plan fence, E, N m
DEFAULT_PROBE_FENCE_EN_M = ((-150.0, -150.0), (150.0, -150.0), (150.0, 150.0), (-150.0, 150.0))
#: flag destination -> field parameter (None: a sensor setting)
_FIELD_FLAGS = {
    "wind_from": "wind_from_deg", "wind_speed": "wind_speed_m_s", "stability": "stability",
    "source_radius": "source_radius_m", "emission_rate": "emission_rate", "background": "background",
    "field_seed": "seed", "release_rate": "release_rate_hz", "meander_time": "meander_time_s",
}


def add_field_arguments(parser: argparse.ArgumentParser, default: str) -> None:
    """The field and sensor-response flags of ``mock``, ``sensor`` and ``run`` (``--field``
    defaults to ``default``; ``--source`` stays each command's own). See ``docs/fields.md``."""
    from sitl_mock.fields_config import FIELD_NAMES
    from sitl_mock.fields_plume import STABILITY_CLASSES

    g = parser.add_argument_group("simulated field (docs/fields.md)")
    g.add_argument("--field", choices=FIELD_NAMES, default=None,
                   help=(f"signal field the sensors sample (default {default}, or the --field-config's type)"
                         if default else "signal field the sensors sample (or give --field-config)"))
    g.add_argument("--field-config", type=path_arg, default=None, metavar="PATH",
                   help="TOML file (e.g. the mission plan) whose [field] table gives the field; flags override it")
    g.add_argument("--field-python", default=None, metavar="PKG.MODULE:FACTORY",
                   help="your own field: a factory importable from sys.path (run from its directory or set "
                        "PYTHONPATH), called with the [field] table of --field-config (docs/fields.md)")
    g.add_argument("--field-npz", type=path_arg, default=None, metavar="PATH",
                   help="gridded concentration frames over time (.npz; docs/fields.md, \"Gridded data\")")
    g.add_argument("--extra-source", type=source_enu, action="append", default=[], metavar="E,N,U",
                   help="another source of the same kind (multi-source field; repeatable)")
    g.add_argument("--wind-from", type=finite_float, default=None, metavar="DEG",
                   help="plumes: direction the wind blows from, degrees clockwise from north (default 270)")
    g.add_argument("--wind-speed", type=positive_float, default=None, metavar="M_S",
                   help="plumes: wind speed, m/s (default 2)")
    g.add_argument("--stability", choices=STABILITY_CLASSES, default=None,
                   help="plumes: Pasquill-Gifford stability class of the spreads (default C)")
    g.add_argument("--source-radius", type=positive_float, default=None, metavar="M",
                   help="plumes: spread at the release point, m (default 1)")
    g.add_argument("--emission-rate", type=positive_float, default=None, metavar="Q",
                   help="plumes: emission rate (default: the plume is 1 at the release)")
    g.add_argument("--background", type=nonnegative_float, default=None, metavar="VALUE",
                   help="plumes: constant background value (default 1e-4)")
    g.add_argument("--no-ground-reflection", action="store_true", help="plumes: no image source below ground")
    g.add_argument("--field-seed", type=int_in_range(0, None, "--field-seed"), default=None, metavar="N",
                   help="intermittent plume: seed of the puffs and the meander (default 0)")
    g.add_argument("--release-rate", type=positive_float, default=None, metavar="HZ",
                   help="intermittent plume: puffs per second (default 2 x wind speed / source radius)")
    g.add_argument("--meander-time", type=positive_float, default=None, metavar="S",
                   help="intermittent plume: correlation time of the wind meander, s (default 5)")
    g.add_argument("--sensor-tau", type=nonnegative_float, default=None, metavar="S",
                   help="sensor response time constant (first-order lag), s (default 0: instantaneous)")
    g.add_argument("--detection-floor", type=nonnegative_float, default=None, metavar="VALUE",
                   help="readings below this report 0 (default 0: no floor)")
    parser.set_defaults(field_default=default)


def field_kind(args: argparse.Namespace) -> str:
    """``"python"``, ``"grid"`` or ``"builtin"``: the kind of field the flags (and the
    ``--field-config``'s ``[field]`` table) describe. A ``--field-config`` that cannot be read
    counts as built-in (:func:`field_from_args` reports it)."""
    from sitl_mock.fields_config import read_field_table

    if getattr(args, "field", None):
        return "builtin"
    if getattr(args, "field_python", None):
        return "python"
    if getattr(args, "field_npz", None):
        return "grid"
    try:
        table = read_field_table(args.field_config) if args.field_config else {}
    except ValueError:
        return "builtin"
    return "python" if "python" in table else "grid" if table.get("type") == "grid" else "builtin"


def _field_table(args: argparse.Namespace) -> tuple[dict, str]:
    """The ``[field]`` table the flags describe (the ``--field-config``'s, overridden) and the kind."""
    from sitl_mock.fields_config import read_field_table

    chosen = [f for f, d in (("--field", "field"), ("--field-python", "field_python"), ("--field-npz", "field_npz"))
              if getattr(args, d, None)]
    if len(chosen) > 1:
        raise ValueError(f"give one of {', '.join(chosen)}, not several")
    table = dict(read_field_table(args.field_config)) if args.field_config else {}
    npz = table.get("npz")
    if args.field_config and isinstance(npz, str) and npz and not Path(npz).is_absolute():
        table["npz"] = str(Path(args.field_config).parent / npz)  # relative to the file that names it
    kind = field_kind(args)
    if args.field:
        table = {k: v for k, v in table.items() if k not in ("python", "npz")}
        table["type"] = args.field
    elif getattr(args, "field_python", None):
        table.pop("type", None)
        table["python"] = args.field_python
    elif getattr(args, "field_npz", None):
        table = {k: v for k, v in table.items() if k.startswith("sensor_")}
        table.update(type="grid", npz=str(args.field_npz))
    elif kind == "builtin":
        table["type"] = table.get("type") or args.field_default
    return table, kind


def field_from_args(args: argparse.Namespace, source):
    """``(name, field, response)`` from the flags of :func:`add_field_arguments` and the
    command's ``source`` (None: the ``--field-config``'s ``source_enu_m``, else 0, 0, 0; a plug-in
    gets it as its table's ``source_enu_m``).

    ``response`` holds the ``time_constant_s`` / ``detection_floor`` keywords of
    :func:`sitl_mock.sensor_response.set_fleet_response`. A plug-in or grid field (``name``
    ``python:pkg.module:factory`` or ``grid``) is not probed here: see
    :func:`sitl_mock.fields_plugin.probe_field`.

    Raises
    ------
    ValueError
        The flags do not fit the field (e.g. ``--wind-from`` for ``sigma2``), or the
        ``--field-config`` file or a value is invalid; the message names the flag or key.
        :class:`~sitl_mock.fields_plugin.FieldPluginError` for a plug-in or data file that cannot serve.
    """
    from sitl_mock.fields_config import FIELD_PARAMS, field_from_table
    from sitl_mock.fields_plugin import FieldPluginError

    table, kind = _field_table(args)
    name = {"python": f"python:{table.get('python')}", "grid": "grid"}.get(kind, table.get("type"))
    if source is not None:
        if kind == "grid":
            raise ValueError("--source does not apply to a grid field (its source is the file's source_enu_m)")
        table["source_enu_m"] = tuple(source)
    if args.extra_source:
        if kind != "builtin":
            raise ValueError(f"--extra-source does not apply to the {name} field")
        table["extra_sources_enu_m"] = [tuple(s) for s in args.extra_source]
        table.pop("strengths", None)
    flags = {dest: getattr(args, dest) for dest in _FIELD_FLAGS if getattr(args, dest) is not None}
    if args.no_ground_reflection:
        flags["no_ground_reflection"] = True
    allowed = FIELD_PARAMS.get(table.get("type"), ()) if kind == "builtin" else ()
    for dest in flags:
        param = _FIELD_FLAGS.get(dest, "ground_reflection")
        if param not in allowed:
            raise ValueError(f"--{dest.replace('_', '-')} does not apply to the {name} field")
        table[param] = flags[dest] if dest in _FIELD_FLAGS else False
    if args.sensor_tau is not None:
        table["sensor_time_constant_s"] = args.sensor_tau
    if args.detection_floor is not None:
        table["sensor_detection_floor"] = args.detection_floor
    try:
        field, response = field_from_table(table)
    except FieldPluginError:
        raise  # one line that names the plug-in or the file already
    except ValueError as exc:
        raise ValueError(f"{args.field_config}: {exc}" if args.field_config else str(exc)) from None
    return name, field, response


def probe_custom_field(field, t0_s: float, points_enu_m=None) -> None:
    """Probe a plug-in or grid field (:func:`sitl_mock.fields_plugin.probe_field`) before anything
    is armed or connected; a built-in field is not probed. ``points_enu_m`` default: the corners and
    centre of ``swarmseek run``'s fence (E, N within +-150 m, 2 to 80 m up), the origin and the
    field's source.

    Raises
    ------
    FieldPluginError
        One line naming the plug-in or file.
    """
    from sitl_mock.fields_grid import GridField
    from sitl_mock.fields_plugin import PluginField, probe_field, probe_points_enu

    if not isinstance(field, (PluginField, GridField)):
        return
    if points_enu_m is None:
        points_enu_m = probe_points_enu(DEFAULT_PROBE_FENCE_EN_M, 2.0, 80.0,
                                        extra=[(0.0, 0.0, 0.0), field.source_enu()])
    probe_field(field, points_enu_m, t0_s)
