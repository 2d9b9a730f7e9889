"""Operator commands to a flying mission: a small queue the mission loop reads.

Commands (:data:`COMMANDS`) come from ``swarmseek ctl`` over zenoh
(:mod:`mission.telemetry.control_channel`) or from a key pressed in the terminal of ``run`` /
``fly``; each carries a sender id. :meth:`MissionControl.submit` decides at once whether the
command applies in the current phase and answers with an acknowledgement (accepted or rejected,
and why); the command and its answer are a ``command`` record of the mission log. The mission
loop then acts on it at its own points:

* ``pause``: the seek loop stops stepping at its next iteration boundary (:meth:`checkpoint`);
  the formation holds (the setpoints of the settled formation keep streaming) until ``continue``;
* ``continue``: the seek goes on from where it held;
* ``abort``: the mission ends now (outcome ``aborted``) and the plan's return brings the vehicles home;
* ``return``: the same through the mission's own return, said as "the operator ended the seek";
* ``land``: every airborne vehicle is commanded to LAND where it is, now (also during the return);
* ``rtl``: every airborne vehicle is commanded to the autopilot's RTL, now (also during the return).

Stops reach the phases as :class:`OperatorStop` (a :class:`~mission.flight.state.MissionError`)
raised by :meth:`check`, which :meth:`mission.flight.coordinator.Coordinator.wait_until` calls at
every poll: every phase before the return waits through it, so a stop takes effect within one
poll period. ``land`` and ``rtl`` replace the return (:class:`mission.flight.phases.return_home.ReturnHome`
asks :attr:`landing`), and interrupt one under way (:meth:`unless_landing_ordered`).
"""
from __future__ import annotations

import asyncio
import math
import re
from collections import deque
from dataclasses import dataclass

from mission.core.clock import cancel_and_wait
from mission.core.plan_types import ControlPlan
from mission.flight.services import Clock, Events, Waiter
from mission.flight.state import MissionError, MissionState
from mission.safety.gate import SafetyGate

__all__ = ["COMMANDS", "MissionControl", "OperatorStop", "Ack", "check_sender", "operator_command",
           "open_control_channel"]

#: every command an operator can send
COMMANDS = ("pause", "continue", "abort", "land", "rtl", "return")
#: phases before the return (a stop ends them; a pause holds the seek)
_BEFORE_RETURN = ("connect", "preflight", "takeoff", "assemble", "seek")
#: phases with vehicles possibly airborne and a ground station still flying them
_FLYING = _BEFORE_RETURN + ("finish", "return", "aborted")
_SENDER_RE = re.compile(r"^[A-Za-z0-9_.@:+-]{1,64}$")


def check_sender(sender) -> str | None:
    """Why ``sender`` is not a valid sender id (1-64 of ``A-Z a-z 0-9 _ . @ : + -``), or None."""
    if not isinstance(sender, str) or not _SENDER_RE.match(sender):
        return (f"invalid sender id {sender!r}: 1-64 characters among letters, digits and _ . @ : + -"
                if isinstance(sender, str) and len(sender) <= 80 else "invalid sender id")
    return None


class OperatorStop(MissionError):
    """An operator ended the mission (``abort``, ``return``, ``land`` or ``rtl``)."""

    def __init__(self, command: str, sender: str):
        self.command, self.sender = command, sender
        what = {"abort": "aborted", "return": "ended the seek; returning",
                "land": "ordered every vehicle to LAND now", "rtl": "ordered every vehicle to RTL now"}[command]
        super().__init__(f"operator {sender} {what} ({command})")


@dataclass(frozen=True)
class Ack:
    """The answer to one command."""

    command: str
    sender: str
    accepted: bool
    reason: str
    phase: str
    t_s: float

    def to_json(self) -> dict:
        """The acknowledgement as sent back to ``swarmseek ctl`` (and logged)."""
        return {"command": self.command, "sender": self.sender, "accepted": self.accepted,
                "reason": self.reason, "phase": self.phase, "t_s": self.t_s}


