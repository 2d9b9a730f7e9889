"""UdpPoller drains each socket in one poll (FIONREAD between datagrams), empty datagrams included.

Real UDP sockets on 127.0.0.1: datagrams are queued before the poll (loopback delivery is done
when ``sendto`` returns), then one :meth:`UdpPoller.poll_once` must hand every one of them to the
consumer in order, up to the per-socket cap, whatever empty datagrams are mixed in (an attacker
sending empty datagrams must not slow the draining of a vehicle's socket down).
"""
from __future__ import annotations

import asyncio
import socket

import pytest

from mission.link.poller import _MAX_DATAGRAMS_PER_SOCKET, UdpPoller


def _poll(datagrams: list[bytes], polls: int = 1) -> list[tuple[int, list[bytes]]]:
    """Send ``datagrams`` to a polled socket, then poll ``polls`` times; (handled, received) per poll."""
    async def scenario():
        poller = UdpPoller(interval_s=3600.0)   # its own task polls once at start, then sleeps
        rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        rx.bind(("127.0.0.1", 0))
        rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        got: list[bytes] = []
        try:
            poller.register(rx, lambda data, addr: got.append(data))
            await asyncio.sleep(0)          # the task's first (empty) poll
            for data in datagrams:
                tx.sendto(data, rx.getsockname())
            out = []
            for _ in range(polls):
                before = len(got)
                handled = poller.poll_once()
                out.append((handled, got[before:]))
            return out
        finally:
            await poller.close()
            rx.close()
            tx.close()
    return asyncio.run(scenario())


def test_every_queued_datagram_is_read_in_one_poll():
    datagrams = [bytes([k]) * (k + 1) for k in range(20)]
    (handled, got), (again, _) = _poll(datagrams, polls=2)
    assert handled == 20 and got == datagrams
    assert again == 0


@pytest.mark.parametrize("pattern", [
    [b"a", b"", b"b", b"", b"c"],
    [b"", b"a", b"b"],
    [b"a", b"", b"", b"b"],
    [b""] * 5,
])
def test_empty_datagrams_do_not_stop_the_draining(pattern):
    (handled, got), (again, rest) = _poll(pattern, polls=2)
    # at most the first empty one can stop a poll (FIONREAD 0); it is then read at the next one
    assert got + rest == pattern
    assert handled >= 1 and handled + again == len(pattern)


def test_a_flood_of_empty_datagrams_is_drained_at_the_cap():
    flood = [b""] * (_MAX_DATAGRAMS_PER_SOCKET + 40) + [b"heartbeat"]
    (first, _), (second, rest) = _poll(flood, polls=2)
    assert first == _MAX_DATAGRAMS_PER_SOCKET
    assert second == 41 and rest[-1] == b"heartbeat"
