"""Where the real SITL builds are: environment variables, CLI overrides and clear errors.

The project never hard-codes the location of a SITL install. A user (or CI) points at it with

* ``SWARMSEEK_PX4_SITL``: a PX4 SITL folder with the SIH quadrotor (``bin/px4`` and the
  ``etc/`` ROMFS with ``etc/init.d-posix/rcS``), e.g. the ``px4-sih`` bundle;
* ``SWARMSEEK_ARDUPILOT_SITL``: an ArduCopter SITL folder (``bin/arducopter`` and the SITL
  default parameters ``copter.parm``).

A CLI flag (``swarmseek sitl --sitl-dir DIR``) overrides the variable. A missing or wrong
setting raises :class:`SitlSetupError` whose message names the variable and what is missing.
"""
from __future__ import annotations

import os
from pathlib import Path

__all__ = ["FLAVOURS", "ENV_VARS", "SitlSetupError", "resolve_sitl_dir", "required_files"]

#: supported SITL flavours
FLAVOURS = ("px4", "ardupilot")
#: flavour -> environment variable naming its SITL folder
ENV_VARS = {"px4": "SWARMSEEK_PX4_SITL", "ardupilot": "SWARMSEEK_ARDUPILOT_SITL"}


class SitlSetupError(RuntimeError):
    """The SITL build cannot be used: unset or wrong setting, missing file, failed start."""


def required_files(flavour: str) -> tuple[str, ...]:
    """Paths (relative to the SITL folder) that must exist for ``flavour``."""
    if flavour == "px4":
        return ("bin/px4", "etc/init.d-posix/rcS")
    if flavour == "ardupilot":
        return ("bin/arducopter", "copter.parm")
    raise SitlSetupError(f"unknown SITL flavour {flavour!r}: expected one of {', '.join(FLAVOURS)}")


def resolve_sitl_dir(flavour: str, override: str | os.PathLike | None = None,
                     environ: dict | None = None) -> Path:
    """The SITL folder of ``flavour``: ``override`` (a CLI flag) or its environment variable.

    Parameters
    ----------
    flavour : str
        ``"px4"`` or ``"ardupilot"``.
    override : path-like, optional
        A folder given on the command line; wins over the environment.
    environ : dict, optional
        The environment to read (default ``os.environ``).

    Returns
    -------
    Path
        The absolute, checked folder.

    Raises
    ------
    SitlSetupError
        Unknown flavour, the variable unset, the folder missing or without the expected files;
        the message names the variable (or the flag) and the missing path.
    """
    files = required_files(flavour)
    var = ENV_VARS[flavour]
    env = os.environ if environ is None else environ
    if override is not None and str(override) != "":
        origin = "--sitl-dir"
        raw = str(override)
    else:
        raw = env.get(var, "")
        origin = var
        if not raw:
            raise SitlSetupError(
                f"{var} is not set: point it at the {flavour} SITL folder (containing "
                f"{' and '.join(files)}), e.g. export {var}=/path/to/sitl (docs/sitl.md)")
    path = Path(raw).expanduser().resolve()
    if not path.is_dir():
        raise SitlSetupError(f"{origin}={raw!r}: no such folder (expected the {flavour} SITL folder)")
    missing = [f for f in files if not (path / f).exists()]
    if missing:
        raise SitlSetupError(f"{origin}={raw!r} is not a {flavour} SITL folder: missing "
                             f"{', '.join(missing)}")
    binary = path / files[0]
    if not os.access(binary, os.X_OK):
        raise SitlSetupError(f"{origin}={raw!r}: {binary} is not executable")
    return path
