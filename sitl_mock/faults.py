"""Per-vehicle fault injection settings for the mock fleet.

One :class:`FaultSet` per vehicle, mutable at run time (from Python or the ``mock`` CLI).
The transports read the link fields, the sensor reads the sensor fields, the vehicle model
reads the vehicle fields. Every field defaults to "no fault".
"""
from __future__ import annotations

from dataclasses import dataclass, fields

__all__ = ["FaultSet", "FAULT_NAMES", "parse_fault"]


@dataclass
class FaultSet:
    """Faults injected into one mock vehicle.

    Attributes
    ----------
    sensor_noise_std : float or None
        Overrides the sensor's Gaussian noise standard deviation (signal units).
    sensor_stuck : bool
        The sensor repeats its last value.
    sensor_bias : float
        Added to every reading.
    sensor_spike_prob, sensor_spike_size : float
        Probability per reading of a spike, and its size (signal units, random sign).
    loss_uplink, loss_downlink : float
        Probability in [0, 1] that a MAVLink frame to / from the vehicle is dropped.
    latency_uplink_s, latency_downlink_s : float
        Delay added to every frame to / from the vehicle.
    link_cut : bool
        No MAVLink frame passes either way.
    crashed : bool
        The vehicle stops transmitting (MAVLink and sensor) and falls to the ground.
    gps_glitch_m : float
        Offset (metres, north) added to the reported position (not the true one).
    battery_low : bool
        Battery drops to a critical level (autopilot failsafe as its personality does).
    max_climb_m_s, max_speed_h_m_s : float or None
        Override the vehicle's climb / horizontal speed limit (a weak motor, a position
        controller that does not follow): 0 means it cannot climb / cannot move horizontally.
        It can still descend and land.
    arm_refused : bool
        Every ARM command is refused (``Arming denied: arming check failed`` / ``Arm: arming check
        failed``) until the fault is cleared, while SYS_STATUS still reports the pre-arm checks
        healthy: a check run only when arming (ArduCopter's mode-dependent ``Need Position
        Estimate``), so the preflight passes and the takeoff's arming retries meet it. A vehicle
        already armed is not affected.
    """

    sensor_noise_std: float | None = None
    sensor_stuck: bool = False
    sensor_bias: float = 0.0
    sensor_spike_prob: float = 0.0
    sensor_spike_size: float = 0.0
    loss_uplink: float = 0.0
    loss_downlink: float = 0.0
    latency_uplink_s: float = 0.0
    latency_downlink_s: float = 0.0
    link_cut: bool = False
    crashed: bool = False
    gps_glitch_m: float = 0.0
    battery_low: bool = False
    max_climb_m_s: float | None = None
    max_speed_h_m_s: float | None = None
    arm_refused: bool = False

    def set(self, name: str, value) -> None:
        """Set one fault by name, converting and checking the value."""
        kinds = {f.name: f.type for f in fields(self)}
        if name not in kinds:
            raise ValueError(f"unknown fault {name!r}; known faults: {', '.join(FAULT_NAMES)}")
        current = getattr(self, name)
        if isinstance(current, bool) or kinds[name] == "bool":
            if isinstance(value, str):
                low = value.strip().lower()
                if low not in ("1", "0", "true", "false", "on", "off", "yes", "no"):
                    raise ValueError(f"fault {name}: expected true/false, got {value!r}")
                value = low in ("1", "true", "on", "yes")
            setattr(self, name, bool(value))
            return
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"fault {name}: expected a number, got {value!r}") from None
        if v != v or v in (float("inf"), float("-inf")):
            raise ValueError(f"fault {name}: must be finite, got {value!r}")
        if name.startswith("loss_") and not 0.0 <= v <= 1.0:
            raise ValueError(f"fault {name}: a probability in [0, 1], got {v}")
        if (name.startswith(("latency_", "max_")) or name == "sensor_noise_std") and v < 0:
            raise ValueError(f"fault {name}: must be >= 0, got {v}")
        if name == "sensor_spike_prob" and not 0.0 <= v <= 1.0:
            raise ValueError(f"fault {name}: a probability in [0, 1], got {v}")
        setattr(self, name, v)


FAULT_NAMES = tuple(f.name for f in fields(FaultSet))


def parse_fault(spec: str) -> tuple[int, str, str]:
    """Parse ``SYSID:NAME=VALUE`` (e.g. ``3:loss_uplink=0.2``) into its parts."""
    try:
        who, rest = spec.split(":", 1)
        name, value = rest.split("=", 1)
        sysid = int(who)
    except ValueError:
        raise ValueError(f"bad fault {spec!r}: expected SYSID:NAME=VALUE, e.g. 3:loss_uplink=0.2") from None
    if sysid < 1 or sysid > 255:
        raise ValueError(f"bad fault {spec!r}: sysid must be 1..255")
    if name not in FAULT_NAMES:
        raise ValueError(f"bad fault {spec!r}: unknown fault {name!r}; known: {', '.join(FAULT_NAMES)}")
    return sysid, name, value
