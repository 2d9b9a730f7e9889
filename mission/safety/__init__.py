"""mission.safety: the safety envelope, its geometry, separation-keeping transfers and the audit.

Depends on :mod:`mission.telemetry` (the audit reads mission logs) and below.
"""
