"""UdpPoller drains each socket in one poll (rounds of one datagram per readable socket, epoll asked
again between rounds), empty datagrams included; many sockets give what reading each dry gives.

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
    # epoll reports a socket holding only empty datagrams readable: all are read in one poll
    assert got == pattern and rest == []
    assert handled == len(pattern) and again == 0


def test_a_flood_of_empty_datagrams_is_drained_at_the_cap():
    flood = [b""] * (_MAX_DATAGRAMS_PER_SOCKET + 40) + [b"heartbeat"]
    (first, _), (second, rest) = _poll(flood, polls=2)
    assert first == _MAX_DATAGRAMS_PER_SOCKET
    assert second == 41 and rest[-1] == b"heartbeat"


def _plain_drain(socks) -> dict[int, list[bytes]]:
    """The plain path: each socket read until ``BlockingIOError``, one after the other."""
    out = {}
    for k, sock in enumerate(socks):
        got = out[k] = []
        while True:
            try:
                got.append(sock.recvfrom(65535)[0])
            except BlockingIOError:
                break
    return out


@pytest.mark.parametrize("seed", range(5))
def test_many_sockets_get_what_reading_each_dry_gets(seed):
    """12 polled sockets and 12 read dry by the plain loop, the same datagrams queued on each pair
    (0 to 9 per socket, empty ones among them): one poll hands every socket's datagrams over in
    the same order as the plain path, and a second poll finds nothing."""
    import random

    rng = random.Random(seed)
    plan = [[bytes(rng.randrange(256) for _ in range(rng.choice([0, 1, 5, 40])))
             for _ in range(rng.randrange(10))] for _ in range(12)]

    async def scenario():
        poller = UdpPoller(interval_s=3600.0)
        polled = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in plan]
        plain = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in plan]
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        got: dict[int, list[bytes]] = {k: [] for k in range(len(plan))}
        try:
            for k, (a, b) in enumerate(zip(polled, plain)):
                for s in (a, b):
                    s.bind(("127.0.0.1", 0))
                    s.setblocking(False)
                poller.register(a, lambda data, addr, k=k: got[k].append(data))
            await asyncio.sleep(0)
            for k, datagrams in enumerate(plan):
                for data in datagrams:
                    tx.sendto(data, polled[k].getsockname())
                    tx.sendto(data, plain[k].getsockname())
            handled = poller.poll_once()
            again = poller.poll_once()
            return handled, again, got, _plain_drain(plain)
        finally:
            await poller.close()
            for s in polled + plain + [tx]:
                s.close()

    handled, again, got, reference = asyncio.run(scenario())
    assert got == reference == {k: d for k, d in enumerate(plan)}
    assert handled == sum(map(len, plan)) and again == 0
