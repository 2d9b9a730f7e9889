"""Sampling while moving: the seek loop's move and readings with ``[seeking] sampling = "moving"``.

Stop and go (:mod:`mission.flight.phases.seek`) flies the formation to the new centre, waits until every
vehicle is within ``arrival_tol_m`` of its slot, then estimates from one reading per vehicle.
With ``moving`` sampling (the ``newton``, ``model`` and ``ste`` seekers only), one iteration is:

1. **move**: the ramp's goals become the slots about the new centre (the ramp and the safety
   envelope apply to every setpoint, as in stop and go); the loop does not wait for the formation
   to settle, only until the centroid of the sensing vehicles' telemetry positions has covered
   ``replan_fraction`` of its distance to the centroid of their goals (or is within
   ``arrival_tol_m`` of it), and at least ``1 / rate_hz`` since the last estimate;
2. **readings**: it waits for a reading taken after that instant from every sensing vehicle;
3. **samples**: every reading taken since the last one the seeker had from that vehicle, with
   the position and time where it was taken, goes to the seeker (:meth:`MovingSampling.collect`);
   each vehicle's reading nearest the estimation instant still gives the logged gradient and
   centroid and feeds the robust estimator's watch, as in stop and go.

**Sensor lag.** A sensor with a first-order response ``tau dy/dt = c - y`` carried at a steady
velocity through a locally linear field reads, once its transient has died out,
``y(t) = c(x(t - tau))``: the concentration where it was ``tau`` earlier. Readings taken while
moving are then shifted along the path by ``v tau`` (1.5 m at 3 m/s for ``tau = 0.5 s``), and the
fitted maximum with them. With ``[seeking] sensor_lag_s = tau`` (the sensor's time constant, from
its datasheet) each reading is given to the seeker at the position its vehicle had ``tau`` before
it was taken (interpolated in the vehicle's reading history); the mission log keeps the real
positions. ``docs/seekers.md`` has the numbers.

The next centre is proposed from the commanded centre (the goal of the move in flight), capped at
``gamma_m`` and clamped by the safety envelope as in stop and go, so the commanded centre leads
the formation by at most ``(1 - replan_fraction)`` of a move plus one capped step. Why the model
seeker may use readings taken anywhere, and why the paper's gradient seeker may not, is in
``docs/seekers.md`` ("Sampling while moving").
"""
from __future__ import annotations

import numpy as np

from mission.flight.control import OperatorStop
from mission.flight.motion import paced, update_odometry
from mission.flight.services import Clock, Events
from mission.flight.state import MissionError

__all__ = ["MovingSampling", "lagged_positions", "moving_sampling", "thin_evenly"]


