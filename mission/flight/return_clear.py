"""The return phase kept clear of lost vehicles that still fly (hovering in hold).

The return (:class:`mission.flight.phases.return_home.ReturnHome`) flies every vehicle up or down to its own
altitude layer, across at that layer to above its home, then lands it (a vertical descent) or
sends it home (RTL). A vehicle lost by its link while flying hovers where it was
(:func:`mission.flight.obstacles.obstacles`); this module plans the return so that every path, the
descent included, keeps ``min_separation_m + OBSTACLE_MARGIN_M`` from it:

1. **Landing spots** (:func:`mission.flight.return_plan.landing_spots`): a home whose descent column (from the layer down)
   passes near an obstacle is replaced by the nearest spot beside it that is clear, at least
   ``min_separation_m`` from the other vehicles' spots and inside the fence. With RTL the
   autopilot flies its own path over home (it may climb first), so a home with an obstacle
   anywhere above it within the clearance is replaced likewise and that vehicle lands instead.
2. **Paths** (:func:`mission.flight.return_plan.plan_clear_return`), first that keeps the clearance:
   ``layered`` (the usual legs: vertical to the layer, horizontal at the layer, vertical to the
   goal); ``layered+detour`` (the same with horizontal detours at each vehicle's layer:
   distinct layers are ``1.25 * min_separation_m`` apart, and the paths of one batch, those of
   vehicles sharing a layer included, are checked pairwise); ``transfer``
   (:func:`mission.flight.obstacles.plan_clear_transfer`, the obstacles as fixed participants, flown
   synchronously). If none keeps the clearance, the candidate with the largest clearance is
   flown (never blocked) and the caller logs a warning.
3. **Flight** (:meth:`ReturnClear.fly_return`): batch by batch (every vehicle reaches a batch before the
   next starts) or, for a synchronous transfer, by interpolated goals every 0.1 s; a vehicle
   lost during the return (a new obstacle) makes it re-plan from the current setpoints.
"""
from __future__ import annotations

import asyncio
import functools

import numpy as np

from mission.flight.layers import layers_keep_apart, shared_layers
from mission.flight.obstacles import OBSTACLE_MARGIN_M, obstacles
from mission.flight.return_plan import (
    ClearPlan,
    landing_spots,
    path_clearance,
    plan_clear_return,
)
from mission.flight.services import Clock, Events, Fleet, Motion
from mission.flight.state import MissionError, MissionState
from mission.safety.gate import SafetyGate

__all__ = ["ReturnClear"]

#: how many times a return may be re-planned after new losses (each re-plan starts where it is)
_MAX_REPLANS = 4


