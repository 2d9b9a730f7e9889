"""Compare two observations of the conformance script (mock vs real SITL) with explicit tolerances.

:func:`compare` returns one :class:`Difference` per behaviour that disagrees; each has a stable
``key`` (e.g. ``ack:mode_invalid``) that the tests match against the documented list of known,
accepted differences (docs/interfaces.md, section "Mock vs real SITL"). The tolerances:

* COMMAND_ACK result: identical per command (``ack:<step>``).
* custom_mode: identical after every mode step (``mode:<step>``).
* parameters: same answer or the same absence of one; the failsafe parameter only by type (its
  value is the launcher's choice) (``param:<step>``).
* mission round trip: same upload ACK, same request message kind, same count, waypoints read back
  identical (``mission:<what>``).
* parameters of the mock's table: they exist on the SITL with the same MAV_PARAM_TYPE
  (``param_type:<NAME>``; values differ on purpose: the mock's come from its dynamics).
* message set: the mock sends every message of :data:`COORDINATOR_MESSAGES`, and every message
  of :data:`WATCHED_MESSAGES` that the SITL sends (``message:<NAME>``); more is allowed.
* rates: every rate the coordinator asks for within a factor :data:`RATE_FACTOR` of the SITL's
  (``rate:<NAME>``).
* STATUSTEXT: the refusal of arming in the return mode matches the SITL's pattern
  (:data:`REFUSAL_PATTERNS`) (``text:arm_in_rtl``); the texts about modes while the unknown
  mode is asked for are identical (``text:mode_invalid``).
* state changes: the same order (``events:order``), the same sequence of EXTENDED_SYS_STATE
  landed states (on ground, taking off, in air, landing, on ground: ``events:landed_states``) and
  durations within a factor :data:`DURATION_FACTOR` plus :data:`DURATION_SLACK_S`
  (``duration:<name>``).
* the position target is reached in both (``target:reached``).
"""
from __future__ import annotations

import re
from dataclasses import dataclass

__all__ = [
    "COORDINATOR_MESSAGES",
    "DURATION_FACTOR",
    "DURATION_SLACK_S",
    "EVENT_ORDER",
    "RATE_FACTOR",
    "REFUSAL_PATTERNS",
    "WATCHED_MESSAGES",
    "Difference",
    "compare",
]

#: Messages mission.vehicle.vehicle_link handles (AUTOPILOT_VERSION only comes on request).
COORDINATOR_MESSAGES = ("HEARTBEAT", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "SYS_STATUS",
                        "EXTENDED_SYS_STATE", "HOME_POSITION", "COMMAND_ACK", "STATUSTEXT")
#: Messages whose presence is compared (coordinator's, plus what a GCS or the sensor may use).
WATCHED_MESSAGES = COORDINATOR_MESSAGES + ("GPS_RAW_INT", "ATTITUDE", "BATTERY_STATUS", "PARAM_VALUE",
                                           "MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ACK",
                                           "MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_CURRENT",
                                           "POSITION_TARGET_LOCAL_NED", "POSITION_TARGET_GLOBAL_INT",
                                           "VFR_HUD", "SYSTEM_TIME")
#: A requested rate must be within this factor of the SITL's (both ways).
RATE_FACTOR = 2.0
#: Durations between state changes: within this factor (both ways) ...
DURATION_FACTOR = 3.0
#: ... after this many seconds of slack (autopilot time) on the larger one.
DURATION_SLACK_S = 3.0
#: State changes every run goes through, in this order.
EVENT_ORDER = ("armed", "above_1m", "takeoff_alt", "target_reached", "rtl_under_way", "land_commanded",
               "disarmed_after_land")
_DURATIONS = {"arm_to_1m": ("armed", "above_1m"), "1m_to_takeoff_alt": ("above_1m", "takeoff_alt"),
              "land_to_landed": ("land_commanded", "landed"),
              "land_to_disarmed": ("land_commanded", "disarmed_after_land")}
#: The real autopilot's text when arming is refused in its return mode (what the mock must match).
_MODE_TEXT = re.compile("mode", re.IGNORECASE)
REFUSAL_PATTERNS = {"ardupilot": r"^Arm: RTL mode not armable$", "px4": r"^Arming denied: "}


@dataclass(frozen=True)
class Difference:
    """One behaviour where mock and SITL disagree."""

    key: str
    mock: object
    sitl: object

    def __str__(self) -> str:
        return f"{self.key}: mock {self.mock!r}, SITL {self.sitl!r}"


