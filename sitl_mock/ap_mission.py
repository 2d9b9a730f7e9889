"""The MAVLink mission protocol, vehicle side (missions, fences, rally points).

Upload (GCS -> vehicle): MISSION_COUNT, then the vehicle requests each item with
MISSION_REQUEST_INT, retrying after a timeout, and ends with MISSION_ACK. Download (vehicle ->
GCS): MISSION_REQUEST_LIST -> MISSION_COUNT, MISSION_REQUEST_INT -> MISSION_ITEM_INT. The
legacy float forms (MISSION_ITEM, MISSION_REQUEST) are answered too. With ``home_as_item0``
(ArduPilot) the mission list always starts with the home position as item 0, as ArduPilot's does.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

__all__ = ["MissionItem", "MissionServer", "MISSION_TIMEOUT_S", "MISSION_RETRIES", "MAX_ITEMS"]

#: Item request timeout and retries (the mission protocol's defaults).
MISSION_TIMEOUT_S = 1.5
MISSION_RETRIES = 5
MAX_ITEMS = 1000

_MISSION = mavlink2.MAV_MISSION_TYPE_MISSION
_ALL = mavlink2.MAV_MISSION_TYPE_ALL
_TYPES = (mavlink2.MAV_MISSION_TYPE_MISSION, mavlink2.MAV_MISSION_TYPE_FENCE,
          mavlink2.MAV_MISSION_TYPE_RALLY)


@dataclass(frozen=True)
class MissionItem:
    """One stored item, as MISSION_ITEM_INT carries it (x, y: degrees * 1e7 for global frames)."""

    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: int
    y: int
    z: float


@dataclass
class _Upload:
    mission_type: int
    count: int
    partner: tuple[int, int]
    items: list = field(default_factory=list)
    last_request_s: float = 0.0
    retries: int = 0


class MissionServer:
    """Vehicle side of the mission protocol for one autopilot.

    Parameters
    ----------
    mav : pymavlink MAVLink
        Encoder of the vehicle (builds the replies).
    emit : callable
        ``emit(message)`` sends a message on every link.
    home_item : callable
        ``home_item() -> MissionItem`` for ArduPilot's item 0 (None when home is unknown).
    home_as_item0 : bool
        ArduPilot behaviour (item 0 of the mission list is home).
    counters : collections.Counter
        Where protocol errors are counted.
    """

    def __init__(self, mav, emit, home_item, home_as_item0: bool, counters):
        self._mav = mav
        self._emit = emit
        self._home_item = home_item
        self._home_as_item0 = home_as_item0
        self._counters = counters
        self._lists: dict[int, list[MissionItem]] = {t: [] for t in _TYPES}
        self._upload: _Upload | None = None
        self.current_seq = 0
        #: incremented every time a mission list changes (the autopilot restarts its mission)
        self.generation = 0
        self._handlers = {
            "MISSION_COUNT": self._on_mission_count,
            "MISSION_ITEM_INT": self._on_mission_item_int,
            "MISSION_ITEM": self._on_mission_item,
            "MISSION_REQUEST_LIST": self._on_mission_request_list,
            "MISSION_REQUEST_INT": self._on_mission_request_int,
            "MISSION_REQUEST": self._on_mission_request,
            "MISSION_ACK": self._on_mission_ack,
            "MISSION_CLEAR_ALL": self._on_mission_clear_all,
            "MISSION_SET_CURRENT": self._on_mission_set_current,
        }

    # ---------------------------------------------------------------- queries
    def items(self, mission_type: int = _MISSION) -> list[MissionItem]:
        """The stored list as a GCS would download it (ArduPilot: home first)."""
        items = list(self._lists[mission_type])
        if mission_type == _MISSION and self._home_as_item0:
            home = self._home_item()
            if home is not None:
                items = [home] + items[1:] if items else [home]
            elif not items:
                items = []
        return items

    def nav_items(self) -> list[MissionItem]:
        """Mission items to fly (without ArduPilot's home item)."""
        items = self._lists[_MISSION]
        return list(items[1:] if self._home_as_item0 else items)

    @property
    def upload_in_progress(self) -> bool:
        """True while an upload is waiting for items."""
        return self._upload is not None

    # --------------------------------------------------------------- handlers
    def handle(self, msg, t_s: float) -> bool:
        """Process a mission-protocol message; returns False if ``msg`` is not one."""
        handler = self._handlers.get(msg.get_type())
        if handler is None:
            return False
        handler(msg, t_s)
        return True

    def poll(self, t_s: float) -> None:
        """Retry or abandon a stalled upload (call regularly)."""
        up = self._upload
        if up is None or t_s - up.last_request_s < MISSION_TIMEOUT_S:
            return
        if up.retries >= MISSION_RETRIES:
            self._counters["mission_upload_timeout"] += 1
            self._ack(up.partner, up.mission_type, mavlink2.MAV_MISSION_OPERATION_CANCELLED)
            self._upload = None
            return
        up.retries += 1
        self._request(up, t_s)

    def _mission_type(self, msg) -> int | None:
        mt = getattr(msg, "mission_type", _MISSION)
        if mt not in _TYPES:
            self._counters["mission_bad_type"] += 1
            self._ack((msg.get_srcSystem(), msg.get_srcComponent()), mt,
                      mavlink2.MAV_MISSION_UNSUPPORTED)
            return None
        return mt

    def _on_mission_count(self, msg, t_s):
        mt = self._mission_type(msg)
        if mt is None:
            return
        partner = (msg.get_srcSystem(), msg.get_srcComponent())
        if msg.count > MAX_ITEMS:
            self._ack(partner, mt, mavlink2.MAV_MISSION_NO_SPACE)
            return
        if msg.count == 0:
            self._commit(mt, [])
            self._ack(partner, mt, mavlink2.MAV_MISSION_ACCEPTED)
            return
        self._upload = _Upload(mt, msg.count, partner)
        self._request(self._upload, t_s)

    def _on_mission_item_int(self, msg, t_s):
        self._store_item(msg, msg.x, msg.y, t_s)

    def _on_mission_item(self, msg, t_s):
        self._store_item(msg, int(round(msg.x * 1e7)), int(round(msg.y * 1e7)), t_s)

    def _store_item(self, msg, x: int, y: int, t_s: float) -> None:
        up = self._upload
        mt = getattr(msg, "mission_type", _MISSION)
        if up is None or mt != up.mission_type:
            self._counters["mission_unexpected_item"] += 1
            return
        expected = len(up.items)
        if msg.seq != expected:
            self._counters["mission_bad_seq"] += 1
            if msg.seq > expected:
                self._ack(up.partner, mt, mavlink2.MAV_MISSION_INVALID_SEQUENCE)
            self._request(up, t_s)
            return
        up.items.append(MissionItem(msg.seq, msg.frame, msg.command, msg.current, msg.autocontinue,
                                    msg.param1, msg.param2, msg.param3, msg.param4, x, y, msg.z))
        up.retries = 0
        if len(up.items) == up.count:
            self._commit(mt, up.items)
            self._ack(up.partner, mt, mavlink2.MAV_MISSION_ACCEPTED)
            self._upload = None
        else:
            self._request(up, t_s)

    def _on_mission_request_list(self, msg, t_s):
        mt = self._mission_type(msg)
        if mt is None:
            return
        self._emit(self._mav.mission_count_encode(
            msg.get_srcSystem(), msg.get_srcComponent(), len(self.items(mt)), mt))

    def _on_mission_request_int(self, msg, t_s):
        item = self._lookup(msg)
        if item is not None:
            self._emit(self._mav.mission_item_int_encode(
                msg.get_srcSystem(), msg.get_srcComponent(), item.seq, item.frame, item.command,
                int(item.seq == self.current_seq), item.autocontinue, item.param1, item.param2,
                item.param3, item.param4, item.x, item.y, item.z, msg.mission_type))

    def _on_mission_request(self, msg, t_s):
        item = self._lookup(msg)
        if item is not None:
            self._emit(self._mav.mission_item_encode(
                msg.get_srcSystem(), msg.get_srcComponent(), item.seq, item.frame, item.command,
                int(item.seq == self.current_seq), item.autocontinue, item.param1, item.param2,
                item.param3, item.param4, item.x / 1e7, item.y / 1e7, item.z, msg.mission_type))

    def _lookup(self, msg) -> MissionItem | None:
        mt = self._mission_type(msg)
        if mt is None:
            return None
        items = self.items(mt)
        if not 0 <= msg.seq < len(items):
            self._counters["mission_bad_seq"] += 1
            self._ack((msg.get_srcSystem(), msg.get_srcComponent()), mt,
                      mavlink2.MAV_MISSION_INVALID_SEQUENCE)
            return None
        return items[msg.seq]

    def _on_mission_ack(self, msg, t_s):
        """End of a download (nothing to do) or a GCS cancelling an upload."""
        up = self._upload
        if up is not None and (msg.get_srcSystem(), msg.get_srcComponent()) == up.partner:
            self._upload = None

    def _on_mission_clear_all(self, msg, t_s):
        mt = getattr(msg, "mission_type", _MISSION)
        types = _TYPES if mt == _ALL else (mt,)
        if mt != _ALL and mt not in _TYPES:
            self._ack((msg.get_srcSystem(), msg.get_srcComponent()), mt,
                      mavlink2.MAV_MISSION_UNSUPPORTED)
            return
        for t in types:
            self._commit(t, [])
        self._ack((msg.get_srcSystem(), msg.get_srcComponent()), mt, mavlink2.MAV_MISSION_ACCEPTED)

    def _on_mission_set_current(self, msg, t_s):
        n = len(self.items(_MISSION))
        if 0 <= msg.seq < max(n, 1):
            self.current_seq = msg.seq
            self._emit(self._mav.mission_current_encode(self.current_seq))
        else:
            self._counters["mission_bad_seq"] += 1

    # ---------------------------------------------------------------- helpers
    def _commit(self, mission_type: int, items: list[MissionItem]) -> None:
        self._lists[mission_type] = list(items)
        if mission_type == _MISSION:
            self.current_seq = 0
            self.generation += 1

    def _request(self, up: _Upload, t_s: float) -> None:
        up.last_request_s = t_s
        self._emit(self._mav.mission_request_int_encode(
            up.partner[0], up.partner[1], len(up.items), up.mission_type))

    def _ack(self, partner, mission_type: int, result: int) -> None:
        self._emit(self._mav.mission_ack_encode(partner[0], partner[1], result, mission_type))
