"""The per-vehicle status in the seek's ``iteration`` records, written only when it changed.

Older mission logs carry every vehicle's whole status dict in every ``iteration`` record
(``status``: a list, about half of the seek's log). That status is also in the 1 Hz ``status``
record, and its position and setpoint in the iteration record's own ``positions_enu`` and
``setpoints_enu``. The iteration record now carries ``status_changes``: per vehicle (system id
as a string key), only the fields of :data:`ITERATION_FIELDS` whose value differs from that
vehicle's in the previous iteration record of the same seek (the first record: all of them). The
fields that change every record (altitude, battery, link age, setpoint rate, position, setpoint)
are read from the ``status`` and ``positions_enu``/``setpoints_enu`` records instead.

:func:`iteration_statuses` reads both forms back into the same thing: per iteration record,
``{sysid: {field: value}}`` with at least :data:`ITERATION_FIELDS` (an old record: every field).
"""
from __future__ import annotations

__all__ = ["ITERATION_FIELDS", "StatusChanges", "iteration_statuses"]

#: the status fields an iteration record keeps (when they changed)
ITERATION_FIELDS = ("id", "status", "sensor_retired", "flight_state", "flavour", "mode", "armed")
_MISSING = object()


class StatusChanges:
    """What changed in the vehicles' status since the last call (one per seek phase)."""

    def __init__(self) -> None:
        self._last: dict[int, dict] = {}

    def changes(self, vehicles) -> dict[str, dict]:
        """``{str(sysid): {field: value}}`` of the :data:`ITERATION_FIELDS` that changed.

        Parameters
        ----------
        vehicles : list of dict
            Every vehicle's status dict (``sysid`` and the fields), as the coordinator's
            ``vehicle_status()`` returns it.

        Returns
        -------
        dict
            Only vehicles with a change; a vehicle not seen before gets all its fields.
        """
        out = {}
        for v in vehicles:
            sysid = int(v["sysid"])
            now = {k: v[k] for k in ITERATION_FIELDS if k in v}
            last = self._last.get(sysid)
            diff = now if last is None else {k: x for k, x in now.items() if last.get(k, _MISSING) != x}
            if diff:
                out[str(sysid)] = diff
            self._last[sysid] = now
        return out


def iteration_statuses(records) -> list[dict[int, dict]]:
    """Every ``iteration`` record's vehicle status, old logs (``status`` lists) and new
    (``status_changes``) alike.

    Parameters
    ----------
    records : iterable of dict
        A mission log's records in order (all types; only ``iteration`` records are read).

    Returns
    -------
    list of dict
        One ``{sysid: {"sysid": sysid, field: value ...}}`` per iteration record, in order: the
        record's own list when it has one, else the vehicles' fields as of that record (the
        changes so far applied in order).
    """
    current: dict[int, dict] = {}
    out = []
    for r in records:
        if r.get("type") != "iteration":
            continue
        if "status" in r:
            current = {int(v["sysid"]): dict(v) for v in r["status"]}
        else:
            for key, diff in (r.get("status_changes") or {}).items():
                current.setdefault(int(key), {"sysid": int(key)}).update(diff)
        out.append({s: dict(v) for s, v in current.items()})
    return out
