"""Shared helper of the real-SITL tests: find the SITL build, or skip (fail in CI) by name.

``require_sitl("px4")`` / ``require_sitl("ardupilot")`` returns the SITL folder named by
``SWARMSEEK_PX4_SITL`` / ``SWARMSEEK_ARDUPILOT_SITL``. When the variable is unset or the build is
absent the test is skipped with a message naming the variable; under ``CI=true`` that is a
failure instead, so CI can never pass by skipping the real autopilots.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from mission.sim.sitl_settings import SitlSetupError, resolve_sitl_dir

__all__ = ["in_ci", "require_sitl", "audit_failure_context", "mission_story"]


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


def audit_failure_context(log_dir: Path) -> str:
    """For a failed audit: each listed violation with the mission phase and iteration it fell in.

    A real-SITL run that breaks the audit is rare and its logs go with the test's temporary
    folder, so the assertion message carries where in the mission each violation happened.
    """
    audit = subprocess.run([sys.executable, "-m", "mission", "audit", str(log_dir), "--json"],
                           capture_output=True, text=True, timeout=300)
    try:
        violations = json.loads(audit.stdout)["violations"]
    except (ValueError, KeyError, TypeError):
        return f"(audit --json unreadable: {audit.stderr[-500:]})"
    marks = []
    with open(Path(log_dir) / "mission.jsonl", encoding="utf-8") as f:
        for line in f:
            try:
                r = json.loads(line)
            except ValueError:
                continue
            if r.get("type") == "phase":
                marks.append((r["t_s"], "phase", r.get("phase")))
            elif r.get("type") == "iteration":
                marks.append((r["t_s"], "iteration", r.get("k")))
    start = marks[0][0] if marks else 0.0
    lines = []
    for v in violations[:20]:
        t_s = float(v["t_s"])
        before = [m for m in marks if m[0] <= t_s]
        phase = next((m[2] for m in reversed(before) if m[1] == "phase"), "?")
        k = next((m[2] for m in reversed(before) if m[1] == "iteration"), "-")
        lines.append(f"{v['kind']} at {t_s - start:.2f} s after the first phase, vehicles {v.get('sysids')}: "
                     f"{v.get('detail')} (phase {phase}, iteration {k})")
    return "\n".join(lines) or "(no violation listed)"


def mission_story(log_dir: Path, limit_chars: int = 1500) -> str:
    """The mission's phases and its warning and error events, one short line each, for a failed
    real-SITL mission's assertion message.

    CI shows only the start and the end of a long assertion message; this goes first, so why a
    mission ended (a vehicle lost, a failsafe, a takeoff timeout) is in the part that is shown. Join
    it into a *string* message: pytest shortens the repr of any other message (a tuple) to 240
    characters (a CI run once showed only a story's first two lines).
    """
    from mission.telemetry.mission_log import read_mission_log

    try:
        records = read_mission_log(Path(log_dir) / "mission.jsonl")
    except (OSError, ValueError) as exc:
        return f"(no mission log: {exc})"
    start, story = None, []
    for r in records:
        if "t_s" not in r:
            continue
        start = r["t_s"] if start is None else start
        at = f"{r['t_s'] - start:7.1f} s"
        if r.get("type") == "phase":
            story.append(f"{at} phase {r.get('phase')} {r.get('outcome') or ''}".rstrip())
        elif (r.get("type") == "event" and r.get("level") in ("warning", "error")
              and not str(r.get("message")).startswith("MAVLink frames rejected")):  # routine on real PX4
            story.append(f"{at} {r['level']}: {str(r.get('message'))[:160]}")
    text = "\n".join(story) or "(no phase or warning in the mission log)"
    return text if len(text) <= limit_chars else text[:limit_chars // 3] + "\n...\n" + text[-2 * limit_chars // 3:]
