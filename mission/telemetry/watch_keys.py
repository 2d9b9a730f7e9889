"""Operator keys in the terminal of ``run`` / ``fly`` while the live table is shown.

``p`` pause, ``c`` continue, ``a`` abort, ``h`` return (home), ``l`` land, ``r`` rtl. The stops
(``a``, ``h``, ``l``, ``r``) must be pressed twice within :data:`CONFIRM_S` seconds (a stray key
never ends a mission). Read without blocking: an asyncio reader on stdin, only when stdin is a
terminal (put in cbreak mode, restored by :meth:`TerminalKeys.close`); the command goes to the
coordinator's ``command(command, sender)`` with the sender ``terminal:USER@HOST``. A terminal that
goes away (end of file, a hung-up SSH session) ends the reading; the mission goes on
(:mod:`mission.telemetry.terminal`).
"""
from __future__ import annotations

import asyncio
import os
import sys
import time
from typing import Callable

from mission.telemetry.display import Display

__all__ = ["KEYS", "CONFIRM_S", "KeyDecoder", "TerminalKeys", "with_keys"]

#: key -> command
KEYS = {"p": "pause", "c": "continue", "a": "abort", "h": "return", "l": "land", "r": "rtl"}
_NEEDS_CONFIRM = ("abort", "return", "land", "rtl")
CONFIRM_S = 3.0


class KeyDecoder:
    """Turns key presses into commands; a stop needs the same key twice within ``confirm_s``."""

    def __init__(self, confirm_s: float = CONFIRM_S, clock=time.monotonic):
        self.confirm_s = float(confirm_s)
        self._clock = clock
        self._armed: tuple[str, float] | None = None

    def press(self, key: str) -> tuple[str | None, str | None]:
        """``(command, hint)``: the command to send now (or None) and a line to show (or None)."""
        command = KEYS.get(key.lower())
        if command is None:
            return None, None
        if command not in _NEEDS_CONFIRM:
            self._armed = None
            return command, None
        now = self._clock()
        if self._armed is not None and self._armed[0] == command and now - self._armed[1] <= self.confirm_s:
            self._armed = None
            return command, None
        self._armed = (command, now)
        return None, f"press {key} again within {self.confirm_s:g} s to {command.upper()} the mission"


class TerminalKeys:
    """Reads keys from stdin on the running event loop while started.

    Parameters
    ----------
    command : callable
        ``command(command, sender) -> dict`` (the coordinator's).
    say : callable
        Shows a line above the table.
    stream : file, optional
        Default ``sys.stdin``; nothing is read unless it is a terminal.
    """

    def __init__(self, command: Callable[[str, str], dict], say: Callable[[str], None], stream=None):
        from mission.telemetry.watch import default_sender

        self.command = command
        self.say = say
        self.stream = stream if stream is not None else sys.stdin
        self.sender = "terminal:" + default_sender()[:55]
        self.decoder = KeyDecoder()
        self._fd: int | None = None
        self._saved = None
        self._loop: asyncio.AbstractEventLoop | None = None

    def start(self) -> bool:
        """Start reading (True), or do nothing when stdin is not a terminal (False)."""
        try:
            if not self.stream.isatty():
                return False
            fd = self.stream.fileno()
        except (AttributeError, ValueError, OSError):
            return False
        import termios
        import tty

        self._saved = termios.tcgetattr(fd)
        tty.setcbreak(fd)
        self._fd = fd
        self._loop = asyncio.get_running_loop()
        self._loop.add_reader(fd, self._on_input)
        self.say("keys: p pause  c continue  a abort  h return  l land  r rtl (stops: press twice)")
        return True

    def _on_input(self) -> None:
        try:
            raw = os.read(self._fd, 64)
        except BlockingIOError:
            return
        except OSError:  # EIO: the terminal hung up
            raw = b""
        if not raw:  # the terminal is gone: stop reading (an end of file is always "readable")
            self._loop.remove_reader(self._fd)
            return
        data = raw.decode("utf-8", errors="ignore")
        for key in data:
            command, hint = self.decoder.press(key)
            if hint:
                self.say(hint)
            if command:
                self.command(command, self.sender)

    def close(self) -> None:
        """Stop reading and restore the terminal."""
        if self._fd is None:
            return
        import termios

        if self._loop is not None and not self._loop.is_closed():
            self._loop.remove_reader(self._fd)
        try:
            termios.tcsetattr(self._fd, termios.TCSADRAIN, self._saved)
        except (termios.error, OSError):
            pass  # the terminal hung up: nothing left to restore
        self._fd = None


async def with_keys(command, say, display: Display | None, work):
    """Await ``work`` (a mission's run) with the operator keys read while ``display`` draws its
    table on a terminal (nothing read otherwise).

    ``command(command, sender)``: an operator command (the mission's); ``say(text)``: a line shown
    above the display (:class:`TerminalKeys`).
    """
    keys = None
    if display is not None and display.tty and not display.quiet:
        keys = TerminalKeys(command, say)
        if not keys.start():
            keys = None
    try:
        return await work
    finally:
        if keys is not None:
            keys.close()
