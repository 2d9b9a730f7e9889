"""Parameter tables of the mock autopilots (the PARAM_* protocol's storage).

Each personality has a real, named parameter table (ArduPilot or PX4 names and units) whose
values the mock reads while it flies: system id, failsafe timeouts and actions, speed limits,
takeoff / RTL altitudes, geofence, battery thresholds. A :class:`ParamTable` stores the values,
checks types and ranges, and encodes them for PARAM_VALUE the way each autopilot does (ArduPilot
casts integers to float, PX4 copies the integer's bytes into the float: "bytewise" encoding).
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

__all__ = ["ParamError", "ParamSpec", "ParamTable", "ardupilot_param_specs", "px4_param_specs"]

_REAL32 = mavlink2.MAV_PARAM_TYPE_REAL32
_INT32 = mavlink2.MAV_PARAM_TYPE_INT32
_INT8 = mavlink2.MAV_PARAM_TYPE_INT8
_INT16 = mavlink2.MAV_PARAM_TYPE_INT16
_INT_TYPES = {mavlink2.MAV_PARAM_TYPE_UINT8, _INT8, mavlink2.MAV_PARAM_TYPE_UINT16, _INT16,
              mavlink2.MAV_PARAM_TYPE_UINT32, _INT32}


class ParamError(ValueError):
    """Unknown parameter name, or a value of the wrong type / out of range."""


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: name (at most 16 characters), default, MAV_PARAM_TYPE and range."""

    name: str
    default: float
    ptype: int = _REAL32
    min_value: float = -math.inf
    max_value: float = math.inf


class ParamTable:
    """Ordered, typed parameter store.

    Parameters
    ----------
    specs : list of ParamSpec
        The table, in PARAM_VALUE index order.
    bytewise : bool
        Encode integer values bytewise in PARAM_VALUE (PX4) instead of casting (ArduPilot).
    overrides : dict, optional
        Initial values replacing the defaults (checked like a PARAM_SET).
    """

    def __init__(self, specs: list[ParamSpec], bytewise: bool, overrides: dict | None = None):
        self._specs = {s.name: s for s in specs}
        self._order = [s.name for s in specs]
        self._index = {name: i for i, name in enumerate(self._order)}
        self._values = {s.name: self._coerce(s, s.default) for s in specs}
        self.bytewise = bytewise
        for name, value in (overrides or {}).items():
            self.set(name, value)

    def __contains__(self, name: str) -> bool:
        return name in self._specs

    def __len__(self) -> int:
        return len(self._order)

    def __getitem__(self, name: str) -> float:
        try:  # the failsafe checks read several parameters every step: one dict lookup
            return self._values[name]
        except KeyError:
            raise ParamError(f"unknown parameter {name!r}") from None

    def names(self) -> list[str]:
        """Parameter names in index order."""
        return list(self._order)

    def as_dict(self) -> dict[str, float]:
        """A copy of every value, by name."""
        return dict(self._values)

    def index_of(self, name: str) -> int:
        """PARAM_VALUE index of ``name``."""
        if name not in self._index:
            raise ParamError(f"unknown parameter {name!r}")
        return self._index[name]

    def name_at(self, index: int) -> str:
        """Name of the parameter at ``index``."""
        if not 0 <= index < len(self._order):
            raise ParamError(f"parameter index {index} out of range 0..{len(self._order) - 1}")
        return self._order[index]

    def ptype(self, name: str) -> int:
        """MAV_PARAM_TYPE of ``name``."""
        return self._spec(name).ptype

    def get(self, name: str) -> float:
        """Current value (an int for integer parameters); ParamError for an unknown name."""
        try:  # _values has exactly the names of _specs (set() only stores known names)
            return self._values[name]
        except KeyError:
            raise ParamError(f"unknown parameter {name!r}") from None

    def set(self, name: str, value) -> float:
        """Set a value after checking type and range; returns the stored value."""
        spec = self._spec(name)
        self._values[name] = self._coerce(spec, value)
        return self._values[name]

    def encode_wire(self, name: str) -> float:
        """The float carried in PARAM_VALUE.param_value for ``name``."""
        spec = self._spec(name)
        value = self._values[name]
        if spec.ptype in _INT_TYPES and self.bytewise:
            return struct.unpack("<f", struct.pack("<i", int(value)))[0]
        return float(value)

    def decode_wire(self, name: str, wire_value: float) -> float:
        """Decode PARAM_SET.param_value for ``name`` (inverse of :meth:`encode_wire`)."""
        spec = self._spec(name)
        if spec.ptype in _INT_TYPES and self.bytewise:
            return struct.unpack("<i", struct.pack("<f", wire_value))[0]
        return wire_value

    def _spec(self, name: str) -> ParamSpec:
        try:
            return self._specs[name]
        except KeyError:
            raise ParamError(f"unknown parameter {name!r}") from None

    @staticmethod
    def _coerce(spec: ParamSpec, value) -> float:
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise ParamError(f"parameter {spec.name}: expected a number, got {value!r}") from None
        if not math.isfinite(v):
            raise ParamError(f"parameter {spec.name}: must be finite, got {value!r}")
        if spec.ptype in _INT_TYPES:
            if v != round(v):
                raise ParamError(f"parameter {spec.name}: expected an integer, got {value!r}")
            v = int(round(v))
        if not spec.min_value <= v <= spec.max_value:
            raise ParamError(
                f"parameter {spec.name}: {v} outside [{spec.min_value}, {spec.max_value}]")
        return v


