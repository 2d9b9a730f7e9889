"""Errors of MAVLink links and the registry that catches one system id on two endpoints.

:class:`SysidRegistry` is shared between the :class:`~mission.link.endpoint.MavEndpoint` objects
of one mission; :class:`LinkError` is what every link problem raises. Both are re-exported by
:mod:`mission.link.endpoint`.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:  # only for annotations: this module must not import the endpoint
    from mission.link.endpoint import MavEndpoint

__all__ = ["LinkError", "SysidRegistry"]


class LinkError(ConnectionError):
    """A MAVLink link problem; the message names the endpoint (and the other one, if any)."""


class SysidRegistry:
    """Which endpoint each vehicle system id was heard on; share one between endpoints.

    :meth:`claim` raises :class:`LinkError` naming both endpoints when a system id shows up on a
    second endpoint.
    """

    def __init__(self) -> None:
        self._owner: dict[int, "MavEndpoint"] = {}

    def claim(self, sysid: int, endpoint: "MavEndpoint") -> None:
        """Record that ``sysid`` is on ``endpoint``; raise if it is already on another one."""
        owner = self._owner.setdefault(sysid, endpoint)
        if owner is not endpoint:
            raise LinkError(
                f"duplicate MAVLink system id {sysid}: heard on {owner.uri!r} and on {endpoint.uri!r}")

    def release(self, endpoint: "MavEndpoint") -> None:
        """Forget every system id of ``endpoint`` (when it closes)."""
        for sysid in [s for s, e in self._owner.items() if e is endpoint]:
            del self._owner[sysid]
