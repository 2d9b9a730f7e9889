"""mission.flight: the mission state machine, its explicit state and its phases.

Depends on every room below it (safety, telemetry, vehicle, link, core), never on ``cli``.
Inside, imports go one way only (no cycle, lazy imports included)::

    state, modes, targets                    the mission's state and types, flight modes, slots
      <- result, obstacles                   the end result; lost vehicles as obstacles
      <- motion                              retried commands; GateMotion: move-and-wait, timed plans, transfers
      <- faults.loss, return_plan, return_clear   losses and re-forming; the return planned clear
      <- faults.rejoin, faults.retire, faults.watchdog  re-admission; retired sensors; re-engaging
      <- faults.responses                    the seek's fault responses and moves in one object
      <- phases.connect, phases.takeoff, phases.assemble, phases.seek, phases.return_home,
         phases.mission_end                  one module per phase
      <- phases.resume <- coordinator        resuming from a log; the coordinator (builds them all)

The phases are grouped in :mod:`mission.flight.phases`; the fault responses (vehicle loss in
flight and in takeoff, re-admission, retired sensors, the watchdog, the landing guard) in
:mod:`mission.flight.faults`.
"""
