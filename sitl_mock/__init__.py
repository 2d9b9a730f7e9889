"""sitl_mock: the simulated world (fields, vehicles, sensors) and protocol-faithful mock autopilots.

The main entry points are re-exported lazily (importing ``sitl_mock.fields_gaussian`` stays cheap):
``MockFleet``, ``MockVehicle``, ``MockAutopilot``, ``FaultSet``, ``SimClock``,
``DynamicsParams``.
"""
from __future__ import annotations

import importlib

__all__ = ["MockFleet", "MockVehicle", "MockAutopilot", "FaultSet", "SimClock",
           "DynamicsParams", "PortInUseError"]

_LAZY = {
    "MockFleet": "sitl_mock.fleet",
    "MockVehicle": "sitl_mock.vehicle",
    "MockAutopilot": "sitl_mock.autopilot",
    "FaultSet": "sitl_mock.faults",
    "SimClock": "sitl_mock.clock",
    "DynamicsParams": "sitl_mock.dynamics_params",
    "PortInUseError": "sitl_mock.transport",
}


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'sitl_mock' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
