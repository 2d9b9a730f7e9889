"""A real sensor's readings on zenoh, placed where the autopilot says the drone is.

:class:`Publisher` is what a sensor loop on the companion computer calls: ``put(value)`` stamps
the value with the companion's clock (Unix time) and the autopilot's latest GLOBAL_POSITION_INT
(read over MAVLink by :class:`companion.autopilot.AutopilotTelemetry`) and puts the reading of
schema ``swarmseek.sensor.v1`` on ``swarmseek/<fleet>/vehicle/<sysid>/sensor`` through the
senders' one publisher (:class:`companion.sensor_wire.SensorPublisher`). A value that is not a
finite number, or that comes before the first position fix or after the fixes stopped, is not
sent: it is counted (:attr:`Publisher.counts`) and :attr:`Publisher.last_problem` says why.
See docs/real-sensor.md.
"""
from __future__ import annotations

import math
import numbers
import threading
import time
from typing import Callable, Iterable

from companion.autopilot import AutopilotTelemetry
from companion.sensor_wire import SENSOR_SCHEMA, SensorPublisher, sensor_key
from wire.fleet_name import check_fleet_name
from wire.zenoh_config import zenoh_config

__all__ = ["COUNT_NAMES", "Publisher", "PublisherError"]

#: the keys of :attr:`Publisher.counts`: what happened to each value given to ``put``
COUNT_NAMES = ("published", "bad_value", "no_position", "stale_position")
#: the default oldest position fix a reading may take (five fixes missed at 10 Hz)
DEFAULT_MAX_FIX_AGE_S = 0.5


class PublisherError(RuntimeError):
    """The publisher cannot start (bad zenoh settings, zenoh session refused): a clear message."""


def _open_session(listen, connect, security):
    import zenoh

    try:
        conf = zenoh_config(listen=list(listen) or None, connect=list(connect) or None, **(security or {}))
    except ValueError as exc:  # no endpoint, a malformed one, a TLS file that vanished
        raise PublisherError(f"bad zenoh settings: {exc}") from None
    try:
        return zenoh.open(conf)
    except Exception as exc:  # zenoh.ZError and friends: bad or busy endpoint
        raise PublisherError(f"cannot open the zenoh session: {exc}") from None


