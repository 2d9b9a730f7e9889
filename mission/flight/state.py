"""The mission's state: :class:`MissionState` and its types (phases, errors, preflight results, losses).

The lowest module of :mod:`mission.flight`: every other flight module may import it, it imports
none of them.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from estimator.estimate import SourceEstimate

__all__ = ["PHASES", "MissionError", "MissionState", "VehicleLoss", "VehicleReadiness"]

PHASES = ("idle", "connect", "preflight", "takeoff", "assemble", "seek", "finish", "return", "done",
          "aborted")


class MissionError(RuntimeError):
    """The mission cannot go on (a phase failed); the message says which and why."""


@dataclass
class VehicleReadiness:
    """Preflight result of one vehicle: every check and why it failed."""

    sysid: int
    id: str
    connection: str
    checks: dict = field(default_factory=dict)
    problems: list = field(default_factory=list)
    flavour: str | None = None
    #: findings that do not make the vehicle unready (e.g. a failsafe that would only hover)
    warnings: list = field(default_factory=list)
    #: the autopilot's failsafe parameters as the preflight read them (name -> value; empty: not read)
    failsafe_params: dict = field(default_factory=dict)

    @property
    def ready(self) -> bool:
        """All checks passed."""
        return bool(self.checks) and all(self.checks.values()) and not self.problems


@dataclass
class VehicleLoss:
    """One lost vehicle.

    Attributes
    ----------
    sysid : int
    reason : str
        ``link`` (silent) or ``left`` (failsafe / unrequested mode, or disarmed in the air).
    detail : str
        Human-readable cause (mode seen, silence length).
    detected_s : float
        Mission clock at detection.
    since_s : float
        Mission clock of the last frame heard (``link``) or of the first sight of the new
        mode (``left``); ``detected_s - since_s`` is the detection latency seen by the coordinator.
    phase : str
        Coordinator phase at detection.
    came_back_s : float or None
        Mission clock when its frames were heard again (link losses).
    last_setpoint_enu : numpy.ndarray or None
        Its last setpoint when it was lost (a silent vehicle may still fly there).
    readmit_pending : bool
        Heard again and waiting for re-admission at the next seek iteration.
    on_ground : bool
        Found disarmed on the ground (``resume``: a vehicle of the stopped mission already down): kept
        out of the formation but accounted for, so not a loss for the exit status.
    """

    sysid: int
    reason: str
    detail: str
    detected_s: float
    since_s: float
    phase: str = ""
    came_back_s: float | None = None
    last_setpoint_enu: np.ndarray | None = None
    readmit_pending: bool = False
    on_ground: bool = False

    @property
    def latency_s(self) -> float:
        """Seconds from the last sign of the vehicle (or of its mode change) to the detection."""
        return float(self.detected_s - self.since_s)


class _Board(Mapping):
    """Read view of one of the state's dicts; item assignment goes to the owner's method.

    ``board[sysid] = value`` is the mapping form of that method (so code written against a
    plain dict, e.g. a test double, still goes through it); there is no other way to change it.
    """

    def __init__(self, data: dict, on_set):
        self._data = data
        self._on_set = on_set

    def __getitem__(self, key):
        return self._data[key]

    def __iter__(self):
        return iter(self._data)

    def __len__(self) -> int:
        return len(self._data)

    def __setitem__(self, key, value) -> None:
        self._on_set(key, value)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self._data!r})"


def _view(attr: str, doc: str) -> property:
    """Read-only property: a read-only view of the private dict ``attr``."""
    return property(lambda self: MappingProxyType(getattr(self, attr)), doc=doc)


def _frozen(attr: str, doc: str) -> property:
    """Read-only property: a frozen copy of the private set ``attr``."""
    return property(lambda self: frozenset(getattr(self, attr)), doc=doc)


def _value(attr: str, doc: str) -> property:
    """Read-only property: the private attribute ``attr``."""
    return property(lambda self: getattr(self, attr), doc=doc)


class MissionState:
    """The mutable state of one mission; its methods are the only way to change it.

    Parameters
    ----------
    sysids : iterable of int
        The plan's vehicles (any other sysid is refused).
    clock
        Mission clock (``time()``).
    log : mission.telemetry.mission_log.MissionLog, optional
        Every vehicle status change goes there as a ``status_change`` record (``sysid``,
        ``status``, ``previous``, ``reason``, ``phase``).
    formation_kind : str
        The plan's formation type (``cvt`` or ``symmetric``).

    Notes
    -----
    Readers get views (read-only mappings, frozen sets); a vehicle's status changes only in
    :meth:`set_status` (``status[sysid] = text`` is the same call).
    """

    def __init__(self, sysids, *, clock, log=None, formation_kind: str = "cvt"):
        self._clock = clock
        self._log = log
        self._sysids = tuple(int(s) for s in sysids)
        self._phase = "idle"
        self._status: dict[int, str] = {s: "pending" for s in self._sysids}
        self._readiness: dict[int, VehicleReadiness] = {}
        self._airborne: set[int] = set()
        self._released: set[int] = set()
        self._reengaging: set[int] = set()
        self._reengaged: dict[int, int] = {}
        self._lost: dict[int, VehicleLoss] = {}
        self._readmitted: list[dict] = []
        self._retired: dict = {}
        self._slot_offsets: dict[int, np.ndarray] = {}
        self._layer_alt_m: dict[int, float] = {}
        self._home_enu: dict[int, np.ndarray] = {}
        self._formation_kind = formation_kind
        self._iteration = 0
        self._centre_enu: np.ndarray | None = None
        self._gradient: np.ndarray | None = None
        self._estimate: SourceEstimate | None = None
        self._spread_m: float | None = None
        self._distance_flown_m = 0.0
        self._vehicle_distance_m: dict[int, float] = {}
        self._last_pos: dict[int, np.ndarray] = {}
        self._t_start_s = float(clock.time())
        self._t_seek_start_s: float | None = None
        self._t_seek_end_s: float | None = None
        self._max_loop_lag_s = 0.0
        self._interrupts: list[str] = []
        self._land_commanded: set[int] = set()
        self._mission_checks: list[dict] = []
        self._still_armed: list[dict] = []
        self._final_result = None
        self._ending: dict | None = None

    # ------------------------------------------------------------------------ reading
    sysids = _value("_sysids", "The plan's vehicles.")
    phase = _value("_phase", "The current phase (one of :data:`PHASES`).")
    readiness = _view("_readiness", "Preflight result by sysid.")
    airborne = _frozen("_airborne", "Vehicles in the air (taken off, not landed, not lost).")
    released = _frozen("_released", "Vehicles left to their autopilot (landing, RTL, lost): never re-engaged.")
    reengaging = _frozen("_reengaging", "Vehicles being switched back to OFFBOARD/GUIDED right now.")
    reengaged = _view("_reengaged", "How many times each vehicle was re-engaged.")
    lost = _view("_lost", "Lost vehicles (:class:`VehicleLoss`) by sysid.")
    readmitted = _value("_readmitted", "Re-admissions: ``sysid``, ``lost_s``, ``came_back_s``, ``readmitted_s``.")
    slot_offsets = _view("_slot_offsets", "Slot offset from the formation centre (ENU m) by sysid.")
    layer_alt_m = _view("_layer_alt_m", "Altitude layer of each vehicle (takeoff, assembly, return).")
    home_enu = _view("_home_enu", "Home of each vehicle (mission ENU m).")
    formation_kind = _value("_formation_kind", "The formation type in use (``cvt`` or ``symmetric``).")
    iteration = _value("_iteration", "Seek iterations done.")
    centre_enu = _value("_centre_enu", "The formation centre (ENU m), None before the assembly.")
    gradient = _value("_gradient", "The last gradient estimate.")
    estimate = _value("_estimate", "The reported source estimate (:class:`estimator.estimate.SourceEstimate`: "
                                   "the point, its 95 % region, what that region is), None before the seek.")

    @property
    def estimate_enu(self) -> np.ndarray | None:
        """The reported source estimate's point (ENU m), None before the seek."""
        return None if self._estimate is None else self._estimate.enu

    @property
    def estimate_region95_m(self) -> float | None:
        """Radius of the estimate's 95 % region (None: none; :attr:`estimate_basis` says why)."""
        return None if self._estimate is None else self._estimate.region95_m

    @property
    def estimate_basis(self) -> str | None:
        """What the estimate's region is (one sentence), None before the seek."""
        return None if self._estimate is None else self._estimate.basis

    spread_m = _value("_spread_m", "RMS spread of the monitor's last centres.")
    distance_flown_m = _value("_distance_flown_m", "Path length of the formation centre during the seek.")
    vehicle_distance_m = _view("_vehicle_distance_m", "Path length flown by each vehicle (telemetry).")
    t_start_s = _value("_t_start_s", "Mission clock at the start.")
    t_seek_start_s = _value("_t_seek_start_s", "Mission clock when the seek started (None before).")
    t_seek_end_s = _value("_t_seek_end_s", "Mission clock when the seek ended (None before).")
    max_loop_lag_s = _value("_max_loop_lag_s", "Largest event-loop lag seen by the watchdog.")
    land_commanded = _frozen("_land_commanded", "Vehicles the landing guard commanded to LAND (not sent twice).")
    final_result = _value("_final_result", "The mission's result, once the mission ended (every path), else None.")

    @property
    def interrupts(self) -> tuple[str, ...]:
        """What interrupted the mission, in order (signal names, the log failure)."""
        return tuple(self._interrupts)

    @property
    def mission_checks(self) -> tuple[dict, ...]:
        """The mission-wide preflight checks (``name``, ``ok``, ``detail``), in report order (copies)."""
        return tuple(dict(c) for c in self._mission_checks)

    @property
    def still_armed(self) -> tuple[dict, ...]:
        """Vehicles still armed at the end, though down or landing (copies of the entries)."""
        return tuple(dict(e) for e in self._still_armed)

    @property
    def status(self) -> _Board:
        """Status text by sysid (``status[sysid] = text`` is :meth:`set_status`)."""
        return _Board(self._status, self.set_status)

    @property
    def retired(self) -> _Board:
        """Retired sensors by sysid (``retired[sysid] = info`` is :meth:`retire`)."""
        return _Board(self._retired, lambda sysid, info: self.retire(info, sysid=sysid))

    # ------------------------------------------------------------------------ vehicles
    def _known(self, sysid) -> int:
        if sysid not in self._status:
            raise ValueError(f"vehicle {sysid!r} is not in the plan (vehicles {list(self._sysids)})")
        return int(sysid)

    def set_status(self, sysid: int, status: str, reason: str | None = None) -> None:
        """Change a vehicle's status (the only place it changes) and log it as ``status_change``.

        Raises
        ------
        ValueError
            ``sysid`` is not one of the plan's vehicles.
        """
        sysid = self._known(sysid)
        previous = self._status[sysid]
        if status == previous:
            return
        self._status[sysid] = str(status)
        if self._log is not None:
            self._log.write("status_change", sysid=sysid, status=str(status), previous=previous,
                            reason=reason, phase=self._phase)

    def set_phase(self, name: str) -> None:
        """Enter phase ``name`` (ValueError if it is not one of :data:`PHASES`)."""
        if name not in PHASES:
            raise ValueError(f"unknown phase {name!r}; phases: {', '.join(PHASES)}")
        self._phase = name

    def set_readiness(self, readiness: VehicleReadiness, status: str) -> None:
        """Record a vehicle's preflight (or connection) result and the status it gives."""
        self._readiness[self._known(readiness.sysid)] = readiness
        self.set_status(readiness.sysid, status, reason="; ".join(readiness.problems) or None)

    def set_airborne(self, sysid: int, status: str) -> None:
        """A vehicle took off (or was re-engaged in the air)."""
        self._airborne.add(self._known(sysid))
        self.set_status(sysid, status)

    def set_landed(self, sysid: int) -> None:
        """A vehicle is down."""
        self._airborne.discard(self._known(sysid))
        self.set_status(sysid, "landed")

    def release(self, sysid: int, status: str | None = None) -> None:
        """Leave a vehicle to its autopilot (landing, RTL): never re-engaged, no longer watched."""
        self._released.add(self._known(sysid))
        if status is not None:
            self.set_status(sysid, status)

    def unrelease(self, sysid: int) -> None:
        """Take a released vehicle back under the mission's setpoints (re-admission)."""
        self._released.discard(self._known(sysid))

    def begin_reengaging(self, sysid: int) -> None:
        """A mode switch back to OFFBOARD/GUIDED is under way (the watchdog leaves it alone)."""
        self._reengaging.add(self._known(sysid))

    def end_reengaging(self, sysid: int, succeeded: bool = False) -> None:
        """The mode switch is over; ``succeeded`` counts it in :attr:`reengaged`."""
        self._reengaging.discard(sysid)
        if succeeded:
            self._reengaged[sysid] = self._reengaged.get(sysid, 0) + 1

    # ------------------------------------------------------------------------ losses
    def declare_lost(self, loss: VehicleLoss, status: str | None = None) -> None:
        """A vehicle is lost: released, no longer airborne, ``loss`` recorded; ``status``: its new status."""
        sysid = self._known(loss.sysid)
        self._lost[sysid] = loss
        self._released.add(sysid)
        self._airborne.discard(sysid)
        if status is not None:
            self.set_status(sysid, status, reason=loss.reason)

    def came_back(self, sysid: int, now_s: float, readmit: bool) -> None:
        """A vehicle lost by its link is heard again; ``readmit``: wait for re-admission."""
        loss = self._lost[self._known(sysid)]
        loss.came_back_s = float(now_s)
        loss.readmit_pending = bool(readmit)

    def keep_out(self, sysid: int, status: str) -> None:
        """A lost vehicle heard again stays out of the formation (no re-admission pending)."""
        loss = self._lost.get(self._known(sysid))
        if loss is not None:
            loss.readmit_pending = False
        self.set_status(sysid, status)

    def readmit(self, sysid: int, now_s: float) -> None:
        """A lost vehicle is back in the formation (re-engaged under the mission's setpoints)."""
        loss = self._lost.pop(self._known(sysid))
        self._released.discard(sysid)
        self._airborne.add(sysid)
        self._readmitted.append({"sysid": sysid, "lost_s": loss.detected_s, "came_back_s": loss.came_back_s,
                                 "readmitted_s": float(now_s)})
        self.set_status(sysid, "re-admitted")

    def retire(self, info, status: str | None = None, sysid: int | None = None) -> None:
        """Record a retired sensor (``mission.flight.faults.retire.RetiredSensor``); ``status``: the vehicle's new status."""
        key = self._known(info.sysid if sysid is None else sysid)
        self._retired[key] = info
        if status is not None:
            self.set_status(key, status)

    # ------------------------------------------------------------------------ formation
    def set_formation(self, slot_offsets: dict, layer_alt_m: dict | None = None,
                      home_enu: dict | None = None, kind: str | None = None) -> None:
        """Replace the slots (and, when given, the altitude layers, the homes and the formation type)."""
        self._slot_offsets = {self._known(s): np.asarray(o, dtype=float) for s, o in slot_offsets.items()}
        if layer_alt_m is not None:
            self._layer_alt_m = {self._known(s): float(a) for s, a in layer_alt_m.items()}
        if home_enu is not None:
            self._home_enu = {self._known(s): np.asarray(h, dtype=float) for s, h in home_enu.items()}
        if kind is not None:
            self.set_formation_kind(kind)

    def update_layers(self, layer_alt_m: dict) -> None:
        """New altitude layers for some vehicles (the others keep theirs)."""
        self._layer_alt_m.update({self._known(s): float(a) for s, a in layer_alt_m.items()})

    def update_slots(self, offsets: dict) -> None:
        """New slot offsets for some vehicles (the others keep theirs)."""
        self._slot_offsets.update({self._known(s): np.asarray(o, dtype=float) for s, o in offsets.items()})

    def set_formation_kind(self, kind: str) -> None:
        """The formation type in use from now on."""
        if kind not in ("cvt", "symmetric"):
            raise ValueError(f"unknown formation type {kind!r}")
        self._formation_kind = kind

    def set_home(self, sysid: int, home_enu) -> None:
        """A vehicle's home (mission ENU m)."""
        self._home_enu[self._known(sysid)] = np.asarray(home_enu, dtype=float)

    # ------------------------------------------------------------------------ seek
    def move_centre(self, centre_enu) -> None:
        """The formation centre is now ``centre_enu``."""
        self._centre_enu = np.array(centre_enu, dtype=float)

    def resume_seek(self, iteration: int, centre_enu, distance_flown_m: float) -> None:
        """Go on with a stopped seek (:mod:`mission.flight.phases.resume`)."""
        self._iteration = int(iteration)
        self.move_centre(centre_enu)
        self._distance_flown_m = float(distance_flown_m)

    def begin_seek(self) -> None:
        """The seek starts now."""
        self._t_seek_start_s = float(self._clock.time())

    def end_seek(self) -> None:
        """The seek ends now."""
        self._t_seek_end_s = float(self._clock.time())

    def record_iteration(self, k: int, gradient, step_m: float, estimate, spread_m) -> None:
        """Seek iteration ``k`` is done: its gradient, the centre's step, the reported source estimate
        (:class:`estimator.estimate.SourceEstimate` or None) and the monitor's spread."""
        if estimate is not None and not isinstance(estimate, SourceEstimate):
            raise TypeError(f"estimate must be a SourceEstimate or None, got {type(estimate).__name__}")
        self._iteration = int(k)
        self._gradient = gradient
        self._distance_flown_m += float(step_m)
        self._estimate = estimate
        self._spread_m = spread_m

    # ------------------------------------------------------------------------ watchdog
    def add_positions(self, positions: dict) -> None:
        """Accumulate each airborne vehicle's flown distance from telemetry positions (by sysid)."""
        for sysid, p in positions.items():
            if p is None:
                continue
            p = np.asarray(p, dtype=float)
            last = self._last_pos.get(sysid)
            if last is not None and sysid in self._airborne:
                step = float(np.linalg.norm(p - last))
                if step < 50.0:
                    self._vehicle_distance_m[sysid] = self._vehicle_distance_m.get(sysid, 0.0) + step
            self._last_pos[sysid] = p

    def note_loop_lag(self, lag_s: float) -> None:
        """An event-loop lag seen by the watchdog (the largest is kept)."""
        self._max_loop_lag_s = max(self._max_loop_lag_s, float(lag_s))

    # ------------------------------------------------------------------------ the end
    def note_interrupt(self, name: str) -> None:
        """Something interrupted the mission (a signal's name, the log failure)."""
        self._interrupts.append(str(name))

    def clear_mission_checks(self) -> None:
        """The mission-wide checks start again (a new preflight)."""
        self._mission_checks = []

    def add_mission_check(self, name: str, ok: bool, detail: str, first: bool = False) -> None:
        """One mission-wide preflight check's outcome (``first``: reported before the others)."""
        entry = {"name": str(name), "ok": bool(ok), "detail": str(detail)}
        if first:
            self._mission_checks.insert(0, entry)
        else:
            self._mission_checks.append(entry)

    def mark_land_commanded(self, sysid: int) -> None:
        """The landing guard's LAND was accepted by ``sysid`` (not sent twice)."""
        self._land_commanded.add(self._known(sysid))

    def set_still_armed(self, entries: list[dict]) -> None:
        """The vehicles found still armed at the end (landing guard entries)."""
        self._still_armed = [dict(e) for e in entries]

    @property
    def ending(self) -> dict | None:
        """How the mission is ending (``outcome``, ``message``, ``exit_status``) once decided, else None."""
        return None if self._ending is None else dict(self._ending)

    def set_ending(self, outcome: str, message: str, exit_status: int) -> None:
        """The mission is ending with ``outcome`` and the command will exit with ``exit_status``
        (:func:`mission.flight.result.mission_exit_status`; told to watchers before its last snapshot)."""
        self._ending = {"outcome": str(outcome), "message": str(message), "exit_status": int(exit_status)}

    def finish(self, result) -> None:
        """The mission ended with ``result`` (:class:`mission.flight.result.MissionResult`)."""
        self._final_result = result
