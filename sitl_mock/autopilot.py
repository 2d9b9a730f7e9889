"""One mock autopilot: MAVLink receive path, flight-mode state machine, failsafes, telemetry.

:class:`MockAutopilot` is transport-agnostic: the transports hand it parsed messages
(:meth:`MockAutopilot.handle_message`) and take the encoded frames it produces
(:meth:`MockAutopilot.drain_outbox`); the fleet calls :meth:`MockAutopilot.step` before each
physics step. Everything runs on the fleet's simulated clock. Commands are in
:mod:`sitl_mock.ap_commands`, setpoints and flight behaviours in :mod:`sitl_mock.ap_flight`,
the dispatch of accepted messages and the parameter protocol in :mod:`sitl_mock.ap_receive`
(``classify_bad_frame`` is imported from there).
"""
from __future__ import annotations

from collections import Counter

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from formation.geodesy import TangentFrame, enu_to_ned, geodetic_to_enu
from sitl_mock import (
    ap_failsafe,
    ap_flight,
    ap_flight_state,
    ap_mission_exec,
    ap_receive,
    ap_setpoints,
)
from sitl_mock.ap_frames import pack_unsigned_v2
from sitl_mock.ap_signing import VehicleSigning
from wire.signing import signing_timestamp
from sitl_mock.ap_mission import MissionItem, MissionServer
from sitl_mock.ap_modes import Personality, make_personality
from sitl_mock.ap_params import ParamTable
from sitl_mock.ap_receive import classify_bad_frame
from sitl_mock.ap_telemetry import WIND_MSG_IDS, MessageScheduler, build_message
from sitl_mock.ap_wind import WindEstimateModel
from sitl_mock.faults import FaultSet

__all__ = ["MockAutopilot", "PX4_GCS_HEARTBEAT_TIMEOUT_S", "PX4_STALE_STATUSTEXT_S"]

#: PX4 hears a ground station while its HEARTBEATs come within this (``telemetry_status.HEARTBEAT_TIMEOUT_US``)
PX4_GCS_HEARTBEAT_TIMEOUT_S = 2.5
#: PX4 drops a held STATUSTEXT older than this (``MavlinkStreamStatustext``: "don't send stale messages")
PX4_STALE_STATUSTEXT_S = 5.0

_TARGETED_AUTOPILOT_COMPONENTS = (0, mavlink2.MAV_COMP_ID_AUTOPILOT1)


