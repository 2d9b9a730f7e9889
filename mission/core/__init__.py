"""mission.core: what every room of the ground station needs and nothing else.

Errors, clocks, the plan (file format and checks), connection strings, signing keys and zenoh
security settings. Imports nothing from the rest of ``mission``.
"""
