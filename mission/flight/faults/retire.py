"""Retiring a faulty sensor during the seek: park its vehicle at the centre, re-form the others.

With ``[faults] faulty_sensor = "retire"`` (the default), whatever the estimator and the seeker,
the seek feeds the faulty-sensor detector's (:mod:`mission.flight.sensor_check`: the robust
estimator's) suspect codes and noise estimates to
:class:`estimator.retire.SensorRetirement` after every iteration (:class:`SensorWatch`). A sensor
named for one of the rule's reasons (by default ``stuck``, or ``noisy`` at 3x the median noise
estimate or more) for ``[faults] retire_after`` consecutive iterations, while at least 4 sensing
vehicles would remain, is *retired* (:meth:`Retirement.retire_sensor`):

* its vehicle stays under setpoints but is parked at the formation centre (offset 0; the plan
  guarantees ``formation.radius_m >= min_separation_m``, so the centre is at least the
  separation from every slot); it moves with the formation and comes home with the others;
* its readings are ignored from then on (the seek estimates from the sensing vehicles only);
* the sensing vehicles are re-formed (:func:`mission.flight.faults.loss.reformed_offsets` with the retired
  vehicle passed as lost: warm-started CVT, a symmetric formation left with an odd number
  switches to CVT) and a separation-keeping transfer is flown in which the retired vehicle
  flies to the centre (the motion's ``transfer_to``, :meth:`mission.flight.motion.GateMotion.transfer_to`, which also keeps every parked vehicle
  in the planning of later transfers);
* the seek starts a fresh robust estimator and a fresh rule for the remaining sensors.

A later loss re-forms the sensing vehicles only (the parked one stays parked); a parked vehicle
that is lost leaves nothing to re-form; a parked vehicle lost by its link and heard again is
kept out and landed, never re-admitted (:meth:`Retirement.keep_out_retired`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mission.core.plan_types import FaultsPlan
from mission.flight.faults.loss import Reformation
from mission.flight.services import Events, Fleet, Motion
from mission.flight.state import MissionState
from mission.safety.gate import SafetyGate

__all__ = ["PARKED_STATUS", "RetiredSensor", "Retirement", "SensorWatch", "restore_retired"]

#: the status of a vehicle whose sensor was retired
PARKED_STATUS = "sensor retired: at the centre"


@dataclass
class RetiredSensor:
    """One retired sensor (``MissionState.retired[sysid]``, the summary's ``retired``).

    Attributes
    ----------
    sysid : int
    reason : str
        The robust estimator's suspect reason when it was retired (``stuck``, ``noisy``...).
    noise_std : float
        The estimator's noise standard deviation estimate of that sensor.
    median_std : float
        Median of the noise standard deviation estimates of all the sensing vehicles then.
    iteration : int
        Seek iteration after which it was retired.
    named_for : int
        Consecutive iterations it had been named.
    retired_s : float
        Mission clock when it was retired.
    """

    sysid: int
    reason: str
    noise_std: float
    median_std: float
    iteration: int
    named_for: int
    retired_s: float

    @property
    def ratio(self) -> float:
        """``noise_std / median_std`` (inf when the median is 0)."""
        return float(self.noise_std / self.median_std) if self.median_std > 0 else float("inf")


class SensorWatch:
    """The retirement rule over the sensing vehicles of one robust estimator.

    Parameters
    ----------
    sysids : list of int
        The sensing vehicles, in the order of the estimator's sensors (sorted sysids).
    after_updates : int
        ``[faults] retire_after``.
    min_sensors : int
        Never retire below this many sensing vehicles.
    min_noise_ratio : float, optional
        ``[faults] retire_min_noise_ratio`` (default: the rule's).
    """

    def __init__(self, sysids: list[int], after_updates: int, min_sensors: int = 4,
                 min_noise_ratio: float | None = None):
        from estimator.retire import SensorRetirement

        self.sysids = sorted(int(s) for s in sysids)
        extra = {} if min_noise_ratio is None else {"min_noise_ratio": float(min_noise_ratio)}
        self.rule = SensorRetirement(len(self.sysids), after_updates=after_updates, min_sensors=min_sensors,
                                     **extra)

    def update(self, estimate, used: list[int], iteration: int, now_s: float) -> RetiredSensor | None:
        """Feed the estimator's state after an update; the sensor to retire now, or None.

        Parameters
        ----------
        estimate
            The seek's faulty-sensor detector (:class:`mission.flight.sensor_check.SensorCheck`), with
            ``suspect_codes()`` and ``noise_std()``.
        used : list of int
            Sysids of the readings of that update, in the estimator's order.
        iteration : int
            The iteration just done.
        now_s : float
            Mission clock.
        """
        from estimator.robust_faults import REASONS

        if list(used) != self.sysids:
            return None  # not an update over every sensing vehicle: the estimator skipped it
        codes = np.asarray(estimate.suspect_codes())
        std = np.asarray(estimate.noise_std(), dtype=float)
        streaks = self.rule.streaks
        idx = int(self.rule.update(codes, noise_std=std))
        if idx < 0:
            return None
        return RetiredSensor(sysid=self.sysids[idx], reason=REASONS[int(codes[idx]) - 1],
                             noise_std=float(std[idx]), median_std=float(np.median(std)),
                             iteration=int(iteration), named_for=int(streaks[idx]) + 1, retired_s=float(now_s))


class Retirement:
    """Faulty sensors retired during the seek: the watch, the parking at the centre, the goals.

    Parameters
    ----------
    state : MissionState
        Who is lost or retired, the slots; a retirement is recorded there.
    fleet : Fleet
        The connected vehicles (a retired one heard again after a link loss is kept out).
    gate : SafetyGate
        Who is under setpoints.
    faults : FaultsPlan
        ``faulty_sensor``, ``retire_after``, ``retire_min_noise_ratio``.
    reformation : Reformation
        The sensing vehicles' new slots (the retired one passed as gone).
    motion : Motion
        ``transfer_to`` (the re-formed formation, the parked vehicle to the centre), ``keep_out``,
        ``parked`` (the vehicles parked at the centre).
    events : Events
        A retirement (or why one was refused) is told.
    """

    def __init__(self, state: MissionState, fleet: Fleet, gate: SafetyGate, faults: FaultsPlan,
                 reformation: Reformation, motion: Motion, events: Events) -> None:
        self.state, self.fleet, self.gate, self.faults = state, fleet, gate, faults
        self.reformation, self.motion, self.events = reformation, motion, events

    def make_watch(self, check, sysids: list[int]) -> SensorWatch | None:
        """A :class:`SensorWatch` for the seek, or None.

        ``check`` is the seek's faulty-sensor detector (:class:`mission.flight.sensor_check.SensorCheck`,
        whatever the estimator and the seeker; None with ``faulty_sensor = "off"``). None without a
        detector, with ``faulty_sensor = "keep"``, or while a vehicle is already parked: the centre is
        the one place known to be clear of every slot, so at most one sensor is retired at a time (a
        second faulty sensor is only left out of the seeker's input while it is excluded, as with ``keep``).
        """
        faults = self.faults
        if check is None or faults.faulty_sensor != "retire" or len(sysids) < 4 or self.motion.parked():
            return None
        return SensorWatch(sysids, faults.retire_after, min_noise_ratio=faults.retire_min_noise_ratio)

    def formation_goals(self, centre_enu, sysids: list[int]) -> dict[int, np.ndarray]:
        """Goals of one iteration: the sensing vehicles at their slots, the parked ones at the centre."""
        centre = np.asarray(centre_enu, dtype=float)
        goals = {s: centre + self.state.slot_offsets[s] for s in sysids}
        goals.update({s: centre.copy() for s in self.motion.parked() if s not in goals})
        return goals

    async def retire_sensor(self, centre_enu, sysids: list[int], info: RetiredSensor) -> list[int]:
        """Retire ``info.sysid``'s sensor: re-form the others about ``centre_enu``, park it at the centre.

        Returns the sensing vehicles left (not lost).
        """
        sysid, state, parked = info.sysid, self.state, self.motion.parked()
        remaining = [s for s in sysids if s != sysid and s not in state.lost]
        why = ("the vehicle was lost" if sysid in state.lost or sysid not in self.gate.sysids
               else f"{len(remaining)} other sensing vehicles left, a formation needs 4" if len(remaining) < 4
               else f"vehicle {parked[0]} is already parked at the centre" if parked else None)
        if why is not None:  # a loss or a parking since the watch was made: the seek's rules apply
            self.events.event(f"vehicle {sysid}'s sensor not retired: {why}", level="warning", sysid=sysid,
                              reason=info.reason)
            return list(sysids)
        new, kind = await self.reformation.survivor_slots(centre_enu, sysids,
                                                          [s for s in sysids if s not in remaining],
                                                          "sensing vehicles")
        state.retire(info, status=PARKED_STATUS)
        ratio = info.ratio
        self.events.event(
            f"vehicle {sysid}'s sensor retired ({info.reason}, std {info.noise_std:.3g} = {ratio:.1f}x the "
            f"median, named for {info.named_for} iterations): parked at the formation centre, readings "
            f"ignored; re-formed for {len(remaining)} ({kind})", level="warning", sysid=sysid,
            reason=info.reason, noise_std=info.noise_std, median_std=info.median_std,
            ratio=round(ratio, 3) if np.isfinite(ratio) else None, iteration=info.iteration,
            named_for=info.named_for, retired_s=info.retired_s)
        new[sysid] = np.zeros(3)
        await self.motion.transfer_to(remaining + [sysid], new, centre_enu,
                                      f"re-forming for {len(remaining)} vehicles ({kind}), sensor of {sysid} retired",
                                      [])
        return [s for s in remaining if s not in state.lost]

    async def keep_out_retired(self, returning: list[int]) -> list[int]:
        """Of the lost vehicles heard again, keep out (and land) those whose sensor was retired.

        Returns the others (to re-admit).
        """
        retired = self.state.retired
        for s in [s for s in returning if s in retired]:
            await self.motion.keep_out(s, self.fleet.vehicles.get(s), "its sensor was retired")
        return [s for s in returning if s not in retired]


def restore_retired(state: MissionState, records: dict) -> None:
    """Put the retired sensors read back from a mission log (:mod:`mission.flight.phases.resume`) into ``state``.

    Written against mappings (``state.retired``, ``state.status``): on a
    :class:`~mission.flight.state.MissionState`, item assignment there is
    :meth:`MissionState.retire <mission.flight.state.MissionState.retire>` and
    :meth:`MissionState.set_status <mission.flight.state.MissionState.set_status>`.
    """
    defaults = {"reason": "", "noise_std": float("nan"), "median_std": float("nan"), "iteration": 0,
                "named_for": 0, "retired_s": float("nan")}
    for sysid, fields in records.items():
        kept = {k: fields[k] for k in defaults if fields.get(k) is not None}
        state.retired[int(sysid)] = RetiredSensor(sysid=int(sysid), **(defaults | kept))
        if int(sysid) not in state.lost:
            state.status[int(sysid)] = PARKED_STATUS
