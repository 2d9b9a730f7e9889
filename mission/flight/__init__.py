"""mission.flight: the mission state machine, its explicit state and its phases.

Depends on every room below it (safety, telemetry, vehicle, link, core), never on ``cli``.
"""
