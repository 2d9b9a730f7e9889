"""Sensor readings over zenoh: decode, validate, count rejections, align in time.

Readings arrive on ``swarmseek/<fleet>/vehicle/<sysid>/sensor`` as the JSON payload of
``docs/interfaces.md`` (schema ``swarmseek.sensor.v1``). :class:`ReadingStore` checks each one
and either keeps it (a bounded history per vehicle) or rejects it and counts the reason, one of
:data:`REJECT_REASONS`:

``malformed``        not UTF-8 JSON, not an object, a field missing or of the wrong type
``wrong_schema``     ``schema`` is not ``swarmseek.sensor.v1``
``wrong_fleet``      ``fleet`` differs from the mission's fleet
``bad_key``          the key is not ``swarmseek/<fleet>/vehicle/<sysid>/sensor`` with the sysid
                     in canonical decimal form (no sign, leading zero or non-ASCII digit)
``unknown_vehicle``  the sysid is not one of the mission's vehicles
``sysid_mismatch``   the sysid in the key differs from the payload's
``not_finite``       NaN or infinity in time, position or value (or an integer beyond floats)
``duplicate``        same ``seq`` as an accepted reading from that vehicle
``old_seq``          ``seq`` lower than the last accepted one (a restart, i.e. a lower seq more
                     than ``seq_reset_after_s`` newer than the last reading, is accepted)
``late``             taken more than ``max_age_s`` before now (mission clock), or in the future
                     by more than ``max_age_s``
``position_far``     taken farther than ``max_position_error_m`` from the vehicle's telemetry

Time alignment: :meth:`ReadingStore.aligned` returns, for an estimation instant ``t``, each
vehicle's reading nearest ``t`` within ``window_s``, with the position where it was taken in the
mission ENU frame (converted with :class:`formation.geodesy.TangentFrame`, pymap3d's maths).

The wire format (schema, keys, :func:`decode_reading`, :class:`Reading`) lives in
:mod:`mission.telemetry.reading_format` (imported from there).
"""
from __future__ import annotations

import bisect
import math
import threading
from collections import deque
from typing import Callable, Iterable

import numpy as np

from formation.geodesy import TangentFrame
from mission.telemetry.reading_format import (
    REJECT_REASONS,
    Reading,
    ReadingRejected,
    decode_reading,
    sensor_key_expr,
    sysid_from_key,
)

__all__ = ["ReadingStore", "ReadingSubscriber"]


