"""Operator commands over zenoh: the coordinator's queryable on ``swarmseek/<fleet>/mission/control``.

A command is a zenoh query (``swarmseek ctl``) on :func:`control_key` whose payload is UTF-8 JSON
``{"schema": "swarmseek.command.v1", "command": "pause", "sender": "alice@ops"}``; the answer is
one reply on the same key, UTF-8 JSON with schema ``swarmseek.command_ack.v1``: ``command``,
``sender``, ``accepted`` (bool), ``reason``, ``phase``, ``t_s`` (mission clock), ``fleet``.

Who may send one is decided by zenoh (the plan's access control: ``commander_*`` subjects; a
query from anyone else is dropped by zenoh and never reaches the coordinator); what a command
does is decided by the ``submit`` callable (:class:`mission.flight.control.MissionControl` via
the coordinator). A malformed request is answered with a rejection and counted
(:attr:`ControlChannel.bad_requests`). Queries are taken from zenoh's queue by a task on the
mission's event loop (never blocking it), so ``submit`` runs on the loop's thread.
"""
from __future__ import annotations

import asyncio
import json
from typing import Callable

from mission.core.tasks import spawn, stop_watched

__all__ = ["COMMAND_SCHEMA", "ACK_SCHEMA", "MAX_REQUEST_BYTES", "control_key", "parse_request",
           "ControlChannel"]

COMMAND_SCHEMA = "swarmseek.command.v1"
ACK_SCHEMA = "swarmseek.command_ack.v1"
MAX_REQUEST_BYTES = 2048


def control_key(fleet: str) -> str:
    """``swarmseek/<fleet>/mission/control``."""
    return f"swarmseek/{fleet}/mission/control"


def parse_request(payload: bytes) -> tuple[str, str]:
    """``(command, sender)`` of a request payload.

    Raises
    ------
    ValueError
        Too long, not UTF-8 JSON, not an object, wrong schema, or ``command`` / ``sender`` missing
        or not strings.
    """
    if len(payload) > MAX_REQUEST_BYTES:
        raise ValueError(f"request of {len(payload)} bytes, more than {MAX_REQUEST_BYTES}")
    try:
        doc = json.loads(payload.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"request is not UTF-8 JSON: {exc}") from None
    if not isinstance(doc, dict):
        raise ValueError("request is not a JSON object")
    if doc.get("schema") != COMMAND_SCHEMA:
        raise ValueError(f"request schema must be {COMMAND_SCHEMA!r}, got {str(doc.get('schema'))[:40]!r}")
    command, sender = doc.get("command"), doc.get("sender")
    if not isinstance(command, str) or not isinstance(sender, str):
        raise ValueError("request needs string fields 'command' and 'sender'")
    return command, sender


class ControlChannel:
    """Answers operator commands on :func:`control_key` while started.

    Parameters
    ----------
    session : zenoh.Session
    fleet : str
    submit : callable
        ``submit(command, sender) -> dict``: decides, logs and returns the acknowledgement
        (``accepted``, ``reason``, ...); called on the event loop's thread.
    poll_s : float
        How often the queue of received queries is looked at (event-loop seconds).
    report : callable, optional
        Told (one line) if the answering task fails (:func:`mission.core.tasks.watch_task`).
    """

    def __init__(self, session, fleet: str, submit: Callable[[str, str], dict], poll_s: float = 0.05,
                 report: Callable[[str], None] | None = None):
        self.fleet = fleet
        self.key = control_key(fleet)
        self.submit = submit
        self.poll_s = float(poll_s)
        self.answered = 0
        self.bad_requests = 0
        self.reply_errors = 0
        self.last_error: str | None = None
        self._queryable = session.declare_queryable(self.key)
        self._task: asyncio.Task | None = None
        self._report = report

    def start(self) -> None:
        """Start answering (a task on the running loop)."""
        if self._task is None:
            self._task = spawn(self._run(), "answering operator commands (zenoh)", self._report)

    async def _run(self) -> None:
        while True:
            self.poll()
            await asyncio.sleep(self.poll_s)

    def poll(self) -> int:
        """Answer every query received so far; returns how many."""
        n = 0
        while self._queryable is not None:
            query = self._queryable.try_recv()
            if query is None:
                return n
            self._answer(query)
            n += 1
        return n

    def _answer(self, query, closing: bool = False) -> None:
        payload = b"" if query.payload is None else query.payload.to_bytes()
        try:
            command, sender = parse_request(payload)
        except ValueError as exc:
            self.bad_requests += 1
            ack = {"command": None, "sender": None, "accepted": False, "reason": f"bad request: {exc}"}
        else:
            ack = (self.submit(command, sender) if not closing else
                   {"command": command, "sender": sender, "accepted": False,
                    "reason": "the coordinator is shutting down"})
        ack = {"schema": ACK_SCHEMA, "fleet": self.fleet, **ack}
        try:
            query.reply(self.key, json.dumps(ack).encode())
            self.answered += 1
        except Exception as exc:  # noqa: BLE001 - the querier went away: counted, the mission goes on
            self.reply_errors += 1
            self.last_error = f"reply: {exc!r}"
        finally:
            query.drop()

    async def stop(self) -> None:
        """Stop answering: queries still queued are told the coordinator is shutting down."""
        await stop_watched(self._task)
        self._task = None
        if self._queryable is None:
            return
        while (query := self._queryable.try_recv()) is not None:
            self._answer(query, closing=True)
        try:
            self._queryable.undeclare()
        except Exception as exc:  # noqa: BLE001 - the session may already be closed: kept for the record
            self.last_error = f"undeclare: {exc!r}"
        self._queryable = None