class MovingSampling:
    """The ``moving`` sampling of one seek (module docstring).

    Parameters
    ----------
    clock : Clock
        The mission clock.
    store : ReadingStore
        The readings (:class:`mission.telemetry.readings.ReadingStore`: ``history``, ``latest``).
    events : Events
        A reading history that overflowed is told there.
    replan_fraction : float
        Fraction of a move, in ``(0, 1]``, covered before the next estimate.
    sensor_lag_s : float
        The sensor's response time constant (>= 0): readings go to the seeker where their
        vehicle was this long before they were taken (module docstring).
    since_s : float or None
        Every vehicle's readings taken after this time go to the seeker (``-inf``: every reading the
        store holds, i.e. since takeoff, for the ``ste`` seeker); None: those taken after the seek
        started, and for a vehicle that joins later (re-admitted) after the collect before it joined.

    Raises
    ------
    ValueError
        ``replan_fraction`` outside ``(0, 1]``, or a negative or non-finite ``sensor_lag_s``.
    """

    def __init__(self, clock: Clock, store, events: Events, replan_fraction: float, sensor_lag_s: float = 0.0,
                 since_s: float | None = None):
        f = float(replan_fraction)
        if not 0.0 < f <= 1.0:
            raise ValueError(f"replan_fraction must be in (0, 1], got {replan_fraction!r}")
        lag = float(sensor_lag_s)
        if not (np.isfinite(lag) and lag >= 0.0):
            raise ValueError(f"sensor_lag_s must be a finite number >= 0, got {sensor_lag_s!r}")
        self.clock, self.store, self.events = clock, store, events
        self.fraction = f
        self.sensor_lag_s = lag
        self.positions_enu = np.zeros((0, 3))  # where the seeker takes the collected readings to be
        self.last_used_s: dict[int, float] = {}  # per vehicle: time of the newest reading the seeker had
        self.t_collected_s = clock.time() if since_s is None else float(since_s)  # a new vehicle's start
        self.since_s = None if since_s is None else float(since_s)  # every vehicle's start, when given
        self.first_s: dict[int, float] = {}  # per vehicle: the seeker gets its readings taken after this
        self.given: dict[int, set] = {}  # per vehicle: (time_s, seq) of the readings given, still in the store
        self.overflowed: set[int] = set()  # vehicles whose readings left the store before the seeker had them

    def _since_s(self, sysid: int) -> float:
        return self.first_s.setdefault(sysid, self.t_collected_s if self.since_s is None else self.since_s)

    def _new(self, sysid: int, hist: list) -> list:
        """The readings of ``hist`` (a vehicle's, oldest first) not given yet: taken after the vehicle's
        start and not given before (a reading that arrives late, older than ones given, still counts)."""
        since_s, given = self._since_s(sysid), self.given.setdefault(sysid, set())
        if hist and since_s < hist[0].time_s and sysid in self.last_used_s and \
                self.last_used_s[sysid] < hist[0].time_s:
            self.overflowed.add(sysid)  # readings between the last given and the store's oldest are gone
        new = [r for r in hist if r.time_s > since_s and (r.time_s, r.seq) not in given]
        oldest_s = hist[0].time_s if hist else -np.inf
        given.intersection_update({k for k in given if k[0] >= oldest_s})  # the store forgot the others
        given.update((r.time_s, r.seq) for r in new)
        if new:
            self.last_used_s[sysid] = max(self.last_used_s.get(sysid, -np.inf), new[-1].time_s)
        return new

    @staticmethod
    def _centroid(run, sysids: list[int]) -> np.ndarray | None:
        """Centroid of the vehicles' telemetry positions (None if one has none)."""
        pos = [run.fleet.telemetry_position(s) for s in sysids if s not in run.state.lost]
        if not pos or any(p is None for p in pos):
            return None
        return np.mean(np.asarray(pos, dtype=float), axis=0)

    async def move(self, run, k: int) -> float:
        """Set the goals about ``run.centre`` and wait until the move is covered enough; that instant.

        ``run`` is the seek phase (:class:`mission.flight.phases.seek.Seek`: its ``centre``, ``sysids``,
        ``sk``, ``period_s``, ``last_estimate_t``; its state, fleet, gate, waiter and formation).
        """
        sk, state, gate = run.sk, run.state, run.gate
        before = {s: state.slot_offsets[s].copy() for s in run.sysids}
        run.formation.clear_goals(run.centre, run.sysids)
        await run.formation.fly_rotation(run.centre, run.sysids, before)
        goals = {s: g for s, g in run.formation.formation_goals(run.centre, run.sysids).items()
                 if s not in state.lost and s in gate.sysids}
        gate.set_goals(goals)  # through the safety gate and its envelope, as in stop and go
        members = [s for s in run.sysids if s in goals]
        target = np.mean([goals[s] for s in members], axis=0) if members else np.asarray(run.centre, dtype=float)
        start = self._centroid(run, members)
        left_m = sk.arrival_tol_m
        if start is not None:
            left_m = max((1.0 - self.fraction) * float(np.linalg.norm(target - start)), left_m)

        def _covered():
            update_odometry(state, run.fleet)
            c = self._centroid(run, members)
            return c is not None and float(np.linalg.norm(c - target)) <= left_m

        try:
            await run.waiter.wait_until(_covered, 20.0 + 3.0 * sk.gamma_m / run.plan.max_speed_m_s,
                                        f"iteration {k + 1}: the formation to cover {self.fraction:.0%} of its move",
                                        poll_s=0.05)
        except OperatorStop:
            raise
        except MissionError as exc:
            self.events.event(f"{exc}; estimating anyway", level="warning")
        return await paced(self.clock, run.period_s, run.last_estimate_t)

    async def wait_readings(self, run, k: int, t_s: float) -> None:
        """Wait for a reading taken at or after ``t_s`` from every sensing vehicle (a warning after a while)."""
        def _stale() -> list[int]:
            return [s for s in run.sysids if s not in run.state.lost
                    and ((r := self.store.latest(s)) is None or r.time_s < t_s)]

        try:
            await run.waiter.wait_until(lambda: not _stale(), max(5.0, 10 * run.sk.reading_window_s),
                                        "readings taken while moving", poll_s=0.02)
        except OperatorStop:
            raise
        except MissionError:
            self.events.event(f"iteration {k + 1}: no reading while moving from vehicles {_stale()}", level="warning")

    def collect(self, sysids: list[int]) -> list:
        """Every reading taken since the last one the seeker had from each vehicle, oldest first per vehicle.

        Each reading keeps the position and time where it was taken
        (:class:`mission.telemetry.readings.Reading`); none is given twice, and one that arrives
        late (older than readings already given) is given when it arrives. ``positions_enu``
        becomes where the seeker takes them to be: those positions, or with ``sensor_lag_s`` the
        vehicle's position that long before each reading.
        """
        out, positions, overflowed = [], [], set(self.overflowed)
        for s in sysids:
            hist = self.store.history(s)
            new = self._new(s, hist)
            out.extend(new)
            positions.extend(lagged_positions(hist, new, self.sensor_lag_s))
        self.t_collected_s = self.clock.time()
        self.positions_enu = np.asarray(positions, dtype=float).reshape(-1, 3)
        if self.overflowed - overflowed:
            self.events.event(f"vehicles {sorted(self.overflowed - overflowed)}: readings left the reading "
                              "store's history before the seeker had them (estimates further apart than the "
                              "history holds)", level="warning")
        return out


