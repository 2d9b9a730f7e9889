"""mission.telemetry: what the ground station hears and tells.

Sensor readings over zenoh, the mission log (JSON lines), the state publication and the live
display. Depends on :mod:`mission.vehicle`, :mod:`mission.link` and :mod:`mission.core`.
"""