def compare(mock, sitl) -> list[Difference]:
    """Every difference between the mock's and the SITL's observation (see the module docstring)."""
    diffs: list[Difference] = []
    diffs += _compare_maps("ack", mock.acks, sitl.acks)
    diffs += _compare_maps("mode", mock.modes, sitl.modes)
    diffs += _compare_params(mock.params, sitl.params)
    diffs += _compare_mission(mock.details, sitl.details)
    diffs += _compare_maps("param_type", mock.details["param_types"], sitl.details["param_types"])
    diffs += _compare_messages(mock, sitl)
    diffs += _compare_texts(mock, sitl)
    diffs += _compare_events(mock.events_s, sitl.events_s)
    for key in ("autopilot", "mav_type"):
        if mock.details.get(key) != sitl.details.get(key):
            diffs.append(Difference(f"identity:{key}", mock.details.get(key), sitl.details.get(key)))
    reached = (mock.details["target"]["reached"], sitl.details["target"]["reached"])
    if reached != (True, True):
        diffs.append(Difference("target:reached", *reached))
    return diffs


def _compare_maps(prefix: str, mock: dict, sitl: dict) -> list[Difference]:
    return [Difference(f"{prefix}:{k}", mock.get(k), sitl.get(k)) for k in sorted(set(mock) | set(sitl))
            if mock.get(k) != sitl.get(k)]


def _compare_params(mock: dict, sitl: dict) -> list[Difference]:
    diffs = []
    for k in sorted(set(mock) | set(sitl)):
        a, b = mock.get(k), sitl.get(k)
        if k == "gcs_failsafe" and a is not None and b is not None:
            a, b = a[2], b[2]  # the value is the launcher's choice: compare the type only
        if a != b:
            diffs.append(Difference(f"param:{k}", mock.get(k), sitl.get(k)))
    return diffs


def _compare_mission(mock: dict, sitl: dict) -> list[Difference]:
    facts = {
        "upload_ack": lambda d: d["mission_upload"]["ack"],
        "request_kind": lambda d: sorted({kind for kind, _ in d["mission_upload"]["requests"]}),
        "count": lambda d: d["mission_download"]["count"],
        "waypoints_match": lambda d: d["mission_download"]["waypoints_match"],
        "item0_command": lambda d: d["mission_download"]["item0_command"],
        "frames": lambda d: d["mission_download"]["frames"],
    }
    return [Difference(f"mission:{name}", get(mock), get(sitl)) for name, get in facts.items()
            if get(mock) != get(sitl)]


def _compare_messages(mock, sitl) -> list[Difference]:
    diffs = []
    for name in WATCHED_MESSAGES:
        in_sitl = sitl.message_counts.get(name, 0) > 0
        in_mock = mock.message_counts.get(name, 0) > 0
        if not in_mock and (in_sitl or name in COORDINATOR_MESSAGES):
            diffs.append(Difference(f"message:{name}", in_mock, in_sitl))
    from tests.conformance.script import COORDINATOR_RATES_HZ
    for name in COORDINATOR_RATES_HZ:
        a, b = mock.rates_hz.get(name, 0.0), sitl.rates_hz.get(name, 0.0)
        if not (a > 0 and b > 0 and 1 / RATE_FACTOR <= a / b <= RATE_FACTOR):
            diffs.append(Difference(f"rate:{name}", a, b))
    return diffs


def _texts(obs, step: str) -> list[str]:
    return [text for s, _, text in obs.statustexts if s == step]


def _compare_texts(mock, sitl) -> list[Difference]:
    diffs = []
    pattern = re.compile(REFUSAL_PATTERNS[sitl.flavour])
    a, b = _texts(mock, "arm_in_rtl"), _texts(sitl, "arm_in_rtl")
    if any(pattern.search(t) for t in a) != any(pattern.search(t) for t in b):
        diffs.append(Difference("text:arm_in_rtl", a, b))
    a, b = ([t for t in _texts(obs, "modes") if _MODE_TEXT.search(t)] for obs in (mock, sitl))
    if a != b:
        diffs.append(Difference("text:mode_invalid", a, b))
    return diffs


def _compare_events(mock: dict, sitl: dict) -> list[Difference]:
    diffs = []
    order = {name: [n for n in EVENT_ORDER if n in ev] for name, ev in (("mock", mock), ("sitl", sitl))}
    sorted_ok = {name: [n for n in order[name]] == sorted(order[name], key=lambda n: ev[n])
                 for name, ev in (("mock", mock), ("sitl", sitl))}
    if order["mock"] != list(EVENT_ORDER) or order["sitl"] != list(EVENT_ORDER) or not all(sorted_ok.values()):
        diffs.append(Difference("events:order", order["mock"], order["sitl"]))
        return diffs
    states = {name: [n for n in sorted(ev, key=ev.get) if n.startswith("landed_state_") or n == "landed"]
              for name, ev in (("mock", mock), ("sitl", sitl))}
    if states["mock"] != states["sitl"]:
        diffs.append(Difference("events:landed_states", states["mock"], states["sitl"]))
    for name, (start, end) in _DURATIONS.items():
        if not all(k in ev for k in (start, end) for ev in (mock, sitl)):
            continue  # a missing state change is reported by events:landed_states
        a, b = mock[end] - mock[start], sitl[end] - sitl[start]
        lo, hi = min(a, b), max(a, b)
        if hi > DURATION_FACTOR * lo + DURATION_SLACK_S:
            diffs.append(Difference(f"duration:{name}", round(a, 1), round(b, 1)))
    return diffs
