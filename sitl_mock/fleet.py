"""A fleet of mock vehicles in one process: autopilots, dynamics, sensors, transports.

One background thread runs the whole fleet: physics at 50 Hz of simulated time, autopilot
logic and telemetry, sensor sampling, and all socket I/O through one ``selectors`` selector
(non-blocking sockets; the thread sleeps in ``select`` between physics steps, so an asyncio
ground station in the same process keeps the GIL most of the time).

Vehicle i (0-based) has system id i + 1, binds UDP ``127.0.0.1:udp_bind_base_port + i``, sends
its stream to ``127.0.0.1:udp_base_port + i`` and serves TCP on ``tcp_base_port + 10 i``. The
two UDP ranges must not overlap: by default the bind base is PX4's 14580 while the fleet fits
below it (up to 40 vehicles from 14540), else right after the send range
(:func:`default_udp_bind_base_port`).
"""
from __future__ import annotations

import dataclasses
import math
import selectors
import threading
import time
import traceback

import numpy as np

from formation.geodesy import enu_to_geodetic
from sitl_mock.autopilot import MockAutopilot
from sitl_mock.clock import SimClock
from sitl_mock.ap_wind import WindEstimateModel, world_wind_ned_m_s
from sitl_mock.dynamics_params import DynamicsParams
from sitl_mock.dynamics import Multicopter
from sitl_mock.faults import FaultSet
from sitl_mock.ports import check_port_base, check_udp_ranges, default_udp_bind_base_port
from sitl_mock.transport import VehicleLinks
from sitl_mock.vehicle import MockVehicle, per_vehicle, per_vehicle_params

__all__ = ["MockFleet", "PHYSICS_RATE_HZ", "DEFAULT_ORIGIN"]

PHYSICS_RATE_HZ = 50.0
DEFAULT_ORIGIN = (45.1900, 5.7200, 230.0)
_MAX_CATCHUP_STEPS = 25
_LOCKSTEP_POLL_S = 0.002
_MAX_ERRORS_KEPT = 20
_ZENOH_SECURITY_KEYS = frozenset({"tls", "enable_mtls", "username", "password", "dictionary_file"})


