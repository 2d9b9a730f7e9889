"""The simulated field's command-line flags, shared by ``mock``, ``sensor`` and ``run``.

:func:`add_field_arguments` adds them, :func:`field_from_args` builds the field; the argument
types are :mod:`wire.cli_args`'s.
"""
from __future__ import annotations

import argparse

from wire.cli_args import finite_float, int_in_range, nonnegative_float, path_arg, positive_float, source_enu

__all__ = ["add_field_arguments", "field_from_args"]

# ----------------------------------------------------------------------------- field flags
#: flag destination -> field parameter (None: a sensor setting)
_FIELD_FLAGS = {
    "wind_from": "wind_from_deg", "wind_speed": "wind_speed_m_s", "stability": "stability",
    "source_radius": "source_radius_m", "emission_rate": "emission_rate", "background": "background",
    "field_seed": "seed", "release_rate": "release_rate_hz", "meander_time": "meander_time_s",
}


def add_field_arguments(parser: argparse.ArgumentParser, default: str) -> None:
    """The field and sensor-response flags of ``mock``, ``sensor`` and ``run`` (``--field``
    defaults to ``default``; ``--source`` stays each command's own). See ``docs/fields.md``."""
    from sitl_mock.fields import FIELD_NAMES, STABILITY_CLASSES

    g = parser.add_argument_group("simulated field (docs/fields.md)")
    g.add_argument("--field", choices=FIELD_NAMES, default=None,
                   help=(f"signal field the sensors sample (default {default}, or the --field-config's type)"
                         if default else "signal field the sensors sample (or give --field-config)"))
    g.add_argument("--field-config", type=path_arg, default=None, metavar="PATH",
                   help="TOML file (e.g. the mission plan) whose [field] table gives the field; flags override it")
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


def field_from_args(args: argparse.Namespace, source):
    """``(name, field, response)`` from the flags of :func:`add_field_arguments` and the
    command's ``source`` (None: the ``--field-config``'s ``source_enu_m``, else 0, 0, 0).

    ``response`` holds the ``time_constant_s`` / ``detection_floor`` keywords of
    :func:`sitl_mock.sensor_response.set_fleet_response`.

    Raises
    ------
    ValueError
        The flags do not fit the field (e.g. ``--wind-from`` for ``sigma2``), or the
        ``--field-config`` file or a value is invalid; the message names the flag or key.
    """
    from sitl_mock.fields import FIELD_PARAMS, field_from_table, read_field_table

    table = dict(read_field_table(args.field_config)) if args.field_config else {}
    table["type"] = args.field or table.get("type") or args.field_default
    if source is not None:
        table["source_enu_m"] = tuple(source)
    if args.extra_source:
        table["extra_sources_enu_m"] = [tuple(s) for s in args.extra_source]
        table.pop("strengths", None)
    flags = {dest: getattr(args, dest) for dest in _FIELD_FLAGS if getattr(args, dest) is not None}
    if args.no_ground_reflection:
        flags["no_ground_reflection"] = True
    allowed = FIELD_PARAMS.get(table["type"], ())
    for dest in flags:
        param = _FIELD_FLAGS.get(dest, "ground_reflection")
        if param not in allowed:
            raise ValueError(f"--{dest.replace('_', '-')} does not apply to the {table['type']} field")
        table[param] = flags[dest] if dest in _FIELD_FLAGS else False
    if args.sensor_tau is not None:
        table["sensor_time_constant_s"] = args.sensor_tau
    if args.detection_floor is not None:
        table["sensor_detection_floor"] = args.detection_floor
    try:
        field, response = field_from_table(table)
    except ValueError as exc:
        raise ValueError(f"{args.field_config}: {exc}" if args.field_config else str(exc)) from None
    return table["type"], field, response
