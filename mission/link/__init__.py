"""mission.link: MAVLink transports and endpoints, message signing and .tlog recording.

Depends on :mod:`mission.core` only.
"""
