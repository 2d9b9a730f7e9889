"""Errors of MAVLink links and the registry that catches one system id on two endpoints.

:class:`SysidRegistry` is shared between the :class:`~mission.link.endpoint.MavEndpoint` objects
of one mission; :class:`LinkError` is what every link problem raises. Both are re-exported by
:mod:`mission.link.endpoint`.
"""
from __future__ import annotations

from typing import Protocol

__all__ = ["LinkError", "SysidRegistry"]


class _Endpoint(Protocol):
    """What the registry needs of an endpoint (a :class:`~mission.link.endpoint.MavEndpoint`)."""

    uri: str


class LinkError(ConnectionError):
    """A MAVLink link problem; the message names the endpoint (and the other one, if any)."""


class SysidRegistry:
    """Which endpoint each vehicle system id was heard on; share one between endpoints.

    :meth:`claim` raises :class:`LinkError` naming both endpoints when a system id shows up on a
    second endpoint.
    """

    def __init__(self) -> None:
        self._owner: dict[int, _Endpoint] = {}

    def claim(self, sysid: int, endpoint: _Endpoint) -> None:
        """Record that ``sysid`` is on ``endpoint``; raise if it is already on another one."""
        owner = self._owner.setdefault(sysid, endpoint)
        if owner is not endpoint:
            raise LinkError(
                f"duplicate MAVLink system id {sysid}: heard on {owner.uri!r} and on {endpoint.uri!r}")

    def release(self, endpoint: _Endpoint) -> None:
        """Forget every system id of ``endpoint`` (when it closes)."""
        for sysid in [s for s, e in self._owner.items() if e is endpoint]:
            del self._owner[sysid]