def ardupilot_param_specs(sysid: int, dyn) -> list[ParamSpec]:
    """ArduCopter parameters the mock honours (units as ArduPilot: cm, cm/s, s, mAh).

    ``dyn`` is the vehicle's :class:`~sitl_mock.dynamics.DynamicsParams`; the speed limits start
    from it so that the table and the dynamics agree. The battery failsafe thresholds default to
    20 % / 10 % of capacity (ArduPilot ships them disabled) so that the low-battery fault acts.
    """
    return [
        ParamSpec("MAV_SYSID", sysid, _INT16, 1, 255),  # SYSID_THISMAV before 4.7
        ParamSpec("MAV_GCS_SYSID", 255, _INT16, 1, 255),  # SYSID_MYGCS before 4.7
        ParamSpec("FS_GCS_ENABLE", 0, _INT8, 0, 7),
        ParamSpec("FS_GCS_TIMEOUT", 5.0, _REAL32, 2.0, 120.0),
        ParamSpec("GUID_TIMEOUT", 3.0, _REAL32, 0.1, 5.0),
        ParamSpec("FENCE_ENABLE", 0, _INT8, 0, 1),
        ParamSpec("FENCE_ACTION", 1, _INT8, 0, 6),
        ParamSpec("FENCE_TYPE", 7, _INT8, 0, 15),  # bits: 1 altitude, 2 circle (honoured), 4 polygon, 8 floor
        ParamSpec("FENCE_ALT_MAX", 100.0, _REAL32, 10.0, 1000.0),
        ParamSpec("FENCE_RADIUS", 300.0, _REAL32, 30.0, 10000.0),
        ParamSpec("WPNAV_SPEED", round(dyn.max_speed_h_m_s * 100.0), _REAL32, 20.0, 2000.0),
        ParamSpec("WPNAV_SPEED_UP", round(dyn.max_speed_up_m_s * 100.0), _REAL32, 10.0, 1000.0),
        ParamSpec("WPNAV_SPEED_DN", round(dyn.max_speed_down_m_s * 100.0), _REAL32, 10.0, 500.0),
        ParamSpec("WPNAV_RADIUS", 200.0, _REAL32, 5.0, 1000.0),
        ParamSpec("LAND_SPEED", round(dyn.land_speed_m_s * 100.0), _INT16, 30.0, 200.0),
        ParamSpec("RTL_ALT", 1500, _INT32, 200, 300000),
        ParamSpec("DISARM_DELAY", 10, _INT8, 0, 127),
        ParamSpec("ARMING_CHECK", 1, _INT32, 0, 2 ** 20),
        ParamSpec("BATT_CAPACITY", 5000, _INT32, 0, 1_000_000),
        ParamSpec("BATT_LOW_MAH", 1000.0, _REAL32, 0.0, 1_000_000.0),
        ParamSpec("BATT_CRT_MAH", 500.0, _REAL32, 0.0, 1_000_000.0),
        ParamSpec("BATT_FS_LOW_ACT", 2, _INT8, 0, 7),
        ParamSpec("BATT_FS_CRT_ACT", 1, _INT8, 0, 7),
        # voltage failsafe as ArduCopter 4.7 (defaults measured on its SITL): below BATT_LOW_VOLT
        # (BATT_CRT_VOLT) for BATT_LOW_TIMER s -> BATT_FS_LOW_ACT (BATT_FS_CRT_ACT); 0 V: off
        ParamSpec("BATT_LOW_VOLT", 10.5, _REAL32, 0.0, 1000.0),
        ParamSpec("BATT_CRT_VOLT", 0.0, _REAL32, 0.0, 1000.0),
        ParamSpec("BATT_LOW_TIMER", 10, _INT8, 0, 120),
        # ArduPilot SITL's simulated pack voltage (its default 12.6 V, fixed without SIM_BATT_CAP_AH);
        # the mock's 0 means its own pack model (4S, 16.8 V full, sagging under load)
        ParamSpec("SIM_BATT_VOLTAGE", 0.0, _REAL32, 0.0, 100.0),
        # mock only (no such ArduPilot parameter): seconds after the GPS fix until the EKF uses
        # it; arming in GUIDED is refused "Need Position Estimate" meanwhile (sitl_mock.ap_prearm)
        ParamSpec("SIM_EKF_GPS_S", 0.0, _REAL32, 0.0, 600.0),
    ]


