"""Errors of MAVLink links and the registry that catches one system id on two endpoints.

:class:`SysidRegistry` is shared between the :class:`~mission.link.endpoint.MavEndpoint` objects
of one mission; :class:`LinkError` is what every link problem raises. Both are imported from
here, not through :mod:`mission.link.endpoint`.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Callable, Protocol

from mission.link.tlog import QUARANTINE_MAX_BYTES, QuarantineLog

__all__ = ["LinkError", "SysidRegistry"]


class _Endpoint(Protocol):
    """What the registry needs of an endpoint (a :class:`~mission.link.endpoint.MavEndpoint`)."""

    uri: str


class LinkError(ConnectionError):
    """A MAVLink link problem; the message names the endpoint (and the other one, if any).

    Attributes
    ----------
    sysid : int or None
        The vehicle the problem is about (a duplicate system id), None when it is the link's.
    """

    sysid: int | None = None


class SysidRegistry:
    """Which endpoint each vehicle system id was heard on; share one between endpoints.

    :meth:`claim` raises :class:`LinkError` naming both endpoints when a system id shows up on a
    second endpoint. It also holds the mission's one :class:`~mission.link.tlog.QuarantineLog` per
    directory (:meth:`quarantine`), closed when the last endpoint using it is released.

    Parameters
    ----------
    quarantine_max_bytes : int
        Size cap of the quarantine logs (default 5 MB).
    """

    def __init__(self, quarantine_max_bytes: int = QUARANTINE_MAX_BYTES) -> None:
        self._owner: dict[int, _Endpoint] = {}
        self.quarantine_max_bytes = int(quarantine_max_bytes)
        self._quarantines: dict[Path, QuarantineLog] = {}
        self._quarantine_users: dict[Path, set[int]] = {}

    def quarantine(self, directory: str | os.PathLike, endpoint: _Endpoint,
                   time_fn: Callable[[], float] | None = None) -> QuarantineLog:
        """The quarantine log of ``directory`` (one per directory, shared by the endpoints)."""
        key = Path(directory).resolve()
        log = self._quarantines.get(key)
        if log is None or log.closed:
            log = self._quarantines[key] = QuarantineLog(key, time_fn=time_fn,
                                                         max_bytes=self.quarantine_max_bytes)
            self._quarantine_users[key] = set()
        self._quarantine_users[key].add(id(endpoint))
        return log

    def quarantine_counters(self) -> dict[str, int]:
        """``records``, ``bytes``, ``dropped`` summed over this registry's quarantine logs."""
        out = {"records": 0, "bytes": 0, "dropped": 0}
        for log in self._quarantines.values():
            for k in out:
                out[k] += log.counters[k]
        return out

    def claim(self, sysid: int, endpoint: _Endpoint) -> None:
        """Record that ``sysid`` is on ``endpoint``; raise if it is already on another one."""
        owner = self._owner.setdefault(sysid, endpoint)
        if owner is not endpoint:
            raise LinkError(
                f"duplicate MAVLink system id {sysid}: heard on {owner.uri!r} and on {endpoint.uri!r}")

    def release(self, endpoint: _Endpoint) -> None:
        """Forget every system id of ``endpoint`` (when it closes); close quarantine logs left unused."""
        for sysid in [s for s, e in self._owner.items() if e is endpoint]:
            del self._owner[sysid]
        for key, users in self._quarantine_users.items():
            users.discard(id(endpoint))
            if not users:
                self._quarantines[key].close()