class Publisher:
    """Publishes one drone's sensor readings with the autopilot's position.

    The constructor opens the MAVLink link and waits for the autopilot's heartbeat, then opens
    the zenoh session (explicit endpoints, multicast scouting off); :meth:`close` (or leaving a
    ``with`` block) releases both.

    Parameters
    ----------
    fleet : str
        Fleet name, the plan's ``fleet`` (key chunk and payload field).
    sysid : int or None
        The autopilot's MAVLink system id, the plan's ``sysid`` for this vehicle; None: the
        first autopilot heartbeat's.
    mavlink : str
        pymavlink connection string to the autopilot (``/dev/ttyAMA0,921600``,
        ``udpin:0.0.0.0:14550``, ``tcp:127.0.0.1:5760``, ...).
    zenoh_listen, zenoh_connect : iterable of str
        zenoh endpoints (``tcp/192.168.1.10:7447``); at least one of the two.
    zenoh_security : dict, optional
        TLS / login keywords of :func:`wire.zenoh_config.zenoh_config` (``tls``,
        ``enable_mtls``, ``username``, ``password``).
    position_rate_hz : float
        GLOBAL_POSITION_INT rate asked of the autopilot (10).
    max_fix_age_s : float
        A value put when the latest fix is older than this is held back (``stale_position``).
    heartbeat_timeout_s : float
        How long the constructor waits for the autopilot's heartbeat (30).
    retries : int
        TCP connection attempts to the autopilot (3).
    log : callable, optional
        ``log(text)`` for the MAVLink link's notices (positions stopped, no fix yet).

    Attributes
    ----------
    fleet : str
    sysid : int
        The autopilot's system id (the heartbeat's when none was given).
    key : str
        The zenoh key readings go to.
    counts : dict
        ``published``, ``bad_value``, ``no_position``, ``stale_position``: values given to
        :meth:`put`, by what became of them.
    last_problem : str or None
        Why the latest value not sent was not sent.
    last_reason : str or None
        Its count name (``bad_value``, ``no_position`` or ``stale_position``).
    telemetry : companion.autopilot.AutopilotTelemetry
        The autopilot's link: ``telemetry.latest()`` the newest fix, ``telemetry.error`` why the
        link was lost (None while it lives).

    Raises
    ------
    ValueError
        A bad fleet name or sysid.
    companion.autopilot.AutopilotError
        The autopilot cannot be reached.
    PublisherError
        Bad zenoh settings, or the zenoh session cannot be opened.
    """

    def __init__(self, fleet: str, sysid: int | None = None, *, mavlink: str, zenoh_listen: Iterable[str] = (),
                 zenoh_connect: Iterable[str] = (), zenoh_security: dict | None = None,
                 position_rate_hz: float = 10.0, max_fix_age_s: float = DEFAULT_MAX_FIX_AGE_S,
                 heartbeat_timeout_s: float = 30.0, retries: int = 3, log: Callable[[str], None] | None = None):
        self.fleet = check_fleet_name(fleet)
        if sysid is not None:
            sensor_key(self.fleet, sysid)  # ValueError for a sysid outside 1..255
        if not (max_fix_age_s > 0 and math.isfinite(max_fix_age_s)):
            raise ValueError(f"max_fix_age_s must be a positive number, got {max_fix_age_s!r}")
        self.max_fix_age_s = float(max_fix_age_s)
        self.counts = dict.fromkeys(COUNT_NAMES, 0)
        self.last_problem: str | None = None
        self.last_reason: str | None = None
        self._seq = 0
        self._lock = threading.Lock()
        self._session = self._sensor = None
        self.telemetry = AutopilotTelemetry(mavlink, sysid, rate_hz=position_rate_hz,
                                            heartbeat_timeout_s=heartbeat_timeout_s, retries=retries, log=log)
        try:
            self.sysid = self.telemetry.sysid
            self.key = sensor_key(self.fleet, self.sysid)
            self._session = _open_session(zenoh_listen, zenoh_connect, zenoh_security)
            self._sensor = SensorPublisher(self._session, self.fleet, [self.sysid])
        except BaseException:
            self.close()
            raise

    def put(self, value, time_s: float | None = None) -> bool:
        """Publish one reading of ``value`` taken now (or at ``time_s``) where the drone is.

        Parameters
        ----------
        value : float
            The sensor's reading, in its own units (a finite int or float).
        time_s : float, optional
            When the sample was taken, Unix seconds on this computer's clock; default now.

        Returns
        -------
        bool
            True when published; False when counted in :attr:`counts` instead (``bad_value``:
            not a finite number, also a bad ``time_s``; ``no_position``: no fix from the
            autopilot yet; ``stale_position``: its latest fix is older than ``max_fix_age_s``),
            with :attr:`last_problem` saying why. Never raises for a bad value.

        Raises
        ------
        RuntimeError
            After :meth:`close`.
        """
        with self._lock:
            if self._sensor is None:
                raise RuntimeError(f"the publisher of {self.fleet}/{self.sysid} is closed")
            problem, reading = self._reading(value, time_s)
            if problem is not None:
                self.counts[problem[0]] += 1
                self.last_reason, self.last_problem = problem
                return False
            self._sensor.publish(reading)
            self._seq += 1
            self.counts["published"] += 1
            return True

    def _reading(self, value, time_s):
        """``(None, reading)``, or ``((count name, reason), None)`` for a value not to send."""
        for what, v in (("value", value), ("time_s", time_s)):
            if v is None and what == "time_s":
                continue
            if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v):
                return ("bad_value", f"{what} is not a finite number: {str(v)[:40]!r}"), None
        fix = self.telemetry.latest()
        if fix is None:
            return ("no_position", "no position fix from the autopilot yet"), None
        age_s = time.monotonic() - fix.received_s
        if age_s > self.max_fix_age_s:
            why = self.telemetry.error or "no GLOBAL_POSITION_INT with a fix since"
            return ("stale_position", f"latest position fix {age_s:.1f} s old ({why})"), None
        reading = {"schema": SENSOR_SCHEMA, "fleet": self.fleet, "sysid": self.sysid, "seq": self._seq,
                   "time_s": time.time() if time_s is None else float(time_s), "lat_deg": fix.lat_deg,
                   "lon_deg": fix.lon_deg, "alt_m": fix.alt_m, "value": float(value)}
        return None, reading

    def wait_for_subscriber(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` until a zenoh subscriber (the ground station) matches the key;
        whether one does (a reading put before that is lost)."""
        deadline = time.monotonic() + timeout_s
        while not self._sensor.has_subscribers(self.sysid) and time.monotonic() < deadline:
            time.sleep(0.02)
        return self._sensor.has_subscribers(self.sysid)

    def summary(self) -> str:
        """One line of the counts, e.g. ``published 120; held 2 (no position yet 2, stale position 0);
        bad values 1``."""
        c = self.counts
        held = c["no_position"] + c["stale_position"]
        return (f"published {c['published']}; held {held} (no position yet {c['no_position']}, "
                f"stale position {c['stale_position']}); bad values {c['bad_value']}")

    def close(self) -> None:
        """Undeclare the publisher, close the zenoh session and the MAVLink link (idempotent)."""
        sensor, session, self._sensor, self._session = self._sensor, self._session, None, None
        if sensor is not None:
            sensor.close()
        if session is not None:
            session.close()
        self.telemetry.close()

    def __enter__(self) -> "Publisher":
        return self

    def __exit__(self, *_exc) -> None:
        self.close()
