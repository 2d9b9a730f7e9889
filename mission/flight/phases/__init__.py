"""The mission's phases, one module per phase, in the order a mission flies them.

* :mod:`~mission.flight.phases.connect`: ``Connect`` (links opened, vehicles attached) and
  ``Preflight`` (each vehicle's checks and the mission-wide ones; the safety envelope);
* :mod:`~mission.flight.phases.takeoff`: ``Takeoff`` (slots, layers, arm, climb);
* :mod:`~mission.flight.phases.assemble`: ``Assemble`` (a layered transfer into the formation);
* :mod:`~mission.flight.phases.seek`: ``Seek`` (the seek loop: readings, estimate, next centre),
  with :mod:`~mission.flight.phases.seek_moving` (sampling while moving);
* :mod:`~mission.flight.phases.return_home`: ``ReturnHome`` (back by layers, land or RTL);
* :mod:`~mission.flight.phases.resume`: ``Resume`` (a stopped mission rejoined from its log, then
  seek on or come home), with :mod:`~mission.flight.phases.resume_endings` (how a log ended);
* :mod:`~mission.flight.phases.mission_end`: ``MissionEnd`` (return, secure, stop, summary on
  every path).

Each phase is an object built by :mod:`mission.flight.coordinator` with the narrow services it
uses (:mod:`mission.flight.services`), never the coordinator, and run with ``await phase.run(...)``.
A phase imports no other phase module except the helpers named above (``resume`` uses
``connect.build_envelope``); the fault responses it needs arrive as typed callables.
"""
