"""mission.vehicle: one vehicle seen from the ground station.

Its telemetry (typed snapshots), its commands (arm, modes, takeoff, land), its local frame and
setpoint streaming. Depends on :mod:`mission.link` and :mod:`mission.core`.
"""
