"""The monitor's side of a mission on zenoh: its state snapshots (``swarmseek watch``) and operator
commands with their acknowledgement (``swarmseek ctl``).

Both work from any machine that reaches the coordinator's zenoh network, directly or through a
router; who may watch and who may command is the zenoh access control's business
(``docs/zenoh.md``, ``docs/operator.md``).
"""
from __future__ import annotations

import getpass
import json
import queue
import socket
import time
import uuid

from mission.telemetry.control_channel import ACK_SCHEMA, COMMAND_SCHEMA, control_key
from mission.telemetry.state_pub import STATE_SCHEMA, state_key

__all__ = ["StateWatcher", "CommandTimeout", "send_command", "default_sender"]


def default_sender() -> str:
    """``USER@HOST`` of this process (characters outside the sender alphabet dropped)."""
    try:
        user = getpass.getuser()
    except (KeyError, OSError):
        user = "operator"
    raw = f"{user}@{socket.gethostname()}"
    return "".join(ch for ch in raw if ch.isalnum() or ch in "_.@:+-")[:64] or "operator"


class CommandTimeout(RuntimeError):
    """No coordinator answered the command in time."""


class StateWatcher:
    """Subscribes to ``swarmseek/<fleet>/mission/state``; :meth:`get` returns the snapshots in order.

    Parameters
    ----------
    session : zenoh.Session
    fleet : str
    max_queue : int
        Snapshots kept while nobody reads (older ones are dropped and counted: the newest
        snapshot supersedes them).
    """

    def __init__(self, session, fleet: str, max_queue: int = 64):
        self.fleet = fleet
        self.received = 0
        self.invalid = 0
        self.dropped = 0
        self._queue: queue.Queue = queue.Queue(maxsize=max_queue)
        self._sub = session.declare_subscriber(state_key(fleet), self._on_sample)

    def _on_sample(self, sample) -> None:
        """zenoh's thread: decode one snapshot and queue it (invalid ones counted)."""
        try:
            state = json.loads(sample.payload.to_bytes().decode("utf-8"))
        except (UnicodeDecodeError, ValueError):
            self.invalid += 1
            return
        if not isinstance(state, dict) or state.get("schema") != STATE_SCHEMA:
            self.invalid += 1
            return
        self.received += 1
        while True:
            try:
                self._queue.put_nowait(state)
                return
            except queue.Full:
                try:
                    self._queue.get_nowait()
                    self.dropped += 1
                except queue.Empty:
                    continue

    def get(self, timeout_s: float) -> dict | None:
        """The next snapshot, or None after ``timeout_s`` wall seconds without one."""
        try:
            return self._queue.get(timeout=timeout_s)
        except queue.Empty:
            return None

    def close(self) -> None:
        """Stop receiving."""
        if self._sub is not None:
            self._sub.undeclare()
            self._sub = None


def send_command(session, fleet: str, command: str, sender: str, timeout_s: float = 5.0) -> dict:
    """Send one operator command and return the coordinator's acknowledgement.

    Waits (up to ``timeout_s`` wall seconds) until the coordinator's control queryable is known
    to this session, then sends one query. The request carries an id so that the command is
    sent once (never repeated).

    Returns
    -------
    dict
        The acknowledgement (schema ``swarmseek.command_ack.v1``): ``accepted``, ``reason``,
        ``phase``, ``command``, ``sender``, ``fleet``.

    Raises
    ------
    CommandTimeout
        No coordinator of ``fleet`` was found or none answered in time.
    """
    key = control_key(fleet)
    deadline = time.monotonic() + float(timeout_s)
    querier = session.declare_querier(key, timeout=max(0.1, float(timeout_s)))
    try:
        while not querier.matching_status.matching:
            if time.monotonic() > deadline:
                raise CommandTimeout(
                    f"no coordinator of fleet {fleet!r} answers on {key} after {timeout_s:g} s: is the "
                    "mission running and this session connected to its zenoh network, and does the "
                    "plan's [zenoh.access_control] list this session as a commander?")
            time.sleep(0.05)
        request = {"schema": COMMAND_SCHEMA, "command": command, "sender": sender,
                   "request_id": uuid.uuid4().hex}
        for reply in querier.get(payload=json.dumps(request).encode()):
            if reply.ok is None:
                continue
            try:
                ack = json.loads(reply.ok.payload.to_bytes().decode("utf-8"))
            except (UnicodeDecodeError, ValueError):
                continue
            if isinstance(ack, dict) and ack.get("schema") == ACK_SCHEMA:
                return ack
        raise CommandTimeout(f"the coordinator of fleet {fleet!r} did not answer within {timeout_s:g} s")
    finally:
        querier.undeclare()
