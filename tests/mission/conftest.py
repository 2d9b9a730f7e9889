"""Fixtures shared by the ground station's tests."""
from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

#: the sample plan of README.md and docs/mission.md
SAMPLE_PLAN = Path(__file__).resolve().parents[2] / "mission" / "examples" / "sitl_plan.toml"


@pytest.fixture
def doc() -> dict:
    """The sample plan (``mission/examples/sitl_plan.toml``) as a fresh TOML table, for a test to change."""
    return tomllib.loads(SAMPLE_PLAN.read_text())
