"""mission: the ground station, in rooms that import only downward.

``core`` (errors, clocks, plan) <- ``link`` (MAVLink transports, signing, .tlog) <- ``vehicle``
(one vehicle: telemetry, commands, setpoint streaming) <- ``telemetry`` (readings, mission log,
state publication, display) <- ``safety`` (envelope, fence, transfers, audit) <- ``flight`` (the
mission state machine) <- ``sim`` (embedded mock fleet, lock-step driver) <- ``cli``.
See docs/architecture.md.
"""
