"""Is this address on this machine only? The loopback rule of the security checks.

The ground station's security check (:mod:`mission.core.plan_security`) and the warnings of
``swarmseek ctl`` / ``watch`` / ``sensor`` / ``mock`` (:func:`wire.zenoh_flags.plain_network_endpoints`)
decide with the same rule whether a zenoh endpoint or a MAVLink connection can be reached from
another machine:

- a loopback IP address (``127.0.0.0/8``, ``::1``) or the name ``localhost``: this machine only;
- a unix socket endpoint (``unixsock-stream/PATH``, ``unixpipe/NAME``): this machine only;
- anything else, including the wildcard addresses ``0.0.0.0`` / ``::`` (every interface) and
  every other host name (no name is looked up: a lookup blocks, and may differ at flight time):
  reachable from the network.

The rule is a plain function, ``Callable[[str], bool]``: the checks take it as an argument, so a
test can declare a loopback address to stand in for a network one.
"""
from __future__ import annotations

import ipaddress
from typing import Callable, Iterable

__all__ = ["IsLoopback", "host_is_loopback", "network_endpoints", "zenoh_endpoint_host", "zenoh_endpoint_is_loopback"]

#: the type of a loopback rule: host (IP address or name, no brackets) -> only this machine?
IsLoopback = Callable[[str], bool]
_LOCAL_NAMES = ("localhost", "localhost.", "ip6-localhost", "ip6-loopback")
_LOCAL_PROTOCOLS = ("unixsock-stream", "unixpipe")


def host_is_loopback(host: str) -> bool:
    """True when ``host`` can only be reached from this machine.

    Parameters
    ----------
    host : str
        An IPv4 / IPv6 address (brackets allowed) or a host name.

    Returns
    -------
    bool
        True for a loopback address or ``localhost``; False for every other address (the
        wildcards ``0.0.0.0`` and ``::`` listen on every interface) and every other name.
    """
    text = str(host).strip().strip("[]").split("%", 1)[0]
    if text.lower() in _LOCAL_NAMES:
        return True
    try:
        return ipaddress.ip_address(text).is_loopback
    except ValueError:
        return False


def zenoh_endpoint_host(endpoint: str) -> str | None:
    """The host of a zenoh endpoint ``PROTO/HOST:PORT[#config][?metadata]``; None for a unix
    socket endpoint (no host: this machine only)."""
    proto, _, rest = str(endpoint).partition("/")
    if proto in _LOCAL_PROTOCOLS:
        return None
    address = rest.split("#", 1)[0].split("?", 1)[0]
    host, sep, _port = address.rpartition(":")
    return host if sep else address


def zenoh_endpoint_is_loopback(endpoint: str, is_loopback: IsLoopback = host_is_loopback) -> bool:
    """True when a zenoh endpoint is on this machine only (see the module docstring)."""
    host = zenoh_endpoint_host(endpoint)
    return host is None or is_loopback(host)


def network_endpoints(endpoints: Iterable[str], is_loopback: IsLoopback = host_is_loopback) -> list[str]:
    """The endpoints of ``endpoints`` another machine can reach, in order."""
    return [ep for ep in endpoints if not zenoh_endpoint_is_loopback(ep, is_loopback)]