class ReturnClear:
    """The return (and the assembly's legs) flown clear of lost vehicles still flying.

    Parameters
    ----------
    state : MissionState
        Who is lost, the phase, the layers and homes; the vehicles' statuses (set here).
    fleet : Fleet
        The connected vehicles (lost vehicles still flying are obstacles).
    gate : SafetyGate
        The setpoints (where the paths start), the speed limits.
    clock : Clock
        The mission clock.
    min_separation_m : float
        The plan's separation (plus :data:`~mission.flight.obstacles.OBSTACLE_MARGIN_M` from obstacles).
    arrival_tol_m : float
        The plan's ``[seeking] arrival_tol_m`` (the return waits within ``max(it, 1 m)``).
    max_alt_m : float
        The geofence's ceiling (new shared layers stay 0.5 m below it).
    return_behaviour : {"land", "rtl"}
        The plan's ``return`` (with RTL a landing spot is checked up to the autopilot's own path).
    fence : mission.safety.fence.Geofence or None
        Landing spots and paths stay inside it.
    motion : Motion
        ``fly_timed`` and ``move_and_wait``: the legs flown on the gate.
    events : Events
        Re-plans, and paths that do not keep the clearance, are told.
    """

    def __init__(self, state: MissionState, fleet: Fleet, gate: SafetyGate, clock: Clock, min_separation_m: float,
                 arrival_tol_m: float, max_alt_m: float, return_behaviour: str, fence, motion: Motion,
                 events: Events) -> None:
        self.state, self.fleet, self.gate, self.clock = state, fleet, gate, clock
        self.min_separation_m, self.arrival_tol_m, self.max_alt_m = float(min_separation_m), arrival_tol_m, max_alt_m
        self.rtl, self.fence = return_behaviour == "rtl", fence
        self.motion, self.events = motion, events

    async def _fly(self, sysids, plan: ClearPlan, tol_m: float, names: tuple[str, str, str]) -> bool:
        """Fly ``plan``; False as soon as a vehicle is lost on the way (the caller re-plans)."""
        lost_before = frozenset(self.state.lost)
        wps = plan.waypoints_enu
        first, across, last = names
        # state.status[s] = ... is MissionState.set_status (a plain dict on test doubles)
        if plan.times_s is not None:
            for s in sysids:
                self.state.status[s] = f"{self.state.phase}: {plan.strategy}"
            await self.motion.fly_timed(sysids, plan.times_s, plan.waypoints_enu)  # legs timed so the gate follows
            batches = [(last, wps[-1])]
        else:  # start, layers, detours..., across (at the layers), goal
            labels = [first] + [f"detour {k + 1}" for k in range(len(wps) - 4)] + [across, last]
            batches = [(name, row) for name, row, prev in zip(labels, wps[1:], wps[:-1])
                       if not np.allclose(row, prev)]
        for name, row in batches:
            if frozenset(self.state.lost) != lost_before:
                return False
            for s in sysids:
                if s not in self.state.lost:
                    self.state.status[s] = f"{self.state.phase}: {name}"
            what = f"the vehicles to reach their '{name}' waypoints of the {self.state.phase}"
            await self.motion.move_and_wait({s: row[i] for i, s in enumerate(sysids)}, tol_m, what=what)
        return frozenset(self.state.lost) == lost_before

    async def _plan_and_fly(self, flying, goal, layers, tol_m, what, names, landing=None, moved=()) -> bool:
        """Plan (worker thread), log, fly. ``landing``: where each vehicle then descends to (its
        descent counts in the closest approach reported). True when flown without a new loss."""
        sep = self.min_separation_m
        clearance = sep + OBSTACLE_MARGIN_M
        fence = self.fence
        obs = obstacles(self.state.lost, self.fleet, self.clock.time())
        start = np.array([self.gate.setpoint(s) for s in flying])
        self.gate.set_goals({s: start[i] for i, s in enumerate(flying)})  # hold while planning
        try:
            plan = await asyncio.get_running_loop().run_in_executor(None, functools.partial(
                plan_clear_return, start, goal, layers, obs, sep, clearance, self.gate.max_speed_m_s,
                self.gate.max_vertical_speed_m_s, fence))
        except Exception as exc:  # noqa: BLE001 - never block the move: the plain layered legs
            self.events.event(f"{what}: planning around the lost vehicles failed ({exc}); flying the plain "
                              "layered legs", level="warning")
            plan = plan_clear_return(start, goal, layers, np.zeros((0, 3)), sep, clearance, self.gate.max_speed_m_s)
            obs = np.zeros((0, 3))
        if len(obs):
            worst, spots_ok = plan.clearance_m, True
            if landing is not None:
                worst = min(worst, path_clearance(np.stack([goal, landing]), obs))
                spots_ok = worst >= clearance
            detail = dict(obstacles=obs, strategy=plan.strategy, clearance_m=round(worst, 3), required_m=clearance,
                          moved_landings=sorted(moved))
            if plan.clear and spots_ok:
                if plan.strategy != "layered" or moved:
                    landings = f", vehicles {sorted(moved)} land beside their homes" if moved else ""
                    self.events.event(f"{what} re-planned around {len(obs)} position(s) of lost vehicles still flying: "
                                      f"{plan.strategy}{landings}; closest approach {worst:.2f} m", **detail)
            else:
                self.events.event(f"{what}: no path keeps {clearance:.2f} m from the lost vehicles still flying; "
                                  f"flying the best found ({plan.strategy}, closest approach {worst:.2f} m)",
                                  level="warning", **detail)
        return await self._fly(flying, plan, tol_m, names)

    async def fly_clear(self, sysids: list[int], goals: dict[int, np.ndarray], tol_m: float, what: str = "assembly",
                        names: tuple[str, str, str] = ("layers", "across", "slots")) -> None:
        """Fly ``sysids`` to ``goals`` by their layers (``self.state.layer_alt_m``), clear of lost vehicles.

        The legs of :func:`mission.flight.targets.layered_transfer`, re-planned by
        :func:`plan_clear_return` around the lost vehicles still flying (events as for the
        return); re-planned from where they are when a vehicle is lost on the way (at most a few
        times). Lost vehicles are dropped.

        Raises
        ------
        MissionError
            A vehicle did not reach a goal in time (:meth:`mission.flight.motion.GateMotion.move_and_wait`).
        """
        for _ in range(_MAX_REPLANS + 1):
            flying = [s for s in sysids if s not in self.state.lost and s in self.gate.sysids]
            if not flying:
                return
            goal = np.array([goals[s] for s in flying], dtype=float)
            layers = np.array([self.state.layer_alt_m[s] for s in flying])
            if await self._plan_and_fly(flying, goal, layers, tol_m, what, names):
                return
            self.events.event(f"{what}: a vehicle was lost on the way; re-planning from where the others are",
                              level="warning")

    def _return_layers(self, flying: list[int], homes) -> np.ndarray:
        """The layers of ``flying`` for the way home.

        The takeoff layers while they keep the rule of :func:`mission.flight.layers.shared_layers`
        for the return paths (from the setpoints to above the homes); else new shared layers (the
        formation has moved since the assembly: two vehicles that shared a layer on the way out may
        cross on the way back), recorded in the state and logged; the takeoff layers with a warning
        if none fit.
        """
        layers = np.array([self.state.layer_alt_m[s] for s in flying])
        start = np.array([self.gate.setpoint(s) for s in flying])
        sep = self.min_separation_m
        if layers_keep_apart(start, homes, layers, sep):
            return layers
        try:
            new = shared_layers(start, homes, float(min(self.state.layer_alt_m.values())), self.max_alt_m - 0.5, sep)
        except ValueError as exc:
            self.events.event(f"return: the takeoff layers do not keep the return paths apart and no others fit "
                              f"({exc}); flying the takeoff layers", level="warning")
            return layers
        self.state.update_layers(dict(zip(flying, new)))
        self.events.event(f"return: {len(np.unique(new))} shared layers {new.min():.1f}..{new.max():.1f} m for the "
                          "way home", layers={s: float(a) for s, a in zip(flying, new)})
        return new

    async def fly_return(self, sysids: list[int]) -> set[int]:
        """Bring ``sysids`` above their landing spots at their layers, clear of lost vehicles.

        Plans with :func:`landing_spots` and :func:`plan_clear_return` (in a worker thread), logs
        an info event when the return was re-planned around an obstacle and a warning when no plan
        keeps ``min_separation_m + OBSTACLE_MARGIN_M``, flies it, and re-plans (at most a few
        times, landing spots included) when a vehicle is lost on the way. A vehicle that cannot
        reach a goal in time ends the flight with a warning (the caller lands everyone from where
        they are). Never raises :class:`~mission.flight.state.MissionError`.

        Returns
        -------
        set of int
            Vehicles whose landing spot was moved off their home: they must land there (no RTL).
        """
        tol = max(self.arrival_tol_m, 1.0)
        sep, fence = self.min_separation_m, self.fence
        land_here: set[int] = set()
        for _ in range(_MAX_REPLANS + 1):
            flying = [s for s in sysids if s not in self.state.lost and s in self.gate.sysids]
            if not flying:
                break
            homes = np.array([self.state.home_enu[s] for s in flying])
            layers = self._return_layers(flying, homes)
            flying_lost = obstacles(self.state.lost, self.fleet, self.clock.time())
            spots, moved, _ = landing_spots(homes, layers, flying_lost, sep + OBSTACLE_MARGIN_M, sep, fence=fence,
                                            rtl=self.rtl)
            land_here = {s for i, s in enumerate(flying) if moved[i]}
            try:
                done = await self._plan_and_fly(flying, np.c_[spots[:, :2], layers], layers, tol, "return",
                                                ("layers", "homes", "homes"), landing=spots, moved=land_here)
            except MissionError as exc:
                self.events.event(f"return: {exc}; landing from where they are", level="warning")
                break
            if done:
                break
            self.events.event("return: a vehicle was lost on the way; re-planning from where the others are",
                              level="warning")
        return land_here
