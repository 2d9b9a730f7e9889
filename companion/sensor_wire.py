"""The sender's side of the sensor readings' wire format (``docs/interfaces.md``, zenoh section).

One copy for every sender: the mock fleet's sensors (``sitl_mock.fleet``), the virtual sensor
(``swarmseek sensor``) and a real sensor on a companion computer (:class:`companion.publisher.
Publisher`, ``swarmseek publish``). :func:`encode_reading` turns a reading dict of schema
``swarmseek.sensor.v1`` into its UTF-8 JSON payload; :class:`SensorPublisher` puts it on
``swarmseek/<fleet>/vehicle/<sysid>/sensor`` (``application/json``, reliable, congestion control
BLOCK), on a session configured by :func:`wire.zenoh_config.zenoh_config`. The ground station's
side (decoding and every check) is :mod:`mission.telemetry.reading_format`.
"""
from __future__ import annotations

import json
import numbers

from wire.fleet_name import check_fleet_name

__all__ = [
    "SENSOR_SCHEMA",
    "SENSOR_ENCODING",
    "check_sysid",
    "encode_reading",
    "sensor_key",
    "SensorPublisher",
]

SENSOR_SCHEMA = "swarmseek.sensor.v1"
SENSOR_ENCODING = "application/json"


def check_sysid(sysid) -> int:
    """``sysid`` as an int when it is an integer (not a bool) in 1..255.

    Raises
    ------
    ValueError
        Otherwise.
    """
    if isinstance(sysid, bool) or not isinstance(sysid, numbers.Integral) or not 1 <= sysid <= 255:
        raise ValueError(f"sysid must be an integer in 1..255, got {sysid!r}")
    return int(sysid)


def sensor_key(fleet: str, sysid: int) -> str:
    """Zenoh key of a vehicle's sensor readings: ``swarmseek/<fleet>/vehicle/<sysid>/sensor``.

    Raises
    ------
    ValueError
        If the fleet name is empty or holds key-expression characters, or sysid is not 1..255.
    """
    return f"swarmseek/{check_fleet_name(fleet)}/vehicle/{check_sysid(sysid)}/sensor"


def encode_reading(reading: dict) -> bytes:
    """UTF-8 JSON payload of a reading (compact; NaN / infinity rejected with ValueError)."""
    try:
        return json.dumps(reading, separators=(",", ":"), allow_nan=False).encode("utf-8")
    except ValueError as exc:
        raise ValueError(f"reading is not valid JSON (non-finite number?): {exc}") from None


class SensorPublisher:
    """The sensor publishers of a fleet's vehicles on one zenoh session.

    Parameters
    ----------
    session : zenoh.Session
        An open session (the caller owns it and closes it after :meth:`close`).
    fleet : str
        Fleet name.
    sysids : list of int
        Vehicles whose readings this object publishes.

    Attributes
    ----------
    published : int
        Readings put so far.
    published_matched : int
        Readings put since a subscriber first matched their key (counted with ``track_matching``).
    """

    def __init__(self, session, fleet: str, sysids: list[int], track_matching: bool = False):
        import zenoh

        self.fleet = check_fleet_name(fleet)
        self.published = 0
        self.published_matched = 0
        self._track_matching = bool(track_matching)
        self._matched: set[int] = set()
        self._publishers = {}
        try:
            for sysid in sysids:
                sid = check_sysid(sysid)
                if sid in self._publishers:
                    raise ValueError(f"sysid {sid} listed twice")
                self._publishers[sid] = session.declare_publisher(
                    sensor_key(self.fleet, sid),
                    encoding=zenoh.Encoding.APPLICATION_JSON,
                    congestion_control=zenoh.CongestionControl.BLOCK,
                    reliability=zenoh.Reliability.RELIABLE,
                )
        except BaseException:
            self.close()
            raise

    @property
    def sysids(self) -> list[int]:
        """System ids this object publishes for."""
        return list(self._publishers)

    def has_subscribers(self, sysid: int) -> bool:
        """True when some subscriber matches the sensor key of ``sysid``."""
        status = self._publisher(sysid).matching_status
        # zenoh-python 1.x returns a MatchingStatus object (always truthy), not a bool
        return bool(getattr(status, "matching", status))

    def _publisher(self, sysid):
        try:
            return self._publishers[sysid]
        except KeyError:
            raise ValueError(
                f"no sensor publisher for sysid {sysid!r} in fleet {self.fleet!r}; "
                f"known: {sorted(self._publishers)}") from None

    def publish(self, reading: dict) -> None:
        """Put one reading (schema ``swarmseek.sensor.v1``: :meth:`sitl_mock.sensor.SignalSensor.sample`,
        :meth:`companion.publisher.Publisher.put`) on its vehicle's key.

        Raises
        ------
        ValueError
            If the reading's fleet or sysid is not one of this publisher's, or it cannot be
            encoded.
        """
        if reading.get("fleet") != self.fleet:
            raise ValueError(f"reading of fleet {reading.get('fleet')!r} given to the publisher of {self.fleet!r}")
        sysid = reading.get("sysid")
        pub = self._publisher(sysid)
        matched = self._track_matching and (sysid in self._matched or self._check_matched(sysid))
        pub.put(encode_reading(reading))
        self.published += 1
        self.published_matched += matched

    def _check_matched(self, sysid) -> bool:
        """Whether ``sysid``'s key has a subscriber; once it has, it is not asked again (a
        subscriber that leaves is the end of the ground station's run)."""
        if self.has_subscribers(sysid):
            self._matched.add(sysid)
            return True
        return False

    def close(self) -> None:
        """Undeclare every publisher (idempotent)."""
        pubs, self._publishers = self._publishers, {}
        for pub in pubs.values():
            try:
                pub.undeclare()
            except Exception:  # already undeclared or session closed: nothing left to release
                pass

    def __enter__(self) -> "SensorPublisher":
        return self

    def __exit__(self, *_exc) -> None:
        self.close()
