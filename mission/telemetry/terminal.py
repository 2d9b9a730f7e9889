"""The terminal is best effort: a closed stdout or stderr never stops a mission.

:func:`best_effort_terminal` wraps a mission command (``run``, ``fly``, ``resume``): for its
duration ``sys.stdout`` and ``sys.stderr`` are :class:`TerminalStream` objects, so every write to
the terminal (the live display, the operator's messages, warnings, the final report) goes through
one place. A write or flush that fails (``BrokenPipeError`` when the reader of a pipe is gone,
``EIO`` on a hung-up terminal, ``ENOSPC`` on a full disk...) marks that stream lost: its file
descriptor is pointed at ``/dev/null`` (the Python documentation's advice for SIGPIPE, so that the
interpreter's last flush at exit has nowhere to fail) and later writes are dropped. The loss is
told once to the mission log (:meth:`Terminal.attach_log`), which holds everything the mission
would have shown.

SIGPIPE: Python ignores it (a write to a closed pipe raises EPIPE instead). The commands that fly
also *block* it (:func:`sigpipe_blocked`) in the main thread before any other thread starts, so in
every thread (numpy's, zenoh's, the mock fleet's): a SIGPIPE that another process sends
(``kill -PIPE``) then stays pending for :func:`mission.flight.operator_stop.run_until_stopped`,
which tells it apart from the SIGPIPE a write of this process raises (that one stays pending on
the writing thread, unseen) and stops the mission as it does for SIGTERM.
"""
from __future__ import annotations

import contextlib
import os
import signal
import sys
from collections.abc import Iterator
from typing import IO, Callable

__all__ = ["TerminalStream", "Terminal", "best_effort_terminal", "alert", "told_to", "block_sigpipe",
           "sigpipe_blocked", "SIGPIPE_STATUS", "silence_broken_pipes"]

#: the exit status of a command whose reader went away (``| head -1``): 128 + SIGPIPE, what a
#: shell reports for a program that SIGPIPE ended
SIGPIPE_STATUS = 128 + 13


class TerminalStream:
    """A text stream whose failures are absorbed: the first one marks it :attr:`lost`.

    Parameters
    ----------
    stream : file
        The stream wrapped (``sys.stdout``, ``sys.stderr``).
    name : str
        ``stdout`` or ``stderr`` (in the loss notice).
    on_lost : callable
        ``on_lost(name, exc)``, called once when the stream is lost.
    """

    def __init__(self, stream: IO[str], name: str, on_lost: Callable[[str, BaseException], None]):
        self.stream = stream
        self.name = name
        self.lost: BaseException | None = None
        self._on_lost = on_lost

    def write(self, text: str) -> int:
        """Write ``text`` (dropped once lost); returns its length, as a file's ``write`` does."""
        if self.lost is None:
            try:
                self.stream.write(text)
            except (OSError, ValueError) as exc:  # ValueError: the stream object was closed
                self._lose(exc)
        return len(text)

    def flush(self) -> None:
        """Flush (nothing once lost)."""
        if self.lost is None:
            try:
                self.stream.flush()
            except (OSError, ValueError) as exc:
                self._lose(exc)

    def isatty(self) -> bool:
        """Whether the stream is a terminal (False once lost)."""
        if self.lost is not None:
            return False
        try:
            return bool(self.stream.isatty())
        except (AttributeError, OSError, ValueError):
            return False

    def __getattr__(self, name):  # fileno, encoding, buffer...: the wrapped stream's
        return getattr(self.stream, name)

    def _lose(self, exc: BaseException) -> None:
        self.lost = exc
        try:  # what is still buffered, and the interpreter's flush at exit, go to /dev/null
            devnull = os.open(os.devnull, os.O_WRONLY)
            try:
                os.dup2(devnull, self.stream.fileno())
            finally:
                os.close(devnull)
        except (OSError, ValueError, AttributeError):
            pass  # not a file descriptor (a test's buffer): the stream stays lost all the same
        self._on_lost(self.name, exc)


