"""The embedded mock fleet as a lock-step world (see :mod:`mission.sim.lockstep`).

:class:`EmbeddedWorld` wraps a :class:`sitl_mock.fleet.MockFleet` started without its thread
(``fleet.start(thread=False)``) and the ground station's reading store:

* ``settle()`` reads every MAVLink frame waiting at the vehicles' sockets (commands are handled
  and answered at once, in zero simulated time), then waits until the ground station has
  received every sensor reading the fleet put on zenoh while the ground station listened, and,
  while the ground station's subscription is still being matched, until it is;
* ``next_event_s()`` is the fleet's next physics step (50 Hz of simulated time);
* ``advance_to(t_s)`` runs the physics, the autopilots, the telemetry and the sensors up to
  ``t_s``.

Waiting for zenoh is done on the wall clock, bounded by ``settle_timeout_s``; a wait that runs
out is counted in :attr:`EmbeddedWorld.stalls` (a reading was lost, or the ground station's
zenoh session does not reach the fleet: reproducibility is lost, not the mission) and is not
repeated for the same loss.
"""
from __future__ import annotations

import time

__all__ = ["EmbeddedWorld"]

_POLL_WALL_S = 5e-5


class EmbeddedWorld:
    """A mock fleet and the ground station's reading store, driven in lock-step.

    Parameters
    ----------
    fleet : sitl_mock.fleet.MockFleet
        Started with ``thread=False``, on the lock-step loop's :class:`VirtualClock`.
    store : mission.telemetry.readings.ReadingStore or None
        Where the ground station's readings arrive (its ``counts()`` and ``subscribers``).
    settle_timeout_s : float
        Longest wall-clock wait for zenoh to deliver or match.

    Attributes
    ----------
    stalls : int
        Waits that ran out (a reading or a match that never came).
    waits : int
        Waits for zenoh that were needed.
    """

    def __init__(self, fleet, store=None, settle_timeout_s: float = 2.0) -> None:
        self.fleet = fleet
        self.store = store
        self.settle_timeout_s = float(settle_timeout_s)
        self.stalls = 0
        self.waits = 0
        self._lost = 0
        self._matched = False          # the current subscription was seen matched
        self._match_given_up = False

    def _received(self) -> int:
        counts = self.store.counts()
        return counts["accepted"] + sum(counts["rejected"].values())

    def _pending(self) -> bool:
        """Something the ground station listens for is still on its way."""
        if self.store is None or not self.store.subscribers:
            self._matched = False
            return False
        if not self._matched:
            if not self.fleet.readings_matched():
                return not self._match_given_up
            self._matched, self._match_given_up = True, False
        return self._received() + self._lost < self.fleet.published_readings

    def settle(self) -> None:
        """Handle every frame waiting at the vehicles; wait for zenoh to deliver (bounded).

        A wait that runs out is counted in :attr:`stalls` and not repeated: a lost reading is
        written off, and a subscription that does not match (zenoh not connected to the fleet)
        is not waited for again until it matches.
        """
        self.fleet.service_io()
        if not self._pending():
            return
        self.waits += 1
        give_up = time.monotonic() + self.settle_timeout_s
        while self._pending():
            if time.monotonic() > give_up:
                self.stalls += 1
                if self.fleet.readings_matched():
                    self._lost = self.fleet.published_readings - self._received()
                else:
                    self._match_given_up = True
                return
            time.sleep(_POLL_WALL_S)

    def next_event_s(self) -> float:
        """The fleet's next physics step (simulated Unix seconds)."""
        return self.fleet.next_step_s

    def advance_to(self, t_s: float) -> None:
        """Run the fleet up to ``t_s`` and send what it produced."""
        self.fleet.step_until(t_s)
