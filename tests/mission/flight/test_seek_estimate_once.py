"""The seek asks its seeker for one posterior summary per iteration: the estimate it reports is the
one the fence's reach check (``Seek._in_reach``) judges, not a second ``source_estimate`` call
(for ``ste`` each call summarises the whole particle posterior)."""
from __future__ import annotations

import asyncio
from types import SimpleNamespace

import numpy as np

from estimator.estimate import SourceEstimate
from mission.flight.phases.seek import Seek
from mission.flight.state import MissionState


class _Clock:
    def time(self) -> float:
        return 100.0

    async def sleep(self, dt_s: float) -> None:
        await asyncio.sleep(0)


class _CountingSeeker:
    """A seeker whose own estimate (far beyond the formation's reach) counts the calls asking for it."""

    def __init__(self) -> None:
        self.calls = 0

    def source_estimate(self, k: int = 0) -> SourceEstimate:
        self.calls += 1
        return SourceEstimate(np.array([40.0 + self.calls, 0.0, 10.0]), 2.0, "posterior 95 % region")


class _Events:
    def __init__(self) -> None:
        self.messages: list[str] = []

    def event(self, message: str, level: str = "info", **fields) -> None:
        self.messages.append(message)


def _seek_at_the_fence(inner: _CountingSeeker) -> Seek:
    """A seek whose every requested centre the envelope holds at the fence (only what ``_step`` reads)."""
    run = object.__new__(Seek)
    held = np.array([0.0, 0.0, 10.0])
    run.sk = SimpleNamespace(eps=0.5, gamma_m=2.0, convergence_window=5, convergence_tol_m=0.5)
    run.state = MissionState([1, 2, 3, 4], clock=_Clock())
    run.events, run.log, run.check, run.samples = _Events(), None, None, None
    run.sysids, run.centre, run.at_fence, run.beyond_reach = [1, 2, 3, 4], held.copy(), 0, 0
    run.seeker = SimpleNamespace(seeker=inner, converges_itself=True, arrival=False, formation_radius_m=None)
    run.envelope = SimpleNamespace(
        clamp_centre=lambda centre, new: SimpleNamespace(at_boundary=True, centre_enu=held, message="held"),
        formation_radius_m=4.0, fence=SimpleNamespace(contains=lambda p: True))
    run.arrival = SimpleNamespace(signal=lambda values: None)
    run.monitor = SimpleNamespace(update=lambda centre, signal, estimate=None, centroid=None: False,
                                  spread_m=None, declared_by=None)

    async def _propose(k, positions, values, times_s=None, sysids=None):
        return held + np.array([2.0, 0.0, 0.0])

    run._propose = _propose
    return run


def test_the_seeker_is_asked_for_its_estimate_once_per_iteration():
    inner = _CountingSeeker()
    run = _seek_at_the_fence(inner)
    aligned = {s: SimpleNamespace(sysid=s, value=1.0, time_s=100.0, position_enu_m=np.array([s, 0.0, 10.0]))
               for s in run.sysids}
    for k in range(3):
        ended = asyncio.run(run._step(k, 100.0, aligned, run.sysids, np.zeros(3), np.zeros(3), False))
        assert ended is None
        assert inner.calls == k + 1, f"iteration {k + 1}: source_estimate asked {inner.calls} times in all"
        # the reported estimate is the one call's, and it is the one judged out of reach
        assert np.allclose(run.state.estimate_enu, [41.0 + k, 0.0, 10.0])
        assert run.beyond_reach == k + 1