class ReadingStore:
    """Validated readings of one fleet, per vehicle, with rejection counts. Thread safe.

    Parameters
    ----------
    fleet : str
        Fleet name (key chunk and payload field).
    sysids : iterable of int
        The mission's vehicles; readings from others are ``unknown_vehicle``.
    origin : tuple
        Mission origin ``(lat_deg, lon_deg, alt_m)``.
    clock
        Mission clock (``time()``), to judge lateness.
    telemetry_position : callable, optional
        ``sysid -> ENU position or None``: the vehicle's latest telemetry position, to reject
        readings far from it.
    max_age_s : float
        Readings older than this are ``late``.
    max_position_error_m : float
        Readings farther than this from the telemetry position are ``position_far``.
    history : int
        Readings kept per vehicle.
    seq_reset_after_s : float
        A lower ``seq`` taken this much later than the last reading is a sender restart.
    """

    def __init__(self, fleet: str, sysids: Iterable[int], origin, clock, *,
                 telemetry_position: Callable[[int], np.ndarray | None] | None = None,
                 max_age_s: float = 5.0, max_position_error_m: float = 10.0, history: int = 200,
                 seq_reset_after_s: float = 5.0):
        self.fleet = fleet
        self.origin = tuple(float(v) for v in origin)
        self._to_enu = TangentFrame(self.origin)
        self.clock = clock
        self.telemetry_position = telemetry_position
        self.max_age_s = float(max_age_s)
        self.max_position_error_m = float(max_position_error_m)
        self.seq_reset_after_s = float(seq_reset_after_s)
        self._lock = threading.Lock()
        self._history: dict[int, deque[Reading]] = {int(s): deque(maxlen=history) for s in sysids}
        self._last_seq: dict[int, tuple[int, float]] = {}
        self.rejected: dict[str, int] = {r: 0 for r in REJECT_REASONS}
        self.accepted = 0
        self.subscribers = 0  # open ReadingSubscriber feeds (a lock-step driver reads it)
        self._last_error: dict[str, str] = {}
        self._key_sysid: dict[str, int] = {}  # valid keys already parsed (see _validate)

    @property
    def sysids(self) -> list[int]:
        """The vehicles whose readings are accepted."""
        return sorted(self._history)

    def remove_vehicle(self, sysid: int) -> None:
        """Stop accepting a vehicle's readings (they count as ``unknown_vehicle``)."""
        with self._lock:
            self._history.pop(int(sysid), None)

    def last_errors(self) -> dict[str, str]:
        """The latest rejection message per reason (for diagnostics)."""
        with self._lock:
            return dict(self._last_error)

    def offer(self, key: str, payload: bytes | str) -> Reading | None:
        """Validate one sample; keep it and return the :class:`Reading`, or count and return None."""
        try:
            reading = self._validate(key, payload)
        except ReadingRejected as exc:
            self.count_rejection(exc.reason, str(exc))
            return None
        return reading

    def count_rejection(self, reason: str, detail: str) -> None:
        """Count one sample refused for ``reason`` and keep ``detail`` as its latest message.

        Parameters
        ----------
        reason : str
            The rejection counter (e.g. ``malformed``), shown to the operator in :meth:`counts`.
        detail : str
            What was wrong, returned by :meth:`last_errors`.
        """
        with self._lock:
            self.rejected[reason] += 1
            self._last_error[reason] = detail

    def _validate(self, key: str, payload) -> Reading:
        key = str(key)
        key_sysid = self._key_sysid.get(key)
        if key_sysid is None:
            key_sysid = sysid_from_key(key, self.fleet)
            if key_sysid in self._history and len(self._key_sysid) < 256:
                self._key_sysid[key] = key_sysid  # the mission's own keys only: a flood stays bounded
        doc = decode_reading(payload)
        if doc["fleet"] != self.fleet:
            raise ReadingRejected("wrong_fleet", f"fleet {doc['fleet'][:40]!r}, expected {self.fleet!r}")
        sysid = doc["sysid"]
        if sysid != key_sysid:
            raise ReadingRejected("sysid_mismatch", f"key says sysid {key_sysid}, payload says {sysid}")
        if sysid not in self._history:
            raise ReadingRejected("unknown_vehicle", f"sysid {sysid} is not in the mission")
        now = self.clock.time()
        t = doc["time_s"]
        if t < now - self.max_age_s or t > now + self.max_age_s:
            raise ReadingRejected("late", f"taken at {t:.3f}, now {now:.3f} (max age {self.max_age_s} s)")
        east_m, north_m, up_m = self._to_enu.geodetic_to_enu_m(doc["lat_deg"], doc["lon_deg"], doc["alt_m"])
        pos = np.array((east_m, north_m, up_m))
        if self.telemetry_position is not None:
            tel = self.telemetry_position(sysid)
            if tel is not None:
                if type(tel) is not np.ndarray or tel.dtype != np.float64:
                    tel = np.asarray(tel, dtype=float)
                tel_e_m, tel_n_m, tel_u_m = tel.tolist()
                # plain floats: a 3-vector's norm costs more in numpy than the rest of the check
                err = math.sqrt((east_m - tel_e_m) ** 2 + (north_m - tel_n_m) ** 2 + (up_m - tel_u_m) ** 2)
                if err > self.max_position_error_m:
                    raise ReadingRejected("position_far", f"sysid {sysid}: reading position {err:.1f} m "
                                          f"from telemetry (max {self.max_position_error_m} m)")
        seq = doc["seq"]
        reading = Reading.accepted(sysid, seq, t, doc["lat_deg"], doc["lon_deg"], doc["alt_m"], doc["value"], pos, now)
        with self._lock:
            hist = self._history.get(sysid)
            if hist is None:
                raise ReadingRejected("unknown_vehicle", f"sysid {sysid} left the mission")
            last = self._last_seq.get(sysid)
            if last is not None:
                last_seq, last_t = last
                if seq == last_seq:
                    raise ReadingRejected("duplicate", f"sysid {sysid}: seq {seq} again")
                if seq < last_seq and t < last_t + self.seq_reset_after_s:
                    raise ReadingRejected("old_seq", f"sysid {sysid}: seq {seq} after {last_seq}")
            self._last_seq[sysid] = (seq, t)
            if hist and t < hist[-1].time_s:
                items = list(hist)
                items.insert(bisect.bisect([r.time_s for r in items], t), reading)
                hist.clear()
                hist.extend(items[-hist.maxlen:])
            else:
                hist.append(reading)
            self.accepted += 1
        return reading

    def latest(self, sysid: int) -> Reading | None:
        """The newest accepted reading of a vehicle, or None."""
        with self._lock:
            hist = self._history.get(int(sysid))
            return hist[-1] if hist else None

    def history(self, sysid: int) -> list[Reading]:
        """Accepted readings of a vehicle, oldest first."""
        with self._lock:
            return list(self._history.get(int(sysid), ()))

    def aligned(self, t_s: float, window_s: float, sysids: Iterable[int] | None = None) -> dict[int, Reading]:
        """Each vehicle's reading nearest ``t_s`` within ``window_s`` (vehicles without one are absent).

        Parameters
        ----------
        t_s : float
            Estimation instant, mission clock.
        window_s : float
            Largest ``|reading.time_s - t_s|`` accepted.
        sysids : iterable of int, optional
            Restrict to these vehicles (default: all).
        """
        out: dict[int, Reading] = {}
        with self._lock:
            keys = list(self._history) if sysids is None else [int(s) for s in sysids]
            for sysid in keys:
                hist = self._history.get(sysid)
                if not hist:
                    continue
                # newest first; stop once readings are older than the window (history is in
                # time order), so the cost does not grow with the history length
                best, best_dt = None, window_s
                for r in reversed(hist):
                    dt = abs(r.time_s - t_s)
                    if dt < best_dt or (best is None and dt <= window_s):
                        best, best_dt = r, dt
                    if r.time_s < t_s - window_s:
                        break
                if best is not None:
                    out[sysid] = best
        return out

    def counts(self) -> dict:
        """``{"accepted": n, "rejected": {reason: n}}`` (a copy)."""
        with self._lock:
            return {"accepted": self.accepted, "rejected": dict(self.rejected)}


class ReadingSubscriber:
    """Feeds a :class:`ReadingStore` from a zenoh subscription on every vehicle's sensor key.

    Parameters
    ----------
    session : zenoh.Session
        An open session (the caller owns it).
    store : ReadingStore
    """

    def __init__(self, session, store: ReadingStore):
        self.store = store
        self._sub = session.declare_subscriber(sensor_key_expr(store.fleet), self._on_sample)
        self._open = True
        store.subscribers += 1

    def _on_sample(self, sample) -> None:
        try:
            payload = sample.payload.to_bytes()
            key = str(sample.key_expr)
        except Exception as exc:  # noqa: BLE001 - a bad sample must never kill the zenoh callback
            self.store.count_rejection("malformed", f"unreadable sample: {exc}")
            return
        self.store.offer(key, payload)

    def close(self) -> None:
        """Undeclare the subscription."""
        if self._open:
            self._open = False
            self.store.subscribers -= 1
        try:
            self._sub.undeclare()
        except Exception:  # noqa: BLE001 - session may already be closed
            pass
