"""How a mission log ends, and what ``swarmseek resume`` does with each ending (docs/faults.md).

A log is one or more *sessions*, each opened by a ``plan`` record (a resume appends one with
``resumed: true``). The last session that reached a deciding phase decides (a resumed session
stopped while it reconnected, with only ``connect`` behind it, leaves the decision to the one
before). In a session:

=====================  ==============================================================  =========
ending                 what the session's records show                                 resume
=====================  ==============================================================  =========
``finished``           a ``finish`` phase (converged, max_iterations, stopped_at_fence,  home
                       too_few_vehicles), whatever follows (return, done, summary)
``returning``          a ``return`` phase without ``finish`` (an operator's land/rtl,   home
                       the return after an abort or an interrupt)
``aborted``            an ``aborted`` phase not from an interrupt: a MissionError        home
                       (preflight failed, no readings, an operator's stop...) or an
                       unexpected error, with or without the return/done/summary after
``interrupted``        an ``aborted`` phase from an interrupt (Ctrl-C, SIGTERM, a         home
                       cancelled task) with the return the default ground station flies
``stopped``            an interrupt of a ground station told to just stop               seek on
                       (``return_on_interrupt = False``: no return, the vehicles hold)
``cut``                the last phase is ``takeoff``, ``assemble`` or ``seek`` and        seek on
                       nothing closes it (killed, crashed, power lost)
``before_takeoff``     only ``connect`` / ``preflight``: no formation was planned,       refused
                       nothing can be flying
=====================  ==============================================================  =========

A record cut in the middle (the last line of a killed process) is skipped by
:func:`mission.telemetry.mission_log.iter_mission_log`: the log ends with the record before it.
``done`` and a ``summary`` never decide by themselves: the phase before them does.
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["ENDINGS", "Ending", "classify_ending"]

#: ending -> the seek goes on (True) or the vehicles still flying are brought home (False)
ENDINGS = {"finished": False, "returning": False, "aborted": False, "interrupted": False,
           "stopped": True, "cut": True, "before_takeoff": False}
_FLYING = ("takeoff", "assemble", "seek")
_NOT_DECIDING = ("connect", "preflight", "done")
#: the event :meth:`mission.flight.phases.mission_end.MissionEnd.run` writes when a ground station told to just stop
#: is interrupted (older logs have no ``returning`` field in their ``aborted`` phase record)
_JUST_STOPS = "the ground station stops; the vehicles do what their autopilots do"


@dataclass(frozen=True)
class Ending:
    """How a log ends: ``name`` (a key of :data:`ENDINGS`), ``go_on`` (seek on), ``last_phase``
    (the last phase of the deciding session) and ``detail`` (the abort's reason, the outcome...)."""

    name: str
    go_on: bool
    last_phase: str
    detail: str = ""


def _sessions(records: list[dict]) -> list[list[dict]]:
    """The records split at each ``plan`` record (records before the first one join the first)."""
    out: list[list[dict]] = [[]]
    for r in records:
        is_plan = r.get("type") == "plan" and not r.get("dry_run")
        if is_plan and any(x.get("type") == "plan" for x in out[-1]):
            out.append([])
        out[-1].append(r)
    return out


def _interrupt_without_return(session: list[dict], aborted: dict) -> bool:
    """The ``aborted`` phase record is an interrupt of a ground station told to just stop."""
    if "returning" in aborted:
        return not aborted["returning"]
    return any(r.get("type") == "event" and _JUST_STOPS in str(r.get("message", "")) for r in session)


def _session_ending(session: list[dict]) -> Ending | None:
    """The ending of one session, or None when it reached no deciding phase."""
    phases = [r for r in session if r.get("type") == "phase"]
    names = [p.get("phase", "") for p in phases]
    if "finish" in names:
        finish = next(p for p in phases if p.get("phase") == "finish")
        return Ending("finished", False, names[-1], str(finish.get("outcome", "")))
    aborted = next((p for p in phases if p.get("phase") == "aborted"), None)
    if aborted is not None:
        reason = str(aborted.get("reason", ""))
        if reason.startswith("interrupted"):
            if _interrupt_without_return(session, aborted) and "return" not in names:
                return Ending("stopped", True, names[-1], reason)
            return Ending("interrupted", False, names[-1], reason)
        return Ending("aborted", False, names[-1], reason)
    if "return" in names:
        return Ending("returning", False, names[-1])
    flown = [n for n in names if n not in _NOT_DECIDING]
    if flown and flown[-1] in _FLYING:
        return Ending("cut", True, flown[-1])
    return None


def classify_ending(records: list[dict]) -> Ending:
    """How the log whose records are ``records`` ends (module docstring); ``before_takeoff`` when
    no session reached a deciding phase."""
    for session in reversed(_sessions(records)):
        ending = _session_ending(session)
        if ending is not None:
            return ending
    phases = [r.get("phase", "") for r in records if r.get("type") == "phase"]
    return Ending("before_takeoff", False, phases[-1] if phases else "")
