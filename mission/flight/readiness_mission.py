"""Ready to seek, not only ready to fly: the mission-wide preflight checks.

Run at the end of the preflight (:class:`mission.flight.phases.connect.Preflight`), after each vehicle's
own checks; ``swarmseek dry-run`` prints each of them, ``fly`` arms nothing when one fails
(:func:`not_ready_message`); :class:`MissionChecks` runs them:

``zenoh``
    the zenoh session is open (``dry-run`` opens one as ``fly`` does; an endpoint that cannot be
    reached is named here, in plain words).
``readings``
    every vehicle's sensor sent an accepted reading within ``[preflight] readings_timeout_s``
    (per vehicle: the ``reading`` check of its readiness). With ``[preflight] require_readings
    = false`` a missing reading is a warning only.
``start_in_fence``
    the seeking start, and the formation about it (its radius), inside the geofence.
``path_in_fence``
    every vehicle's path to its slot (climb over its home to its altitude layer, across at the
    layer, down to the slot) inside the geofence.

The checks are kept as a list of ``{"name", "ok", "detail"}`` in the mission state
(``MissionState.mission_checks``) and go into the dry run's result (``mission_checks``).
"""
from __future__ import annotations

import numpy as np

from formation.geodesy import geodetic_to_enu
from mission.core.plan_types import Plan
from mission.flight.services import Clock, Events, Fleet
from mission.flight.state import MissionState
from mission.telemetry.readings import ReadingStore

__all__ = ["MissionChecks", "not_ready_message"]


