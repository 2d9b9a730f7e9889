"""mission.sim: the simulation backend of the ground station.

An embedded mock fleet (:mod:`sitl_mock`) with its plan and ports, and the lock-step driver
that runs the fleet and the coordinator on one simulated clock. Depends on :mod:`mission.core`
and on :mod:`sitl_mock`; used by ``cli`` and the tests.
"""
