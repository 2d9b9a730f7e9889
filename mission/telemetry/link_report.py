"""What the MAVLink links rejected, for the operator: totals over a mission's endpoints.

Every :class:`~mission.link.endpoint.MavEndpoint` counts the frames it drops (see its
``counters``); :func:`link_rejections` adds up the kinds that mean "a frame was refused" over
every endpoint of the mission, :func:`unknown_sysids` lists the system ids heard that are not
vehicles of the plan. The coordinator puts both in its state publication, its ``status``
records, a warning event when they grow and the mission's result; the display shows the
non-zero counts (:func:`format_rejections`).
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping

__all__ = [
    "LINK_REJECTION_KINDS",
    "format_rejections",
    "link_rejections",
    "rejection_increase",
    "unknown_sysids",
]

#: endpoint counters that count refused frames, in the order they are shown:
#: ``unsigned``, ``bad_signature``, ``replayed`` (signing on: not delivered nor logged);
#: ``bad_crc``, ``malformed``, ``truncated`` (not MAVLink, or damaged); ``unknown_msgid``
#: (a message id outside the dialect); ``setup_signing_refused`` (an unsigned autopilot heartbeat
#: from a system id the mission does not fly: never sent the key); ``duplicate_sysid``
#: (one system id from two places); ``handler_errors`` (a message a vehicle could not handle);
#: ``foreign_address`` (a vehicle's system id from another address than the one it is pinned to),
#: ``unplanned_sysid`` (a system id the plan does not put on that link), ``unverified`` (a planned
#: vehicle's frames before its first heartbeat, beyond what is held)
LINK_REJECTION_KINDS = ("unsigned", "bad_signature", "replayed", "bad_crc", "malformed", "truncated",
                        "unknown_msgid", "setup_signing_refused", "duplicate_sysid", "handler_errors",
                        "foreign_address", "unplanned_sysid", "unverified")


def link_rejections(endpoints: Iterable) -> dict[str, int]:
    """Frames refused by the endpoints, by kind (:data:`LINK_REJECTION_KINDS`), non-zero only.

    Parameters
    ----------
    endpoints : iterable of MavEndpoint
        The mission's endpoints (their ``counters``).
    """
    totals = dict.fromkeys(LINK_REJECTION_KINDS, 0)
    for ep in endpoints:
        counters = ep.counters
        for kind in LINK_REJECTION_KINDS:
            totals[kind] += int(counters.get(kind, 0))
    return {k: n for k, n in totals.items() if n}


def unknown_sysids(endpoints: Iterable, expected: Iterable[int]) -> list[int]:
    """System ids heard on the endpoints that are no vehicle of the plan (refused or ignored:
    nothing is attached to them), sorted."""
    want = set(expected)
    seen: set[int] = set()
    for ep in endpoints:
        seen |= set(ep.sysids_seen())
    return sorted(seen - want)


def rejection_increase(before: Mapping[str, int], now: Mapping[str, int]) -> dict[str, int]:
    """The kinds whose count grew from ``before`` to ``now``, with the increase."""
    return {k: n - before.get(k, 0) for k, n in now.items() if n > before.get(k, 0)}


def format_rejections(counts: Mapping[str, int] | None) -> str:
    """``bad_signature 3, unsigned 2`` (non-zero counts), or ``0``."""
    shown = [f"{k} {n}" for k, n in (counts or {}).items() if n]
    return ", ".join(shown) if shown else "0"