class MockAutopilot:
    """A simulated ArduPilot or PX4 multicopter autopilot speaking MAVLink 2.

    Parameters
    ----------
    sysid : int
        MAVLink system id (component id is 1).
    personality : str or Personality
        ``"ardupilot"`` or ``"px4"``.
    multicopter : sitl_mock.dynamics.Multicopter
        The vehicle it flies (its LOCAL_NED origin is ``home``).
    home : tuple of float
        ``(lat_deg, lon_deg, alt_m)`` of the LOCAL_NED origin (on the ground).
    t_boot_s : float
        Boot time on the simulated clock.
    faults : FaultSet, optional
    param_overrides : dict, optional
        Parameter values replacing the personality's defaults.
    uid : int, optional
        AUTOPILOT_VERSION.uid (unique per vehicle; default derived from sysid).
    signing_key : bytes, optional
        32-byte MAVLink 2 signing key: signing on from boot (see :mod:`sitl_mock.ap_signing`).
    wind : WindEstimateModel, optional
        The vehicle's wind estimate (WIND_COV on PX4, WIND on ArduPilot); default: the dynamics'
        constant wind, with an error drawn from a generator seeded by ``uid``.

    Attributes
    ----------
    counters : collections.Counter
        Receive / transmit / protocol counters (``rx_frames``, ``rx_bad_crc``, ``rx_malformed``,
        ``rx_unknown_msg``, ``rx_not_for_us``, ``tx_frames``, ...; with signing on
        ``rx_unsigned``, ``rx_bad_signature``, ``rx_replayed``, ``rx_unsigned_accepted``,
        ``signing_setup_accepted``, ``signing_setup_refused_armed``, ``signing_disabled``).
        A message handler that raised is counted in ``rx_handler_error`` (and
        ``rx_handler_error:<type>``), a telemetry message that could not be built or encoded in
        ``tx_error`` (and ``tx_error:<type>``).
    last_error : str or None
        Description of the last such error (message type, exception), for diagnosis.
    signing : VehicleSigning
        MAVLink 2 signing state (key set by SETUP_SIGNING or :meth:`set_signing_key`).
    params : ParamTable
    missions : MissionServer
    mode_name : str
    wind : WindEstimateModel
    """

    def __init__(self, sysid: int, personality, multicopter, home, t_boot_s: float,
                 faults: FaultSet | None = None, param_overrides: dict | None = None,
                 uid: int | None = None, signing_key: bytes | None = None,
                 wind: WindEstimateModel | None = None):
        if not 1 <= int(sysid) <= 255:
            raise ValueError(f"sysid must be 1..255, got {sysid!r}")
        self.personality: Personality = (make_personality(personality)
                                         if isinstance(personality, str) else personality)
        self.sysid = int(sysid)
        self.mc = multicopter
        self.faults = faults if faults is not None else FaultSet()
        self.uid = int(uid) if uid is not None else (0x5357_0000_0000_0000 | self.sysid)
        self.wind = wind if wind is not None else WindEstimateModel(
            multicopter.params.wind_ned_m_s, np.random.default_rng([self.uid, 0x57494E44]))
        self.mav = mavlink2.MAVLink(None, srcSystem=self.sysid, srcComponent=1)
        self.counters: Counter = Counter()
        self.last_error: str | None = None
        self.signing = VehicleSigning(self.mav, self.counters)
        self.params = ParamTable(self.personality.param_specs(self.sysid, multicopter.params),
                                 self.personality.param_bytewise, param_overrides)
        self._origin = tuple(float(v) for v in home)
        self._frame = TangentFrame(self._origin)
        self._outbox: list[bytes] = []
        self.missions = MissionServer(self.mav, self.emit, self._home_item,
                                      self.personality.name == "ardupilot", self.counters)
        self._boot(t_boot_s)
        self.apply_params()
        if signing_key is not None:
            self.set_signing_key(signing_key, t_boot_s)

    # ------------------------------------------------------------------ state
    def _boot(self, t_s: float) -> None:
        self.t_boot_s = float(t_s)
        p = self.personality
        self.scheduler = MessageScheduler(t_s, {p.wind_msg_id: p.wind_default_hz},
                                          [m for m in WIND_MSG_IDS if m != p.wind_msg_id])
        self.mode_name = self.personality.boot_mode
        self.home_ned = np.zeros(3)
        self.home: tuple | None = None
        self.failsafe: str | None = None
        self.flight = ap_flight_state.FlightState()
        self.last_gcs_heartbeat_s: float | None = None
        #: PX4's STATUSTEXTs held while no ground station is heard: ``(t_s, message)`` (:meth:`statustext`)
        self._held_statustexts: list = []
        self._est_key = None
        self._est = None
        self._local_key = None
        self._local = None
        self._last_t_s = t_s

    @property
    def armed(self) -> bool:
        """True while the motors are armed."""
        return bool(self.mc.armed)

    @property
    def behaviour(self) -> str:
        """The internal behaviour of the current mode (hold, guided, offboard, ...)."""
        return self.personality.behaviour(self.mode_name)

    def time_boot_ms(self, t_s: float) -> int:
        """Milliseconds since boot (wraps at 2**32)."""
        return int((t_s - self.t_boot_s) * 1000.0) & 0xFFFFFFFF

    def position_ready(self, t_s: float) -> bool:
        """True once the position estimate (GPS + EKF) is usable."""
        return self.mc.position_estimate_ready(t_s - self.t_boot_s)

    @property
    def home_origin(self) -> tuple:
        """``(lat_deg, lon_deg, alt_m)`` of this vehicle's LOCAL_NED origin."""
        return self._origin

    def home_geodetic(self) -> tuple | None:
        """Home ``(lat_deg, lon_deg, alt_m)``, None until the position estimate is ready."""
        return self.home

    def true_position_ned(self) -> np.ndarray:
        """True position in this vehicle's LOCAL_NED frame (metres from its origin)."""
        return self.mc.position_ned_m

    def ned_to_geodetic(self, ned) -> tuple[float, float, float]:
        """Convert a LOCAL_NED point of this vehicle to ``(lat_deg, lon_deg, alt_m)``."""
        n, e, d = ned
        return self._frame.ned_to_geodetic(float(n), float(e), float(d))

    def geodetic_to_ned(self, lat_deg: float, lon_deg: float, alt_m: float) -> np.ndarray:
        """Convert a geodetic point to this vehicle's LOCAL_NED frame."""
        return enu_to_ned(geodetic_to_enu(lat_deg, lon_deg, alt_m, self._origin))

    def estimate_local(self, t_s: float) -> tuple:
        """Reported ``(ned_m, vel_ned_m_s)`` (one draw per step), what :meth:`estimate` converts.

        The messages that need no latitude (LOCAL_POSITION_NED, ATTITUDE) read this: a step
        that sends only those does no geodetic conversion.
        """
        key = self._last_t_s
        if self._local_key != key or self._local is None:
            self._local = (self.mc.reported_position_ned_m(), self.mc.velocity_ned_m_s)
            self._local_key = key
        return self._local

    def estimate(self, t_s: float) -> tuple:
        """Reported state ``(ned_m, vel_ned_m_s, lat_deg, lon_deg, alt_m)`` (one draw per step)."""
        key = self._last_t_s
        if self._est_key != key or self._est is None:
            ned, vel = self.estimate_local(t_s)
            lat, lon, alt = self.ned_to_geodetic(ned)
            self._est = (ned, vel, lat, lon, alt)
            self._est_key = key
        return self._est

    def health_ok(self, t_s: float) -> bool:
        """GPS and pre-arm checks healthy (SYS_STATUS health bits)."""
        return self.position_ready(t_s) and ap_flight.arming_problem(self, t_s, self.mode_name,
                                                                    check_mode=False) is None

    def landed_state(self) -> int:
        """EXTENDED_SYS_STATE.landed_state."""
        mc = self.mc
        if mc.landed or (not mc.armed and mc.on_ground):
            return mavlink2.MAV_LANDED_STATE_ON_GROUND
        if mc.mode == "takeoff":
            return mavlink2.MAV_LANDED_STATE_TAKEOFF
        if mc.mode == "land" and not self.flight.descent_without_pilot:
            return mavlink2.MAV_LANDED_STATE_LANDING
        return mavlink2.MAV_LANDED_STATE_IN_AIR

    def heartbeat_fields(self) -> tuple[int, int, int]:
        """HEARTBEAT ``(base_mode, custom_mode, system_status)``."""
        base = mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if self.personality.name == "ardupilot":
            base |= mavlink2.MAV_MODE_FLAG_STABILIZE_ENABLED | mavlink2.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
            if self.mode_name in self.personality.position_modes:
                base |= mavlink2.MAV_MODE_FLAG_GUIDED_ENABLED
        else:
            base |= mavlink2.MAV_MODE_FLAG_STABILIZE_ENABLED
            if self.behaviour in ("offboard", "mission", "rtl", "land", "takeoff", "hold"):
                base |= mavlink2.MAV_MODE_FLAG_GUIDED_ENABLED
            if self.behaviour in ("mission", "rtl", "land", "takeoff"):
                base |= mavlink2.MAV_MODE_FLAG_AUTO_ENABLED
        if self.mc.armed:
            base |= mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
        if self.failsafe is not None:
            status = mavlink2.MAV_STATE_CRITICAL
        elif self.mc.armed and not self.mc.landed:
            status = mavlink2.MAV_STATE_ACTIVE
        elif self.home is None:
            status = mavlink2.MAV_STATE_BOOT if self.personality.name == "ardupilot" \
                else mavlink2.MAV_STATE_STANDBY
        else:
            status = mavlink2.MAV_STATE_STANDBY
        return base, self.personality.custom_mode(self.mode_name), status

    def setpoint_echo(self):
        """Current GCS setpoint for POSITION_TARGET_* (None when none is being followed)."""
        return ap_setpoints.setpoint_echo(self)

    # ----------------------------------------------------------------- output
    def emit(self, msg) -> None:
        """Encode ``msg`` with this vehicle's identity and queue it for every link.

        Unsigned frames of messages without arrays are packed by :func:`sitl_mock.ap_frames.pack_unsigned_v2`
        (the same bytes as pymavlink, cheaper); signed ones and the rest by pymavlink.
        """
        mav = self.mav
        buf = None if mav.signing.sign_outgoing else pack_unsigned_v2(msg, mav.seq, mav.srcSystem,
                                                                      mav.srcComponent)
        if buf is None:
            buf = msg.pack(mav)
        mav.seq = (mav.seq + 1) % 256
        self._outbox.append(buf)
        self.counters["tx_frames"] += 1

    def drain_outbox(self) -> list[bytes]:
        """Frames produced since the last call (the transports send them)."""
        out, self._outbox = self._outbox, []
        return out

    def statustext(self, text: str, severity: int = mavlink2.MAV_SEVERITY_INFO) -> None:
        """Send a STATUSTEXT (at most 50 characters).

        PX4 sends its STATUSTEXTs only while it hears a ground station (``MavlinkStreamStatustext``:
        a GCS HEARTBEAT within ``telemetry_status`` 2.5 s) and drops those older than 5 s when it
        hears one again (measured on SIH: the words of a data-link loss came with the first GCS
        heartbeat back). The PX4 personality holds them the same way once a GCS was heard (before
        that it sends them at once, unlike PX4); :meth:`flush_statustexts` sends the held ones."""
        msg = self.mav.statustext_encode(severity, text.encode()[:50])
        last = self.last_gcs_heartbeat_s
        if (self.personality.name != "ardupilot" and last is not None
                and self._last_t_s - last > PX4_GCS_HEARTBEAT_TIMEOUT_S):
            self._held_statustexts.append((self._last_t_s, msg))
            return
        self.emit(msg)

    def flush_statustexts(self, t_s: float) -> None:
        """A ground station is heard again: send the held STATUSTEXTs not older than
        :data:`PX4_STALE_STATUSTEXT_S` (PX4 drops the others)."""
        held, self._held_statustexts = self._held_statustexts, []
        for held_s, msg in held:
            if t_s - held_s < PX4_STALE_STATUSTEXT_S:
                self.emit(msg)

    def send_message_now(self, msg_id: int, t_s: float) -> bool:
        """Send one telemetry message immediately; False if unsupported / not available."""
        msg = build_message(self, msg_id, t_s)
        if msg is None:
            return False
        self.emit(msg)
        return True

    # ------------------------------------------------------------------ signing
    def set_signing_key(self, key: bytes | None, t_s: float | None = None) -> None:
        """Set the 32-byte signing key (None or all zeros: signing off), as SETUP_SIGNING does.

        ``t_s`` (simulated Unix seconds, default the last step's time) gives the initial
        timestamp. Prefer calling it before the fleet starts.
        """
        t = self._last_t_s if t_s is None else float(t_s)
        self.signing.set_key(key, signing_timestamp(t))

    # ------------------------------------------------------------ receive path
    def accept_frame(self, msg) -> str | None:
        """Gate of the receive path: None to accept ``msg``, else the counter name of the reason.

        The one place where frames are rejected before being acted upon: bad CRC, malformed,
        unknown message, and with signing on unsigned, badly signed and replayed frames (see
        :mod:`sitl_mock.ap_signing`).
        """
        kind = msg.get_type()
        if kind == "BAD_DATA":
            return classify_bad_frame(str(getattr(msg, "reason", "")))
        if kind.startswith("UNKNOWN_"):  # a message id not in the dialect (CRC unverifiable)
            return "rx_unknown_msg"
        return self.signing.check(msg)

    def handle_message(self, msg, t_s: float) -> None:
        """Act on one received message (never raises on bad input; rejections are counted)."""
        reason = self.accept_frame(msg)
        if reason is not None:
            self.counters[reason] += 1
            return
        self.counters["rx_frames"] += 1
        target = getattr(msg, "target_system", 0)
        if target not in (0, self.sysid):
            self.counters["rx_not_for_us"] += 1
            return
        comp = getattr(msg, "target_component", 0)
        if comp not in _TARGETED_AUTOPILOT_COMPONENTS and msg.get_type() != "TIMESYNC":
            self.counters["rx_not_for_us"] += 1
            return
        if self.faults.crashed:
            return
        try:
            ap_receive.dispatch(self, msg, t_s)
        except Exception as exc:  # a handler bug must not stop the link: counted and kept
            self.counters["rx_handler_error"] += 1
            self.counters["rx_handler_error:" + type(exc).__name__] += 1
            self.last_error = f"{msg.get_type()}: {type(exc).__name__}: {exc}"

    def apply_params(self) -> None:
        """Push the parameters that shape the dynamics into the vehicle model."""
        ap_flight.apply_params(self)

    # -------------------------------------------------------------- simulation
    def step(self, t_s: float, dt_s: float) -> None:
        """Run the autopilot logic at ``t_s`` (before the physics step of ``dt_s``)."""
        self._last_t_s = t_s
        self.signing.advance_clock(t_s)
        mc = self.mc
        faults = self.faults
        if faults.crashed and not mc.crashed:
            mc.crash()
        glitch = faults.gps_glitch_m
        if glitch != mc.gps_glitch_ned_m[0]:
            mc.gps_glitch_ned_m = np.array((glitch, 0.0, 0.0))
        if faults.battery_low and mc.battery_remaining > 0.06:
            mc.battery_remaining = 0.06
        if faults.max_climb_m_s is not None:
            mc.params.max_speed_up_m_s = faults.max_climb_m_s
        if faults.max_speed_h_m_s is not None:
            mc.params.max_speed_h_m_s = faults.max_speed_h_m_s
        if self.home is None and self.position_ready(t_s):
            self.home = self._origin
            self.home_ned = np.zeros(3)
        ap_failsafe.check_failsafes(self, t_s)
        ap_flight.update(self, t_s)
        if self.behaviour == "mission":
            ap_mission_exec.step_mission(self, t_s)
        self.missions.poll(t_s)

    def send_telemetry(self, t_s: float) -> None:
        """Emit the telemetry messages due at ``t_s``."""
        if self.faults.crashed:
            return
        for msg_id in self.scheduler.due(t_s):
            try:  # per message: one value that cannot be encoded must not silence the vehicle
                msg = build_message(self, msg_id, t_s)
                if msg is not None:
                    self.emit(msg)
            except Exception as exc:
                self.counters["tx_error"] += 1
                self.counters["tx_error:" + type(exc).__name__] += 1
                self.last_error = f"telemetry {msg_id}: {type(exc).__name__}: {exc}"

    def reboot(self, t_s: float) -> None:
        """Simulated reboot: boot state again, new system id from the parameter table."""
        self.sysid = int(self.params[self.personality.sysid_param])
        self.mav.srcSystem = self.sysid
        self._boot(t_s)

    def _home_item(self) -> MissionItem | None:
        if self.home is None:
            return None
        lat, lon, alt = self.home
        return MissionItem(0, mavlink2.MAV_FRAME_GLOBAL, mavlink2.MAV_CMD_NAV_WAYPOINT, 0, 1,
                           0.0, 0.0, 0.0, 0.0, int(round(lat * 1e7)), int(round(lon * 1e7)), alt)

    def __repr__(self) -> str:
        return (f"MockAutopilot(sysid={self.sysid}, personality={self.personality.name!r}, "
                f"mode={self.mode_name!r}, armed={self.armed})")

