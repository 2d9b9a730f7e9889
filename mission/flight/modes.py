"""Flight modes the coordinator knows: those it flies in, those that mean a vehicle left."""
from __future__ import annotations

__all__ = ["GUIDED_MODES", "LEFT_MODES"]

#: the mode a vehicle is flown in under the mission's setpoints, by autopilot flavour
GUIDED_MODES = {"px4": "OFFBOARD", "ardupilot": "GUIDED"}

#: modes that mean "this vehicle left the mission" when the coordinator did not ask for them
LEFT_MODES = {"px4": frozenset({"AUTO.RTL", "AUTO.LAND"}),
              "ardupilot": frozenset({"RTL", "SMART_RTL", "LAND"})}