class MockFleet:
    """N mock autopilots with dynamics, sensors and MAVLink transports, run in one thread.

    Parameters
    ----------
    n : int
        Number of vehicles (system ids 1..n).
    personality : str or list of str
        ``"px4"`` or ``"ardupilot"``, for all vehicles or one per vehicle.
    field : sitl_mock.fields_gaussian.Field, optional
        Signal field the sensors sample (no sensors without a field).
    origin : tuple
        Fleet origin ``(lat_deg, lon_deg, alt_m)`` (the mission frame's origin).
    home_offsets_enu : array_like (n, 3), optional
        Homes in ENU metres from the origin (default: a 5 m grid).
    speedup : float
        Simulated seconds per wall second (ignored when ``clock`` is given).
    clock : clock object, optional
        A :class:`~sitl_mock.clock.SimClock` or, stepped with ``start(thread=False)``, a lock-step
        ``mission.sim.lockstep.VirtualClock``.
    seed : int
        Seeds dynamics, sensor noise and packet loss.
    udp_base_port, udp_bind_base_port, tcp_base_port : int
        Port bases (0 disables UDP / TCP); ``udp_bind_base_port`` None:
        :func:`default_udp_bind_base_port`. The two UDP ranges must not overlap.
    fleet_name : str
        Name in the zenoh keys and sensor payloads.
    sensor_noise_std : float or list of float
        Sensor noise per vehicle.
    sensor_rate_hz : float
        Readings per simulated second per vehicle.
    zenoh_listen, zenoh_connect : list of str, optional
        Endpoints of the fleet's zenoh session (no session, hence no publishing, without them;
        they need a ``field``).
    zenoh : bool
        False disables zenoh even if endpoints are given.
    zenoh_security : dict, optional
        TLS / login keywords of :func:`wire.zenoh_config.zenoh_config` for the fleet's session:
        ``tls`` (mapping of ``transport/link/tls`` file keys), ``enable_mtls``, ``username``,
        ``password``, ``dictionary_file`` (as built by
        :func:`wire.zenoh_flags.security_kwargs`).
    dynamics : DynamicsParams
        Dynamics of every vehicle (copied per vehicle: parameters can then differ).
    params : dict or list of dict, optional
        Autopilot parameter overrides (for all vehicles or per vehicle).
    signing_key : bytes, optional
        32-byte MAVLink 2 signing key of every vehicle (signing on from boot: unsigned, badly
        signed and replayed commands are rejected and counted, everything sent is signed).
        Without it a vehicle gets a key only from SETUP_SIGNING.
    """

    def __init__(self, n: int = 8, personality="px4", field=None, origin=DEFAULT_ORIGIN,
                 home_offsets_enu=None, speedup: float = 1.0, clock=None, seed: int = 0,
                 udp_base_port: int = 14540, udp_bind_base_port: int | None = None,
                 tcp_base_port: int = 5760, fleet_name: str = "swarmseek",
                 sensor_noise_std=0.0, sensor_rate_hz: float = 10.0, zenoh_listen=None,
                 zenoh_connect=None, zenoh: bool = True, dynamics: DynamicsParams | None = None,
                 params=None, signing_key: bytes | None = None, zenoh_security: dict | None = None):
        n = int(n)
        if not 1 <= n <= 255:
            raise ValueError(f"n must be 1..255 vehicles, got {n}")
        personalities, offsets, noise = per_vehicle(n, personality, home_offsets_enu, sensor_noise_std)
        if not (math.isfinite(sensor_rate_hz) and sensor_rate_hz > 0):
            raise ValueError(f"sensor_rate_hz must be > 0, got {sensor_rate_hz!r}")
        overrides = per_vehicle_params(n, params)
        if udp_bind_base_port is None:
            udp_bind_base_port = default_udp_bind_base_port(n, udp_base_port)
        check_port_base("udp_base_port", udp_base_port, n, 1)
        check_udp_ranges(udp_base_port, udp_bind_base_port, n)
        check_port_base("udp_bind_base_port", udp_bind_base_port, n, 1)
        check_port_base("tcp_base_port", tcp_base_port, n, 10)
        self.clock = clock if clock is not None else SimClock(speedup)
        self.origin = tuple(float(v) for v in origin)
        self.fleet_name = fleet_name
        self.field = field
        self.sensor_rate_hz = float(sensor_rate_hz)
        self._zenoh_listen = zenoh_listen
        self._zenoh_connect = zenoh_connect
        self._zenoh_enabled = bool(zenoh) and bool(zenoh_listen or zenoh_connect)
        self._zenoh_security = dict(zenoh_security or {})
        unknown = set(self._zenoh_security) - _ZENOH_SECURITY_KEYS
        if unknown:
            raise ValueError(f"unknown zenoh_security keys {sorted(unknown)} "
                             f"(allowed: {', '.join(sorted(_ZENOH_SECURITY_KEYS))})")
        if self._zenoh_enabled and field is None:
            raise ValueError("zenoh endpoints given but no field: the sensors would have nothing "
                             "to publish (pass field=..., or zenoh=False)")
        self._session = None
        self._publisher = None
        self._selector = selectors.DefaultSelector()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._started = threading.Event()
        self._tick_cond = threading.Condition()
        self._sim_time_s = -math.inf
        self._opened = False
        self._t_start_s = self.clock.time()
        self._k = 0  # index of the next physics step: its time is _t_start_s + _k * dt (no drift)
        self.errors: list[str] = []
        self.stats = {"ticks": 0, "lag_s": 0.0, "busy_wall_s": 0.0, "wall_s": 0.0, "dropped_steps": 0}
        dyn_base = dynamics if dynamics is not None else DynamicsParams()
        seeds = np.random.SeedSequence(seed).spawn(n)
        t0 = self.clock.time()
        self.vehicles: list[MockVehicle] = []
        for i in range(n):
            # the 4th stream (the wind estimate's error) leaves the first three as they were
            rng_dyn, rng_sensor, rng_link, rng_wind = (np.random.default_rng(s) for s in seeds[i].spawn(4))
            faults = FaultSet()
            mc = Multicopter(dataclasses.replace(dyn_base), rng_dyn)
            lat, lon, alt = enu_to_geodetic(offsets[i], self.origin)
            home = (float(lat), float(lon), float(alt))
            ap = MockAutopilot(i + 1, personalities[i], mc, home, t0, faults, overrides[i],
                               uid=(seed & 0xFFFF) << 32 | 0x5357_0000 | (i + 1),
                               signing_key=signing_key,
                               wind=WindEstimateModel(world_wind_ned_m_s(field, dyn_base.wind_ned_m_s), rng_wind))
            links = VehicleLinks(ap, self.clock, self._selector, rng_link,
                                 udp_bind_base_port + i if udp_bind_base_port and udp_base_port else 0,
                                 udp_base_port + i if udp_base_port and udp_bind_base_port else 0,
                                 tcp_base_port + 10 * i if tcp_base_port else 0)
            sensor = None
            if field is not None:
                from sitl_mock.sensor import SignalSensor
                sensor = SignalSensor(field, noise[i], rng_sensor, faults, fleet_name, i + 1)
            self.vehicles.append(MockVehicle(i, ap, mc, faults, offsets[i], home, self.origin,
                                             links, sensor))

    # ------------------------------------------------------------- lifecycle
    def start(self, thread: bool = True) -> "MockFleet":
        """Open the sockets (and zenoh session); with ``thread`` start the simulation thread.

        Parameters
        ----------
        thread : bool
            True (default): a background thread runs the fleet on its clock. False: nothing runs
            by itself; a lock-step driver calls :meth:`service_io` and :meth:`step_until`
            (see :mod:`mission.sim.lockstep`).
        """
        if self._thread is not None or self._opened:
            raise RuntimeError("fleet already started")
        try:
            for v in self.vehicles:
                v.links.open()
            if self._zenoh_enabled:
                import zenoh

                from companion.sensor_wire import SensorPublisher
                from wire.zenoh_config import zenoh_config
                self._session = zenoh.open(zenoh_config(self._zenoh_listen, self._zenoh_connect,
                                                        **self._zenoh_security))
                self._publisher = SensorPublisher(self._session, self.fleet_name,
                                                  [v.sysid for v in self.vehicles],
                                                  track_matching=not thread)
        except BaseException:
            self._close_io()
            raise
        self._opened = True
        if not thread:
            return self
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="mock-fleet", daemon=True)
        self._thread.start()
        self._started.wait(10.0)
        return self

    def publish_readings_to(self, sink) -> None:
        """Hand every sensor reading to ``sink.publish(reading)`` instead of zenoh.

        For a fleet without zenoh (``zenoh=False`` or no endpoints): tests and benchmarks that want
        the readings without a zenoh session. ``sink.close()`` is called when the fleet stops.

        Raises
        ------
        ValueError
            If the fleet publishes on zenoh.
        """
        if self._zenoh_enabled:
            raise ValueError("publish_readings_to needs a fleet that does not publish on zenoh (zenoh=False "
                             "or no zenoh endpoints)")
        self._publisher = sink

    def stop(self) -> None:
        """Stop the thread and close every socket and the zenoh session (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10.0)
            self._thread = None
        self._close_io()
        self._opened = False

    def _close_io(self) -> None:
        for v in self.vehicles:
            v.links.close()
        if self._publisher is not None:
            self._publisher.close()
            self._publisher = None
        if self._session is not None:
            self._session.close()
            self._session = None

    def __enter__(self) -> "MockFleet":
        return self.start()

    def __exit__(self, *_exc) -> None:
        self.stop()

    @property
    def running(self) -> bool:
        """True while the simulation thread runs."""
        return self._thread is not None and self._thread.is_alive()

    @property
    def started(self) -> bool:
        """True from :meth:`start` (with or without thread) until :meth:`stop`."""
        return self._opened

    # ------------------------------------------------------------------ API
    @property
    def sim_time_s(self) -> float:
        """Simulated time of the last physics step done (-inf before the first)."""
        return self._sim_time_s

    def wait_for_sim_time(self, t_s: float, timeout_s: float = 30.0) -> bool:
        """Block until the physics has reached ``t_s`` (simulated); False on wall timeout.

        With ``thread=False`` the physics moves only in :meth:`step_until`.
        """
        with self._tick_cond:
            return self._tick_cond.wait_for(lambda: self._sim_time_s >= t_s - 1e-9, timeout_s)

    def vehicle(self, sysid: int) -> MockVehicle:
        """The vehicle with system id ``sysid``."""
        for v in self.vehicles:
            if v.sysid == sysid:
                return v
        raise KeyError(f"no vehicle with sysid {sysid}; fleet has {[v.sysid for v in self.vehicles]}")

    def set_fault(self, sysid: int, name: str, value) -> None:
        """Set one fault of one vehicle (see :class:`~sitl_mock.faults.FaultSet`)."""
        self.vehicle(sysid).faults.set(name, value)

    # ------------------------------------------------------------ lock-step driving
    @property
    def next_step_s(self) -> float:
        """Simulated time of the next physics step."""
        return self._t_start_s + self._k / PHYSICS_RATE_HZ

    @property
    def published_readings(self) -> int:
        """Readings put on zenoh while a subscriber matched (counted with ``thread=False`` only)."""
        return 0 if self._publisher is None else self._publisher.published_matched

    def readings_matched(self) -> bool:
        """True when every vehicle's sensor publisher has a matching subscriber (no zenoh: True)."""
        pub = self._publisher
        return pub is None or all(pub.has_subscribers(s) for s in pub.sysids)

    def service_io(self) -> int:
        """Read every socket with data now, send what the vehicles have to send; events handled."""
        handled = 0
        while True:
            events = self._selector.select(0)
            if not events:
                break
            handled += len(events)
            for key, mask in events:
                self._guard(key.data, mask)
        if handled:  # answers to what came in (outboxes fill only here and in the physics steps)
            t_io = self.clock.time()
            for v in self.vehicles:
                self._guard(v.links.pump, t_io)
        return handled

    def step_until(self, t_s: float) -> int:
        """Run every physics step due at or before ``t_s`` (simulated), then send their output.

        Returns
        -------
        int
            Steps run.
        """
        dt = 1.0 / PHYSICS_RATE_HZ
        sample_dt = 1.0 / self.sensor_rate_hz
        steps = 0
        while self.next_step_s <= t_s + 1e-9:
            if steps:  # catching up: send the previous step's frames first (see below)
                self._pump_all()
            self._tick(self.next_step_s, dt, sample_dt)
            self._k += 1
            steps += 1
        if steps:
            with self._tick_cond:
                self._sim_time_s = self.next_step_s - dt
                self._tick_cond.notify_all()
            self._pump_all()
        return steps

    def _pump_all(self) -> None:
        """Send every vehicle's pending frames now.

        Called between the steps of a catch-up too: on a starved host a run of up to
        ``_MAX_CATCHUP_STEPS`` steps (with their sensor publications, which may block on a slow
        zenoh peer) took over a wall second, and a ground station heard nothing from any vehicle
        for that long and declared the whole fleet lost (``tests/mission/telemetry/test_ctl_processes.py`` under load).
        """
        t_io = self.clock.time()
        for v in self.vehicles:
            self._guard(v.links.pump, t_io)

    # ------------------------------------------------------------ simulation thread
    def _run(self) -> None:
        clock = self.clock
        dt = 1.0 / PHYSICS_RATE_HZ
        lockstep = math.isinf(getattr(clock, "speedup", 1.0))
        speedup = getattr(clock, "speedup", 1.0)
        self._t_start_s = clock.time()
        self._k = 0
        wall0 = time.perf_counter()
        busy = 0.0
        self._started.set()
        while not self._stop.is_set():
            t0 = time.perf_counter()
            now = clock.time() + 1e-9
            if self.next_step_s <= now:
                self.step_until(min(now, self.next_step_s + (_MAX_CATCHUP_STEPS - 1) * dt))
            next_tick = self.next_step_s
            if not lockstep and next_tick <= now - max(1.0, 0.2 * speedup):
                # hopelessly behind (over 0.2 s of wall time): skip ahead, count it
                skipped = int((now - next_tick) / dt)
                self.stats["dropped_steps"] += skipped
                self._k += skipped
                next_tick = self.next_step_s
            self.stats["lag_s"] = max(0.0, now - next_tick)
            t_io = clock.time()
            for v in self.vehicles:
                self._guard(v.links.pump, t_io)
            busy += time.perf_counter() - t0
            if lockstep:
                timeout = _LOCKSTEP_POLL_S
            else:
                timeout = min(max((next_tick - clock.time()) / speedup, 0.0), 0.05)
            events = self._selector.select(timeout)
            t2 = time.perf_counter()
            for key, mask in events:
                self._guard(key.data, mask)
            busy += time.perf_counter() - t2
            self.stats["busy_wall_s"] = busy
            self.stats["wall_s"] = time.perf_counter() - wall0

    def _tick(self, t_s: float, dt: float, sample_dt: float) -> None:
        self.stats["ticks"] += 1
        due: list[MockVehicle] = []  # vehicles whose sensor samples at this step
        for v in self.vehicles:
            try:
                ap = v.autopilot
                ap.step(t_s, dt)
                v.dynamics.step(dt)
                ap.send_telemetry(t_s)
                if v.sensor is not None and t_s >= v.next_sample_s:
                    v.next_sample_s = max(v.next_sample_s + sample_dt, t_s) \
                        if math.isfinite(v.next_sample_s) else t_s + sample_dt
                    if not v.faults.crashed:
                        due.append(v)
            except Exception:  # never let one vehicle stop the fleet; keep the evidence
                self._record_error()
        if due:
            self._sample_all(due, t_s)

    def _sample_all(self, due: list[MockVehicle], t_s: float) -> None:
        """Take the readings of ``due`` (in fleet order) at ``t_s``: the field evaluated once
        for all of them (a batch of points gives each point's value bit for bit as one call per
        point, ``tests/sitl_mock/test_mock_step_identical.py``; the intermittent plume costs
        about 70 us per single-point call, 2 us per point in a batch of 50); a field that fails
        on the batch is asked point by point, so each vehicle keeps its own error."""
        where, sampled = [], []
        for v in due:
            try:
                north_m, east_m, down_m = v.dynamics.position_ned_m_tuple()
                where.append((v.mission_enu_of(north_m, east_m, down_m),
                              v.autopilot.ned_to_geodetic((north_m, east_m, down_m))))
                sampled.append(v)
            except Exception:  # as in _tick: this vehicle's evidence, the others go on
                self._record_error()
        if not sampled:
            return
        due = sampled
        values = [None] * len(due)
        field = due[0].sensor.field
        if all(v.sensor.field is field for v in due):
            try:
                batch = np.asarray(field.value(np.array([enu for enu, _ in where]), t_s), dtype=float)
                if batch.shape == (len(due),):
                    values = batch.tolist()
            except Exception:  # asked again point by point below: the errors are kept there
                values = [None] * len(due)
        for v, (enu, (lat, lon, alt)), value in zip(due, where, values):
            try:
                reading = v.sensor.sample(t_s, enu, lat, lon, alt, true_value=value)
                if self._publisher is not None:
                    self._publisher.publish(reading)
            except Exception:  # as in _tick: this vehicle's evidence, the others go on
                self._record_error()

    def _guard(self, fn, arg) -> None:
        try:
            fn(arg)
        except Exception:
            self._record_error()

    def _record_error(self) -> None:
        if len(self.errors) < _MAX_ERRORS_KEPT:
            self.errors.append(traceback.format_exc())

    def __repr__(self) -> str:
        return f"MockFleet(n={len(self.vehicles)}, clock={self.clock!r}, running={self.running})"