def lagged_positions(history: list, readings: list, lag_s: float) -> list[np.ndarray]:
    """Where one vehicle was ``lag_s`` before each of ``readings`` (linear in its reading ``history``,
    oldest first; the first position before the history starts); the readings' own positions for
    ``lag_s = 0``."""
    if lag_s <= 0.0 or not readings:
        return [r.position_enu_m for r in readings]
    t_s = np.array([r.time_s for r in history])
    pos = np.array([r.position_enu_m for r in history], dtype=float)
    back_s = np.array([r.time_s for r in readings]) - lag_s
    return list(np.stack([np.interp(back_s, t_s, pos[:, i]) for i in range(3)], axis=-1))


def thin_evenly(readings: list, positions, per_vehicle: int) -> tuple[list, np.ndarray]:
    """At most ``per_vehicle`` of each vehicle's ``readings`` (with their ``positions`` (M, 3)), evenly
    spread over its readings in time order (the first kept, and the last when ``per_vehicle`` > 1);
    every reading when it has that many or fewer.

    For the ``ste`` seeker (:data:`mission.flight.phases.seek.STE_READINGS_PER_VEHICLE`): its CPU grows with
    the readings of an update, and its tempering is calibrated for one reading per vehicle per
    update; with more, its posterior is overconfident (docs/seekers.md, "ste in missions").
    """
    pos = np.asarray(positions, dtype=float).reshape(-1, 3)
    by_vehicle: dict[int, list[int]] = {}
    for i, r in enumerate(readings):
        by_vehicle.setdefault(r.sysid, []).append(i)
    keep: list[int] = []
    for idx in by_vehicle.values():
        if len(idx) <= per_vehicle:
            keep.extend(idx)
        else:
            keep.extend(idx[j] for j in np.unique(np.round(np.linspace(0, len(idx) - 1, per_vehicle)).astype(int)))
    keep.sort()
    return [readings[i] for i in keep], pos[keep]


def moving_sampling(clock: Clock, store, events: Events, sk) -> MovingSampling | None:
    """A :class:`MovingSampling` for the plan's ``[seeking] sampling = "moving"``, else None.

    Only :data:`estimator.seekers.MOVING_SEEKERS` sample while moving (a plan cannot ask
    otherwise; a plan built in code that does gets a warning and stop and go).
    """
    from estimator.seekers import MOVING_SEEKERS

    if sk.sampling != "moving":
        return None
    if sk.seeker not in MOVING_SEEKERS:
        events.event(f'sampling = "moving" needs the newton, model or ste seeker; the {sk.seeker} seeker samples '
                 "stop and go", level="warning")
        return None
    since_s = -np.inf if sk.seeker == "ste" else None  # ste: every reading since takeoff, once
    return MovingSampling(clock, store, events, sk.replan_fraction, sk.sensor_lag_s, since_s=since_s)
