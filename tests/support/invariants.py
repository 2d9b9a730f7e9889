"""The never-abandon invariant, checked against the mock fleet's ground truth.

Every vehicle the ground station armed ends the mission disarmed or on the ground, or flying a
landing behaviour of its autopilot (LAND or RTL), or it is named in an ``airborne_left`` record
of the mission log (the operator was told). :func:`check_never_abandoned` asserts it;
``fly_helpers.run_fleet`` calls it after every mission it flies.
"""
from __future__ import annotations

from pathlib import Path

from mission.telemetry.mission_log import read_mission_log

__all__ = ["abandoned", "check_never_abandoned", "reported_airborne"]

#: mock behaviours that bring a vehicle down by themselves
LANDING_BEHAVIOURS = ("land", "rtl")


def reported_airborne(log_path) -> set[int]:
    """Sysids named in the ``airborne_left`` records of a mission log."""
    if log_path is None or not Path(log_path).exists():
        return set()
    return {int(v["sysid"]) for r in read_mission_log(log_path) if r["type"] == "airborne_left"
            for v in r["vehicles"]}


def abandoned(fleet, log_path=None) -> list[str]:
    """The mock vehicles that break the invariant (empty: none), described."""
    told = reported_airborne(log_path)
    out = []
    for v in fleet.vehicles:
        ap = v.autopilot
        if not ap.armed or ap.mc.landed or ap.behaviour in LANDING_BEHAVIOURS or v.sysid in told:
            continue
        out.append(f"vehicle {v.sysid} armed in {v.mode_name} at {v.true_position_enu().round(1)} m, "
                   "not reported")
    return out


def check_never_abandoned(fleet, log_path=None) -> None:
    """Assert the invariant for ``fleet`` at the end of the mission logged at ``log_path``."""
    bad = abandoned(fleet, log_path)
    assert not bad, "vehicles abandoned in the air: " + "; ".join(bad)