class MissionChecks:
    """The mission-wide preflight checks (module docstring), recorded in the mission state.

    Parameters
    ----------
    state : MissionState
        Where each check (``mission_checks``) and a vehicle failing the readings check go.
    fleet : Fleet
        The connected vehicles (their homes).
    plan : Plan
        The plan: its geofence, formation, seeking start, zenoh and ``[preflight]`` sections.
    clock : Clock
        The mission clock (the wait for readings).
    store : ReadingStore
        The zenoh readings received.
    session : zenoh.Session or None
        The zenoh session (None: none could be opened).
    zenoh_problem : str or None
        Why no zenoh session was opened, in plain words.
    readings_subscribed : bool
        The readings subscription is running.
    events : Events
        Each check is told as an event.
    """

    def __init__(self, state: MissionState, fleet: Fleet, plan: Plan, clock: Clock, store: ReadingStore,
                 session, zenoh_problem: str | None, readings_subscribed: bool, events: Events) -> None:
        self.state, self.fleet, self.plan, self.clock, self.store = state, fleet, plan, clock, store
        self.session, self.zenoh_problem, self.readings_subscribed = session, zenoh_problem, readings_subscribed
        self.events = events

    def _record(self, name: str, ok: bool, detail: str, first: bool = False) -> None:
        self.state.add_mission_check(name, ok, detail, first=first)
        self.events.event(f"preflight: {name} " + ("ok" if ok else "FAIL") + f": {detail}",
                 level="info" if ok else "warning", check=name, ok=bool(ok))

    async def check(self) -> None:
        """Run the mission-wide checks (module docstring); record each in ``self.state.mission_checks``."""
        self.state.clear_mission_checks()
        await self._readings_check()  # first: it gives the zenoh connections time to come up
        self._zenoh_check()  # reported first
        offsets = None
        if len(self.fleet.vehicles) >= 4 and self.plan.geofence.polygon_en_m:  # the slots of path_problems, off the loop
            from mission.flight.targets import solve_formation

            f = self.plan.formation
            offsets = await solve_formation(f.type, len(self.fleet.vehicles), f.radius_m, f.seed)
        self._fence_checks(offsets)

    def _zenoh_check(self) -> None:
        problem = self.zenoh_problem
        if problem or self.session is None:
            self._record("zenoh", False, problem or "no zenoh session: no reading can arrive", first=True)
            return
        z = self.plan.zenoh
        try:
            info = self.session.info
            n_peers = len(list(info.peers_zid())) + len(list(info.routers_zid()))
        except Exception as exc:  # noqa: BLE001 - a closed session, a test double: said, not fatal
            self._record("zenoh", False, f"the zenoh session does not answer: {exc}", first=True)
            return
        if z.connect and n_peers == 0:
            self._record("zenoh", False, f"session open, but nothing reached at {', '.join(z.connect)} (mode {z.mode}): "
                    "is the zenoh router or the sensors' listener running, and is the address right?", first=True)
            return
        self._record("zenoh", True, f"session open, {n_peers} zenoh peer(s)/router(s) connected"
                + (f", connecting to {', '.join(z.connect)}" if z.connect else "")
                + (f", listening on {', '.join(z.listen)}" if z.listen else ""), first=True)

    async def _readings_check(self) -> None:
        """Wait for a reading from every connected vehicle; per-vehicle ``reading`` check."""
        pre = self.plan.preflight
        if not self.readings_subscribed:
            self._record("readings", False, "not subscribed to the readings (no zenoh session)")
            return

        def _missing():
            return [s for s in sorted(self.fleet.vehicles) if self.store.latest(s) is None]

        deadline = self.clock.time() + pre.readings_timeout_s
        while _missing() and self.clock.time() < deadline:
            await self.clock.sleep(0.2)
        missing = _missing()
        counts = self.store.counts()
        rejected = {k: n for k, n in counts["rejected"].items() if n}
        if not missing:
            self._record("readings", True, f"a reading from each of the {len(self.fleet.vehicles)} vehicles")
            return
        detail = (f"no sensor reading accepted from vehicles {missing} within {pre.readings_timeout_s:g} s "
                  "(sensor not running, or not connected to this zenoh network: a refused TLS handshake or "
                  "login is silent in zenoh; check the sensor's output)"
                  + (f"; readings rejected so far: {rejected}" if rejected else ""))
        if not pre.require_readings:
            self._record("readings", True, "WARNING (preflight.require_readings = false): " + detail)
            return
        self._record("readings", False, detail + "; set [preflight] require_readings = false to fly anyway")
        for s in missing:
            r = self.state.readiness.get(s)
            if r is not None:
                r.checks["reading"] = False
                r.problems.append(f"no sensor reading within {pre.readings_timeout_s:g} s")
                self.state.set_readiness(r, "not ready: " + "; ".join(r.problems))

    def _fence_checks(self, offsets=None) -> None:
        from mission.safety.fence import Geofence

        plan = self.plan
        if not plan.geofence.polygon_en_m:
            self._record("start_in_fence", True, "no geofence polygon in the plan: nothing to check")
            return
        try:
            fence = Geofence(np.asarray(plan.geofence.polygon_en_m, dtype=float), plan.geofence.min_alt_m,
                             plan.geofence.max_alt_m)
        except ValueError as exc:
            self._record("start_in_fence", False, f"the geofence cannot be built: {exc}")
            return
        start = plan.seeking.start_point()
        margin = float(fence.distance_inside(start))
        radius = plan.formation.radius_m
        where = f"start ({start[0]:.1f}, {start[1]:.1f}, {start[2]:.1f}) m"
        if margin < 0:
            self._record("start_in_fence", False, f"{where} is outside the geofence ({-margin:.1f} m beyond it)")
        elif margin < radius:
            self._record("start_in_fence", False, f"{where} is {margin:.1f} m inside the geofence: the formation "
                    f"(radius {radius} m) would cross it")
        else:
            self._record("start_in_fence", True, f"{where} and the formation (radius {radius} m) inside the geofence")
        problems = self.path_problems(fence, offsets)
        if problems is None:
            self._record("path_in_fence", False, "not checked: no home position of every vehicle")
        else:
            self._record("path_in_fence", not problems, "; ".join(problems) if problems else
                    "every vehicle's path to its slot (climb, across at its layer, down) inside the geofence")

    def path_problems(self, fence, offsets=None) -> list[str] | None:
        """Vehicles whose path to their slot at the start leaves ``fence`` (None: homes unknown).

        ``offsets``: the formation's slot offsets, solved off the event loop
        (:func:`mission.flight.targets.solve_formation`); solved here when not given or not one per vehicle.
        """
        from mission.flight.layers import shared_layers
        from mission.flight.targets import formation_offsets
        from mission.flight.targets import assign_slots

        plan = self.plan
        sysids = sorted(self.fleet.vehicles)
        homes = []
        for s in sysids:
            home = self.fleet.vehicles[s].state.home
            if home is None:
                return None
            homes.append(geodetic_to_enu(home[0], home[1], home[2], plan.origin))
        if len(sysids) < 4:
            return [f"only {len(sysids)} vehicles connected: a formation needs 4"]
        homes = np.asarray(homes, dtype=float)
        if offsets is None or len(offsets) != len(sysids):
            offsets = formation_offsets(plan.formation.type, len(sysids), plan.formation.radius_m, plan.formation.seed)
        slots_all = plan.seeking.start_point() + offsets
        perm = assign_slots(np.column_stack([homes[:, :2], np.zeros(len(sysids))]),
                            np.column_stack([slots_all[:, :2], np.zeros(len(sysids))]))
        slots = slots_all[np.asarray(perm)]
        base = float(np.max(homes[:, 2])) + plan.takeoff_alt_m
        try:
            layers = shared_layers(homes, slots, base, plan.geofence.max_alt_m - 0.5, plan.min_separation_m)
        except ValueError as exc:
            return [f"no altitude layers for the takeoff: {exc}"]
        out = []
        floor = plan.geofence.min_alt_m + 0.01
        for i, s in enumerate(sysids):
            h, g, z = homes[i], slots[i], float(layers[i])
            legs = [(np.array([h[0], h[1], max(floor, h[2])]), np.array([h[0], h[1], z])),
                    (np.array([h[0], h[1], z]), np.array([g[0], g[1], z])),
                    (np.array([g[0], g[1], z]), g)]
            if not all(bool(fence.segment_inside(a, b)) for a, b in legs):
                out.append(f"vehicle {s}: its path from home ({h[0]:.1f}, {h[1]:.1f}) m at layer {z:.1f} m to its "
                           f"slot ({g[0]:.1f}, {g[1]:.1f}, {g[2]:.1f}) m leaves the geofence")
        return out


def not_ready_message(state: MissionState) -> str | None:
    """Why ``fly`` must not arm (vehicles not ready, a mission check failed), or None."""
    parts = [f"vehicle {r.sysid}: {', '.join(r.problems)}" for r in state.readiness.values() if not r.ready]
    parts += [f"{c['name']}: {c['detail']}" for c in state.mission_checks if not c["ok"]]
    return ("not ready to seek, nothing armed: " + "; ".join(parts)) if parts else None
