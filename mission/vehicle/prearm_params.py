"""Reading autopilot parameters by name (PARAM_REQUEST_READ / PARAM_VALUE), for preflight checks.

:class:`ParamCache` keeps every PARAM_VALUE a vehicle sends (decoded per flavour: ArduPilot sends
integers cast to float, PX4 copies an integer's bytes into the float, "bytewise");
:func:`read_params` asks for the missing names, again every ``resend_s``, until all are known or
the time is up. Nothing is ever written.
"""
from __future__ import annotations

import struct

from pymavlink.dialects.v20 import ardupilotmega as mavlink

__all__ = ["ParamCache", "read_params"]

_M = mavlink
_INT_TYPES = {_M.MAV_PARAM_TYPE_UINT8, _M.MAV_PARAM_TYPE_INT8, _M.MAV_PARAM_TYPE_UINT16,
              _M.MAV_PARAM_TYPE_INT16, _M.MAV_PARAM_TYPE_UINT32, _M.MAV_PARAM_TYPE_INT32}


class ParamCache:
    """Parameter values heard from one vehicle, by name.

    Parameters
    ----------
    flavour : str
        ``"px4"`` decodes integer parameters bytewise; others cast.
    """

    def __init__(self, flavour: str) -> None:
        self.flavour = flavour
        self.values: dict[str, float] = {}

    def on_param_value(self, msg) -> None:
        """Store one PARAM_VALUE (decoded)."""
        name = msg.param_id if isinstance(msg.param_id, str) else bytes(msg.param_id).decode("ascii", "replace")
        name = name.rstrip("\x00")
        value = float(msg.param_value)
        if msg.param_type in _INT_TYPES:
            if self.flavour == "px4":
                value = float(struct.unpack("<i", struct.pack("<f", value))[0])
            else:
                value = float(round(value))
        self.values[name] = value

    def get(self, name: str) -> float | None:
        """The value of ``name``, or None if not heard."""
        return self.values.get(name)


async def read_params(v, names, timeout_s: float = 5.0, resend_s: float = 1.0) -> dict[str, float]:
    """Read ``names`` from vehicle ``v`` (a ``VehicleLink``); returns those that arrived in time.

    A name the autopilot does not have never arrives (real autopilots send nothing for an
    unknown name): it is simply missing from the result.
    """
    cache: ParamCache = v.params
    wanted = [str(n) for n in names]
    deadline = v.clock.time() + timeout_s
    while True:
        missing = [n for n in wanted if cache.get(n) is None]
        if not missing or v.clock.time() >= deadline:
            break
        for name in missing:
            v.endpoint.send(v.sysid, _M.MAVLink_param_request_read_message(
                v.sysid, v.compid, name.encode("ascii"), -1))
        step_end = min(deadline, v.clock.time() + resend_s)
        while v.clock.time() < step_end and any(cache.get(n) is None for n in missing):
            await v.clock.sleep(0.05)
    return {n: cache.get(n) for n in wanted if cache.get(n) is not None}