class Terminal:
    """The mission's stdout and stderr (:class:`TerminalStream`), their losses told to the mission log.

    A loss before :meth:`attach_log` is told when the log is attached.
    """

    def __init__(self, stdout: IO[str], stderr: IO[str]):
        self.out = TerminalStream(stdout, "stdout", self._lost)
        self.err = TerminalStream(stderr, "stderr", self._lost)
        self._log = None
        self._untold: list[tuple[str, BaseException]] = []

    def _lost(self, name: str, exc: BaseException) -> None:
        self._untold.append((name, exc))
        self._tell()

    def _tell(self) -> None:
        while self._log is not None and self._untold:
            name, exc = self._untold.pop(0)
            self._log.event(f"the terminal's {name} is gone ({type(exc).__name__}: {exc}): the mission goes "
                            f"on; what it would show there is in this log", level="warning",
                            terminal_lost=name)

    @contextlib.contextmanager
    def attach_log(self, log) -> Iterator[None]:
        """While in this context, losses of the terminal are events of the mission log ``log``."""
        self._log = log
        try:
            self._tell()
            yield
        finally:
            self._log = None


def alert(text: str) -> bool:
    """Write ``text`` (one line) loudly on whatever output still works: stderr, else stdout.

    Returns False when neither could take it.
    """
    for stream in (sys.stderr, sys.stdout):
        if stream is None or _is_lost(stream):
            continue
        try:
            stream.write(text.rstrip("\n") + "\n")
            stream.flush()
        except (OSError, ValueError):
            continue
        if not _is_lost(stream):
            return True
    return False


def _is_lost(stream) -> bool:
    """Whether ``stream`` is a :class:`TerminalStream` that was lost (a plain stream never is)."""
    return isinstance(stream, TerminalStream) and stream.lost is not None


@contextlib.contextmanager
def best_effort_terminal() -> Iterator[Terminal]:
    """``sys.stdout`` and ``sys.stderr`` best effort (a :class:`Terminal`) and SIGPIPE blocked in
    the main thread, for the duration of a mission command; both restored after."""
    saved = sys.stdout, sys.stderr
    term = Terminal(sys.stdout, sys.stderr)
    sys.stdout, sys.stderr = term.out, term.err
    try:
        with sigpipe_blocked():
            yield term
    finally:
        term.out.flush()
        term.err.flush()
        sys.stdout, sys.stderr = saved


@contextlib.contextmanager
def sigpipe_blocked() -> Iterator[bool]:
    """SIGPIPE blocked (:func:`block_sigpipe`) in this context, unblocked after if blocked here;
    yields whether it was. A SIGPIPE of our own writes still pending when it is unblocked is
    discarded: Python ignores SIGPIPE.

    Threads inherit the mask of the thread that starts them: ``swarmseek run``/``fly``/``resume``
    enter this first thing (:func:`mission.cli.main`), before numpy's and zenoh's threads exist, so
    that a SIGPIPE sent to the process can only be taken by
    :func:`mission.flight.operator_stop.run_until_stopped`'s waiter."""
    blocked = block_sigpipe()
    try:
        yield blocked
    finally:
        if blocked:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, [signal.SIGPIPE])


def block_sigpipe() -> bool:
    """Block SIGPIPE in this thread if it is the main one and SIGPIPE is ignored (Python's
    default); True when blocked here (False: not the main thread, or already blocked)."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        return False
    if signal.getsignal(signal.SIGPIPE) != signal.SIG_IGN:
        return False
    if signal.SIGPIPE in signal.pthread_sigmask(signal.SIG_BLOCK, [signal.SIGPIPE]):
        return False  # already blocked by someone else: theirs to undo
    return True


def _broken_pipe(fd: int) -> bool:
    """Whether ``fd`` is the write end of a pipe whose reader is gone (poll: POLLERR)."""
    import select

    try:
        poller = select.poll()
        poller.register(fd, select.POLLOUT)
        return any(events & select.POLLERR for _, events in poller.poll(0))
    except (OSError, ValueError):
        return False


def silence_broken_pipes() -> bool:
    """After a ``BrokenPipeError``: point stdout and stderr, where their reader is gone, at
    ``/dev/null`` (so that the interpreter's last flush at exit has nowhere to fail, as the
    Python documentation advises for SIGPIPE); returns whether either was (False: the broken pipe
    was something else, e.g. a socket, and is not the terminal's)."""
    gone = False
    for stream in (sys.stdout, sys.stderr):
        try:
            fd = stream.fileno()
        except (AttributeError, OSError, ValueError):
            continue
        if _broken_pipe(fd):
            gone = True
            devnull = os.open(os.devnull, os.O_WRONLY)
            try:
                os.dup2(devnull, fd)
            finally:
                os.close(devnull)
    return gone


def told_to(terminal: Terminal | None, log):
    """``terminal.attach_log(log)``, or nothing to do without a terminal (a context manager)."""
    return contextlib.nullcontext() if terminal is None else terminal.attach_log(log)
