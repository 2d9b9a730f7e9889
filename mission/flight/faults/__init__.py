"""What the mission does when something goes wrong with a vehicle or a sensor.

One module per fault response, each an object handed narrow services
(:mod:`mission.flight.services`), never the coordinator:

* :mod:`~mission.flight.faults.loss`: a vehicle lost in flight (link silent, left by a failsafe,
  disarmed in the air) detected, and the formation re-formed for the survivors;
* :mod:`~mission.flight.faults.takeoff_loss`: a vehicle that fails in the takeoff or the assembly;
* :mod:`~mission.flight.faults.rejoin`: lost vehicles that still fly (kept clear of) and those
  heard again (re-admitted);
* :mod:`~mission.flight.faults.retire`: a faulty sensor retired, its vehicle parked at the centre;
* :mod:`~mission.flight.faults.watchdog`: a vehicle thrown out of OFFBOARD/GUIDED re-engaged,
  refused frames reported, the status records;
* :mod:`~mission.flight.faults.landing_guard`: every mission path ends with no vehicle abandoned.

See ``docs/faults.md``.
"""
