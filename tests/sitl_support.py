"""Shared helper of the real-SITL tests: find the SITL build, or skip (fail in CI) by name.

``require_sitl("px4")`` / ``require_sitl("ardupilot")`` returns the SITL folder named by
``SWARMSEEK_PX4_SITL`` / ``SWARMSEEK_ARDUPILOT_SITL``. When the variable is unset or the build is
absent the test is skipped with a message naming the variable; under ``CI=true`` that is a
failure instead, so CI can never pass by skipping the real autopilots.
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from mission.sim.sitl_settings import SitlSetupError, resolve_sitl_dir

__all__ = ["in_ci", "require_sitl"]


def in_ci() -> bool:
    """True when the ``CI`` environment variable says so (``true``/``1``/``yes``)."""
    return os.environ.get("CI", "").strip().lower() in ("true", "1", "yes")


def require_sitl(flavour: str) -> Path:
    """The SITL folder of ``flavour``, or skip (outside CI) / fail (in CI) naming the variable."""
    try:
        return resolve_sitl_dir(flavour)
    except SitlSetupError as exc:
        message = f"real {flavour} SITL not available: {exc}"
        if in_ci():
            pytest.fail(f"{message} (CI=true: a skipped SITL test is a failure)", pytrace=False)
        pytest.skip(message)
