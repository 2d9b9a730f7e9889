"""Sampling while moving: the seek loop's move and readings with ``[seeking] sampling = "moving"``.

Stop and go (:mod:`mission.flight.seek`) flies the formation to the new centre, waits until every
vehicle is within ``arrival_tol_m`` of its slot, then estimates from one reading per vehicle.
With ``moving`` sampling (the ``newton`` and ``model`` seekers only), one iteration is:

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
from mission.flight.motion import paced
from mission.flight.rejoin import clear_goals, fly_rotation
from mission.flight.retire import formation_goals
from mission.flight.state import MissionError

__all__ = ["MovingSampling", "lagged_positions", "moving_sampling"]


class MovingSampling:
    """The ``moving`` sampling of one seek (module docstring).

    Parameters
    ----------
    co : mission.flight.coordinator.Coordinator
        The mission (ramp, store, clock, telemetry, events).
    replan_fraction : float
        Fraction of a move, in ``(0, 1]``, covered before the next estimate.
    sensor_lag_s : float
        The sensor's response time constant (>= 0): readings go to the seeker where their
        vehicle was this long before they were taken (module docstring).

    Raises
    ------
    ValueError
        ``replan_fraction`` outside ``(0, 1]``, or a negative or non-finite ``sensor_lag_s``.
    """

    def __init__(self, co, replan_fraction: float, sensor_lag_s: float = 0.0):
        f = float(replan_fraction)
        if not 0.0 < f <= 1.0:
            raise ValueError(f"replan_fraction must be in (0, 1], got {replan_fraction!r}")
        lag = float(sensor_lag_s)
        if not (np.isfinite(lag) and lag >= 0.0):
            raise ValueError(f"sensor_lag_s must be a finite number >= 0, got {sensor_lag_s!r}")
        self.co = co
        self.fraction = f
        self.sensor_lag_s = lag
        self.positions_enu = np.zeros((0, 3))  # where the seeker takes the collected readings to be
        self.last_used_s: dict[int, float] = {}  # per vehicle: time of the newest reading the seeker had
        self.t_collected_s = co.clock.time()     # readings of a vehicle new to the seeker start here

    def _since_s(self, sysid: int) -> float:
        return self.last_used_s.get(sysid, self.t_collected_s)

    def _centroid(self, sysids: list[int]) -> np.ndarray | None:
        """Centroid of the vehicles' telemetry positions (None if one has none)."""
        pos = [self.co.telemetry_position(s) for s in sysids if s not in self.co.state.lost]
        if not pos or any(p is None for p in pos):
            return None
        return np.mean(np.asarray(pos, dtype=float), axis=0)

    async def move(self, run, k: int) -> float:
        """Set the goals about ``run.centre`` and wait until the move is covered enough; that instant.

        ``run`` is the seek loop (:class:`mission.flight.seek._Seek`: ``centre``, ``sysids``,
        ``sk``, ``period_s``, ``last_estimate_t``).
        """
        co, sk = self.co, run.sk
        before = {s: co.state.slot_offsets[s].copy() for s in run.sysids}
        clear_goals(co, run.centre, run.sysids)
        await fly_rotation(co, run.centre, run.sysids, before)
        goals = {s: g for s, g in formation_goals(co, run.centre, run.sysids).items()
                 if s not in co.state.lost and s in co.ramp.sysids}
        co.ramp.set_goals(goals)  # through the ramp and the safety envelope, as in stop and go
        members = [s for s in run.sysids if s in goals]
        target = np.mean([goals[s] for s in members], axis=0) if members else np.asarray(run.centre, dtype=float)
        start = self._centroid(members)
        left_m = sk.arrival_tol_m
        if start is not None:
            left_m = max((1.0 - self.fraction) * float(np.linalg.norm(target - start)), left_m)

        def _covered():
            co.update_odometry()
            c = self._centroid(members)
            return c is not None and float(np.linalg.norm(c - target)) <= left_m

        try:
            await co.wait_until(_covered, 20.0 + 3.0 * sk.gamma_m / co.plan.max_speed_m_s,
                                f"iteration {k + 1}: the formation to cover {self.fraction:.0%} of its move",
                                poll_s=0.05)
        except OperatorStop:
            raise
        except MissionError as exc:
            co.event(f"{exc}; estimating anyway", level="warning")
        return await paced(co.clock, run.period_s, run.last_estimate_t)

    async def wait_readings(self, run, k: int, t_s: float) -> None:
        """Wait for a reading taken at or after ``t_s`` from every sensing vehicle (a warning after a while)."""
        co = self.co

        def _stale() -> list[int]:
            return [s for s in run.sysids if s not in co.state.lost
                    and ((r := co.store.latest(s)) is None or r.time_s < t_s)]

        try:
            await co.wait_until(lambda: not _stale(), max(5.0, 10 * run.sk.reading_window_s),
                                "readings taken while moving", poll_s=0.02)
        except OperatorStop:
            raise
        except MissionError:
            co.event(f"iteration {k + 1}: no reading while moving from vehicles {_stale()}", level="warning")

    def collect(self, sysids: list[int]) -> list:
        """Every reading taken since the last one the seeker had from each vehicle, oldest first per vehicle.

        Each reading keeps the position and time where it was taken
        (:class:`mission.telemetry.readings.Reading`); none is given twice. ``positions_enu``
        becomes where the seeker takes them to be: those positions, or with ``sensor_lag_s`` the
        vehicle's position that long before each reading.
        """
        out, positions = [], []
        for s in sysids:
            since_s = self._since_s(s)
            hist = self.co.store.history(s)
            new = [r for r in hist if r.time_s > since_s]
            if new:
                self.last_used_s[s] = new[-1].time_s
            out.extend(new)
            positions.extend(lagged_positions(hist, new, self.sensor_lag_s))
        self.t_collected_s = self.co.clock.time()
        self.positions_enu = np.asarray(positions, dtype=float).reshape(-1, 3)
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


def moving_sampling(co, sk) -> MovingSampling | None:
    """A :class:`MovingSampling` for the plan's ``[seeking] sampling = "moving"``, else None.

    Only :data:`estimator.seekers.MOVING_SEEKERS` sample while moving (a plan cannot ask
    otherwise; a plan built in code that does gets a warning and stop and go).
    """
    from estimator.seekers import MOVING_SEEKERS

    if getattr(sk, "sampling", "stop_and_go") != "moving":
        return None
    if sk.seeker not in MOVING_SEEKERS:
        co.event(f'sampling = "moving" needs the newton or model seeker; the {sk.seeker} seeker samples '
                 "stop and go", level="warning")
        return None
    return MovingSampling(co, sk.replan_fraction, getattr(sk, "sensor_lag_s", 0.0))