class MissionControl:
    """The operator-command queue of one mission (see the module docstring).

    Parameters
    ----------
    clock
        Mission clock (``time()``).
    log : mission.telemetry.mission_log.MissionLog, optional
        Every command and its answer go there as a ``command`` record.
    """

    def __init__(self, clock, log=None):
        self._clock = clock
        self._log = log
        self._paused_by: str | None = None
        self._stop: tuple[str, str] | None = None   # (command, sender) of abort / return
        self._landing: tuple[str, str] | None = None  # (land | rtl, sender)
        self._holding = False
        self._changed: asyncio.Event | None = None  # created on the running loop
        self.history: deque[dict] = deque(maxlen=100)  # the last answers (all of them are in the log)
        self.count = 0

    # ------------------------------------------------------------------ reading
    @property
    def paused(self) -> bool:
        """A ``pause`` is in force (until ``continue`` or a stop)."""
        return self._paused_by is not None

    @property
    def holding(self) -> bool:
        """The seek loop is holding the formation for a pause right now."""
        return self._holding

    @property
    def landing(self) -> str | None:
        """``"land"`` or ``"rtl"`` when the operator ordered it, else None."""
        return None if self._landing is None else self._landing[0]

    @property
    def stop(self) -> str | None:
        """The stop ordered (``abort``, ``return``, ``land``, ``rtl``), or None."""
        if self._landing is not None:
            return self._landing[0]
        return None if self._stop is None else self._stop[0]

    def snapshot(self) -> dict:
        """What the state publication and the display show."""
        last = self.history[-1] if self.history else None
        return {"paused": self.paused, "paused_by": self._paused_by, "holding": self._holding, "stop": self.stop,
                "last_command": last, "commands": self.count}

    # ------------------------------------------------------------------ commands
    def submit(self, command: str, sender: str, phase: str) -> Ack:
        """Decide on one command in ``phase``; log it and return the :class:`Ack`."""
        problem = check_sender(sender)
        if problem is None:
            accepted, reason = self._decide(command, sender, phase)
        else:
            accepted, reason, sender = False, problem, str(sender)[:80]
        ack = Ack(command=str(command)[:32], sender=sender, accepted=accepted, reason=reason, phase=phase,
                  t_s=float(self._clock.time()))
        self.history.append(ack.to_json())
        self.count += 1
        if self._log is not None:
            self._log.write("command", **{k: v for k, v in ack.to_json().items() if k != "t_s"})
        return ack

    def _decide(self, command: str, sender: str, phase: str) -> tuple[bool, str]:
        if command not in COMMANDS:
            return False, f"unknown command {str(command)[:32]!r}; commands: {', '.join(COMMANDS)}"
        if phase not in _FLYING:
            return False, f"no mission in flight (phase {phase})"
        if command in ("land", "rtl"):
            return self._decide_landing(command, sender)
        if self.stop is not None:
            return False, f"the mission is already ending ({self.stop})"
        if phase not in _BEFORE_RETURN:
            return False, f"the mission is already returning (phase {phase})"
        if command == "pause":
            if self.paused:
                return False, f"already paused (by {self._paused_by})"
            self._paused_by = sender
            when = "now" if phase == "seek" else "once the formation is assembled"
            return True, f"the formation holds {when} (at the end of the current iteration)"
        if command == "continue":
            if not self.paused:
                return False, "not paused"
            self._paused_by = None
            return True, "the seek goes on"
        self._stop = (command, sender)
        self._paused_by = None
        return True, ("the mission ends now; the plan's return brings the vehicles home" if command == "abort"
                      else "the seek ends now; the mission's return brings the vehicles home")

    def _decide_landing(self, command: str, sender: str) -> tuple[bool, str]:
        current = self.landing
        if current == command:
            return False, f"{command} already ordered (by {self._landing[1]})"
        if current == "land":
            return False, "LAND already ordered: it is not replaced by RTL"
        self._landing = (command, sender)
        self._paused_by = None
        if self._changed is not None:
            self._changed.set()
        return True, ("every airborne vehicle is commanded to LAND where it is" if command == "land"
                      else "every airborne vehicle is commanded to RTL (the autopilot's return)")

    # ------------------------------------------------------------------ the mission loop's side
    def check(self, phase: str) -> None:
        """Raise :class:`OperatorStop` when a stop is ordered and ``phase`` is before the return
        (at every call: a phase that catches its own wait's error meets it again at the next wait)."""
        order = self._landing or self._stop
        if order is not None and phase in _BEFORE_RETURN:
            raise OperatorStop(*order)

    async def checkpoint(self, state: MissionState, gate: SafetyGate, events: Events, clock: Clock,
                         waiter: Waiter) -> None:
        """The seek loop's iteration boundary: a stop raises, a pause holds the formation (``gate``'s
        setpoints where they are, until continued: waited for on ``waiter``)."""
        self.check(state.phase)
        if not self.paused:
            return
        by = self._paused_by
        held = {s: gate.setpoint(s) for s in gate.sysids}
        gate.set_goals(held)  # the formation is settled at its slots: hold these setpoints
        events.event(f"paused by {by}: the formation holds at iteration {state.iteration}", sender=by)
        t0 = clock.time()
        self._holding = True
        try:
            await waiter.wait_until(lambda: not self.paused, math.inf, "continue", poll_s=0.1)
        finally:
            self._holding = False
        events.event(f"continued after {clock.time() - t0:.1f} s paused", paused_s=clock.time() - t0)

    async def unless_landing_ordered(self, work, current: str | None = None) -> str | None:
        """Run ``work`` (a coroutine); when a LAND/RTL other than ``current`` is ordered meanwhile,
        cancel it and return that order (None: ``work`` finished)."""
        if self._changed is None:
            self._changed = asyncio.Event()
        task = asyncio.ensure_future(work)
        try:
            while True:
                if self.landing is not None and self.landing != current:
                    await cancel_and_wait(task)
                    return self.landing
                self._changed.clear()
                waiter = asyncio.ensure_future(self._changed.wait())
                done, _ = await asyncio.wait({task, waiter}, return_when=asyncio.FIRST_COMPLETED)
                await cancel_and_wait(waiter)
                if task in done:
                    task.result()
                    return None
        except asyncio.CancelledError:
            await cancel_and_wait(task)
            raise


def operator_command(control: MissionControl, phase: str, events: Events, command: str, sender: str,
                     state_pub=None) -> dict:
    """Submit an operator command to the mission's ``control`` in ``phase``: decided, logged
    (``events``), shown above the table and published at once (``state_pub``); returns the
    acknowledgement dict."""
    ack = control.submit(command, sender, phase)
    events.event(f"operator {ack.sender}: {ack.command} {'accepted' if ack.accepted else 'rejected'}: "
                 f"{ack.reason}", level="info" if ack.accepted else "warning")
    if state_pub is not None:
        state_pub.publish_now()
    return ack.to_json()


def open_control_channel(session, control_plan: ControlPlan, fleet: str, on_command, report):
    """The started zenoh :class:`~mission.telemetry.control_channel.ControlChannel` of the
    ``fleet`` (None without a ``session`` or with ``[control] remote = false``): each command
    goes to ``on_command(command, sender)``, a failure to ``report(message)``."""
    if session is None or not control_plan.remote:
        return None
    from mission.telemetry.control_channel import ControlChannel

    channel = ControlChannel(session, fleet, on_command, report=report)
    channel.start()
    return channel
