"""A higher CPU priority for the real-SITL work unit (tests/conftest.py).

On the 2-core CI machine the real autopilots share the cores with two other pytest workers running
mock missions. A real autopilot that is starved falls behind the ground station's wall clock: a PX4
SIH fleet once ended its mission at the takeoff on CI, a real PX4 once refused OFFBOARD for 30 s.
The lock-step mock missions of the other workers only take longer when starved; the real firmware
misbehaves. So the worker raises its own priority (``nice`` lowered by :data:`BOOST`) while a file
of the real-SITL unit runs: on Linux the nice value is per thread and inherited, so the autopilots,
``swarmseek fly``, the sensors and the mock sessions the test starts run at that priority too.

Lowering a nice value needs ``CAP_SYS_NICE`` (root, as on CI). Without it nothing changes and the
reason is returned, to be shown once in the session's summary.
"""
from __future__ import annotations

import contextlib
import os

__all__ = ["BOOST", "SITL_BOOST", "raised_priority"]

#: nice levels taken off: a thread at nice -5 weighs about 3 times one at nice 0 (Linux CFS)
BOOST = 5
#: the real-SITL unit's, above the wall-clock mock unit's :data:`BOOST`: nice -8 weighs about twice
#: nice -5, so where both units run at once the real firmware is served first (an ArduCopter SITL once
#: went 1.48 s without a frame, and was lost, while a wall-clock file started its processes at -5)
SITL_BOOST = 8


@contextlib.contextmanager
def raised_priority(boost: int = BOOST):
    """Run the block with the calling thread's nice value lowered by ``boost``.

    Yields
    ------
    str or None
        None when the priority was raised; else why not (e.g. no permission).
    """
    before = os.getpriority(os.PRIO_PROCESS, 0)
    try:
        os.setpriority(os.PRIO_PROCESS, 0, before - boost)
    except PermissionError as exc:
        yield f"the real-SITL tests run at normal priority: raising it needs CAP_SYS_NICE ({exc})"
        return
    try:
        yield None
    finally:
        os.setpriority(os.PRIO_PROCESS, 0, before)  # raising a nice value back is always allowed