def px4_param_specs(sysid: int, dyn) -> list[ParamSpec]:
    """PX4 multicopter parameters the mock honours (SI units as PX4).

    ``COM_LOW_BAT_ACT`` defaults to 3 (return at critical, land at emergency) so that the
    low-battery fault acts; the offboard-loss action ``COM_OBL_RC_ACT`` 0 (position mode) switches
    to ``POSCTL`` and, without RC, descends at ``MPC_LAND_SPEED`` and lands, as real PX4 v1.16 SIH
    (docs/faults.md); 1 and 2 (altitude / manual, not measured) fall back to Hold.
    """
    return [
        ParamSpec("MAV_SYS_ID", sysid, _INT32, 1, 255),
        ParamSpec("MAV_COMP_ID", 1, _INT32, 1, 255),
        ParamSpec("COM_OF_LOSS_T", 1.0, _REAL32, 0.0, 60.0),
        ParamSpec("COM_OBL_RC_ACT", 0, _INT32, 0, 7),
        ParamSpec("COM_DL_LOSS_T", 10, _INT32, 5, 300),
        ParamSpec("NAV_DLL_ACT", 0, _INT32, 0, 6),
        ParamSpec("COM_DISARM_PRFLT", 10.0, _REAL32, -1.0, 20.0),
        ParamSpec("COM_DISARM_LAND", 2.0, _REAL32, -1.0, 20.0),
        ParamSpec("MIS_TAKEOFF_ALT", 2.5, _REAL32, 0.0, 1000.0),
        ParamSpec("MPC_XY_VEL_MAX", dyn.max_speed_h_m_s, _REAL32, 0.0, 20.0),
        ParamSpec("MPC_Z_VEL_MAX_UP", dyn.max_speed_up_m_s, _REAL32, 0.5, 8.0),
        ParamSpec("MPC_Z_VEL_MAX_DN", dyn.max_speed_down_m_s, _REAL32, 0.5, 4.0),
        ParamSpec("MPC_LAND_SPEED", dyn.land_speed_m_s, _REAL32, 0.6, 10.0),
        ParamSpec("MPC_TKO_SPEED", dyn.takeoff_speed_m_s, _REAL32, 1.0, 5.0),
        ParamSpec("NAV_ACC_RAD", 2.0, _REAL32, 0.05, 200.0),
        ParamSpec("RTL_RETURN_ALT", 60.0, _REAL32, 0.0, 150.0),
        ParamSpec("GF_ACTION", 1, _INT32, 0, 5),
        ParamSpec("COM_FAIL_ACT_T", 5.0, _REAL32, 0.0, 25.0),
        ParamSpec("GF_MAX_HOR_DIST", 0.0, _REAL32, 0.0, 10000.0),
        ParamSpec("GF_MAX_VER_DIST", 0.0, _REAL32, 0.0, 10000.0),
        ParamSpec("COM_LOW_BAT_ACT", 3, _INT32, 0, 3),
        ParamSpec("BAT_LOW_THR", 0.15, _REAL32, 0.12, 0.5),
        ParamSpec("BAT_CRIT_THR", 0.07, _REAL32, 0.05, 0.5),
        ParamSpec("BAT_EMERGEN_THR", 0.05, _REAL32, 0.03, 0.5),
    ]
