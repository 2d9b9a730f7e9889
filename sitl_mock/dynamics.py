"""Point-mass multicopter dynamics under a cascaded position / velocity controller.

Each vehicle lives in its own LOCAL_NED frame (origin = its home on the ground, x north,
y east, z down). The ground is ``z = 0``: the vehicle never goes below it (``z <= 0``).

The controller is the usual autopilot cascade, reduced to a point mass:

* position loop: a square-root controller (linear ``kp_pos * error`` near the target,
  ``sqrt(2 a d)`` far from it, as ArduPilot's ``sqrt_controller``) plus an optional velocity
  feed-forward, giving a velocity command clamped to the horizontal, climb and descent speed
  limits;
* velocity loop: first order, ``dv = (v_cmd - v) * min(kp_vel * dt, a_max * dt / |v_cmd - v|)``
  (horizontal and vertical separately), so the velocity always moves *towards* the command
  and never exceeds the speed limits in still air;
* wind: a drag acceleration ``drag_per_s * (wind - v)``, with wind = constant + Ornstein-
  Uhlenbeck gusts; the autopilot compensates a low-passed estimate of it (like an integrator),
  so a constant wind is rejected after a few seconds and gusts push the vehicle around.

The state is kept in plain floats (faster than tiny numpy arrays); the array attributes of the
API (``position_ned_m``, ``velocity_ned_m_s``) are properties returning fresh copies.

The parameters live in :mod:`sitl_mock.dynamics_params` and the control laws in
:mod:`sitl_mock.dynamics_control` (``DynamicsParams`` and ``GRAVITY_M_S2`` are imported from there).
"""
from __future__ import annotations

import math

import numpy as np

from sitl_mock.dynamics_control import (
    finite3 as _finite3,
    limit_velocity_command,
    position_velocity_command,
    velocity_loop_step,
    wrap_pi as _wrap_pi,
)
from sitl_mock.dynamics_disturbances import NormalBatch, gauss_markov_step, wind_drag_step
from sitl_mock.dynamics_params import GRAVITY_M_S2, DynamicsParams

__all__ = ["Multicopter"]

_MODE_IDLE = "idle"          # motors off, or armed and sitting on the ground
_MODE_POSITION = "position"  # fly to / hold a position target
_MODE_VELOCITY = "velocity"  # follow a velocity target
_MODE_TAKEOFF = "takeoff"    # climb vertically to the takeoff altitude, then hold
_MODE_LAND = "land"          # hold horizontally, descend, touch down
_MODE_FALLING = "falling"    # no thrust (disarmed in the air, crashed, battery empty)

_GROUND_EPS_M = 1e-6
_LIFTOFF_M = 0.05            # above this height (m) the vehicle is no longer landed
_LANDED_SPEED_M_S = 0.1      # on the ground and slower than this: landed
_CRASH_IMPACT_M_S = 3.0      # hitting the ground faster than this: crashed
_TERMINAL_SPEED_M_S = 20.0
_LAND_HIGH_ALT_M = 10.0      # above this height LAND descends at max_speed_down (LAND_SPEED_HIGH)
_MAX_SUBSTEP_S = 0.02


class Multicopter:
    """Point-mass multicopter under a position controller, in its own LOCAL_NED frame (origin
    = home on the ground, z down). Seeded rng.

    Commands (``command_*``) set what the controller does; they have an effect only while the
    vehicle is armed and has not crashed (motors off otherwise). :meth:`arm` on the ground
    leaves the vehicle sitting there (idle) until a takeoff, or a position / velocity command
    that climbs. Preconditions such as "no takeoff while disarmed" are the autopilot's job.

    Parameters
    ----------
    params : DynamicsParams
    rng : numpy.random.Generator
        Source of gusts and GPS noise (reproducible with a seed).

    Attributes
    ----------
    yaw_rad : float
        Heading, radians clockwise from north.
    armed, landed, crashed : bool
    battery_remaining : float
        State of charge, 1.0 (full) .. 0.0 (empty); may be set (e.g. a low-battery fault).
    gps_glitch_ned_m : numpy.ndarray
        Offset added to the reported (not the true) position, set by the fleet.
    """

    def __init__(self, params: DynamicsParams, rng: np.random.Generator):
        self.params = params
        self.rng = rng
        self._n = self._e = self._d = 0.0
        self._vn = self._ve = self._vd = 0.0
        self.yaw_rad = 0.0
        self.armed = False
        self.landed = True
        self.crashed = False
        self.battery_remaining = 1.0
        self.gps_glitch_ned_m = np.zeros(3)
        self._mode = _MODE_IDLE
        self._land_fast_high = True       # LAND: max_speed_down above _LAND_HIGH_ALT_M
        self._tgt = (0.0, 0.0, 0.0)       # position target (NED m)
        self._vel_tgt = (0.0, 0.0, 0.0)   # velocity target or feed-forward (NED m/s)
        self._yaw_tgt: float | None = None
        self._gust = (0.0, 0.0, 0.0)
        self._gps_err = (0.0, 0.0, 0.0)
        self._wind_comp = (0.0, 0.0, 0.0)  # autopilot's compensation (m/s^2)
        self._load = 0.0                   # 0 (motors off) .. ~1.5 (climbing)
        self._normals = NormalBatch(rng)   # gusts and GPS noise share one stream

    # ------------------------------------------------------------------ state
    @property
    def position_ned_m(self) -> np.ndarray:
        """True position, NED metres from home (a copy; assign to teleport)."""
        return np.array((self._n, self._e, self._d))

    @position_ned_m.setter
    def position_ned_m(self, ned_m) -> None:
        n, e, d = _finite3(ned_m, "position")
        self._n, self._e, self._d = n, e, min(d, 0.0)
        self.landed = self._d >= -_LIFTOFF_M and self._mode == _MODE_IDLE

    def position_ned_m_tuple(self) -> tuple[float, float, float]:
        """True position ``(north_m, east_m, down_m)`` as floats (no array: for per-step code)."""
        return self._n, self._e, self._d

    @property
    def velocity_ned_m_s(self) -> np.ndarray:
        """True velocity, NED m/s (a copy; assign to set)."""
        return np.array((self._vn, self._ve, self._vd))

    @velocity_ned_m_s.setter
    def velocity_ned_m_s(self, ned_m_s) -> None:
        self._vn, self._ve, self._vd = _finite3(ned_m_s, "velocity")

    @property
    def mode(self) -> str:
        """Controller mode: idle, position, velocity, takeoff, land or falling."""
        return self._mode

    @property
    def position_target_ned_m(self) -> np.ndarray | None:
        """Current position target (None in velocity, idle and falling modes)."""
        if self._mode in (_MODE_POSITION, _MODE_TAKEOFF, _MODE_LAND):
            return np.array(self._tgt)
        return None

    @property
    def on_ground(self) -> bool:
        """True when touching the ground (z at 0)."""
        return self._d >= -_GROUND_EPS_M

    @property
    def battery_voltage_v(self) -> float:
        """Pack voltage: 3.5 .. 4.2 V per cell with the state of charge, minus sag under load."""
        soc = min(max(self.battery_remaining, 0.0), 1.0)
        cell = 3.5 + 0.7 * soc - 0.12 * self._load
        return int(self.params.battery_cells) * cell

    # --------------------------------------------------------------- commands
    def arm(self) -> None:
        """Start the motors; on the ground the vehicle stays there until told to climb."""
        if self.crashed:
            return
        self.armed = True
        if self.on_ground:
            self._mode = _MODE_IDLE
            self.landed = True

    def disarm(self) -> None:
        """Stop the motors; in the air the vehicle falls."""
        self.armed = False
        if not self.on_ground or self._mode == _MODE_FALLING:
            self._mode = _MODE_FALLING
        else:
            self._mode = _MODE_IDLE

    def _flying_allowed(self) -> bool:
        return self.armed and not self.crashed and self._mode != _MODE_FALLING

    def command_position(self, ned_m, yaw_rad=None, velocity_ff_ned_m_s=None) -> None:
        """Fly to and hold ``ned_m`` (NED m from home), optionally with a heading and a
        velocity feed-forward (NED m/s). A target at or below the ground while landed keeps the
        vehicle on the ground. Non-finite values raise ValueError (resolve MAVLink's ignored
        fields, e.g. via type_mask, before calling)."""
        if not self._flying_allowed():
            return
        n, e, d = _finite3(ned_m, "position target")
        ff = (0.0, 0.0, 0.0) if velocity_ff_ned_m_s is None else _finite3(
            velocity_ff_ned_m_s, "velocity feed-forward")
        self._tgt = (n, e, min(d, 0.0))
        self._vel_tgt = ff
        self._set_yaw_target(yaw_rad)
        self._mode = _MODE_POSITION

    def command_velocity(self, ned_m_s, yaw_rad=None) -> None:
        """Follow a velocity (NED m/s), clamped to the speed limits (ValueError if not finite)."""
        if not self._flying_allowed():
            return
        self._vel_tgt = _finite3(ned_m_s, "velocity target")
        self._set_yaw_target(yaw_rad)
        self._mode = _MODE_VELOCITY

    def command_hold(self) -> None:
        """Brake and hold at the stopping point (where braking at the limit ends)."""
        if not self._flying_allowed():
            return
        if self.on_ground and self._mode in (_MODE_IDLE, _MODE_LAND):
            self._mode = _MODE_IDLE
            return
        a = 0.5 * self.params.max_accel_m_s2
        self._tgt = (self._n + self._vn * abs(self._vn) / (2 * a),
                     self._e + self._ve * abs(self._ve) / (2 * a),
                     min(self._d + self._vd * abs(self._vd) / (2 * a), 0.0))
        self._vel_tgt = (0.0, 0.0, 0.0)
        self._mode = _MODE_POSITION

    def command_takeoff(self, alt_m: float) -> None:
        """Climb vertically at the takeoff speed to ``alt_m`` above home, then hold there."""
        if not self._flying_allowed():
            return
        alt = float(alt_m)
        if not (math.isfinite(alt) and alt > 0.0):
            raise ValueError(f"takeoff altitude must be a positive finite number, got {alt_m!r}")
        self._tgt = (self._n, self._e, -alt)
        self._vel_tgt = (0.0, 0.0, 0.0)
        self._mode = _MODE_TAKEOFF

    def command_land(self, fast_high: bool = True) -> None:
        """Hold horizontally and descend; on touchdown ``landed`` becomes True.

        ``fast_high``: above ``_LAND_HIGH_ALT_M`` descend at ``max_speed_down_m_s`` (an autopilot's
        LAND mode); False: at ``land_speed_m_s`` all the way (PX4's descent without a pilot).
        """
        if not self._flying_allowed():
            return
        self._land_fast_high = bool(fast_high)
        self._tgt = (self._n, self._e, 0.0)
        self._vel_tgt = (0.0, 0.0, 0.0)
        self._mode = _MODE_IDLE if self.on_ground else _MODE_LAND

    def crash(self) -> None:
        """The vehicle fails: motors stop, it falls and stays where it hits the ground."""
        self.crashed = True
        self.armed = False
        self._mode = _MODE_FALLING
        self.landed = self.on_ground and abs(self._vd) < _LANDED_SPEED_M_S

    def _set_yaw_target(self, yaw_rad) -> None:
        if yaw_rad is not None:
            y = float(yaw_rad)
            if math.isfinite(y):
                self._yaw_tgt = _wrap_pi(y)

    # ----------------------------------------------------------------- sensors
    def reported_position_ned_m(self) -> np.ndarray:
        """Position as the vehicle's GPS reports it: true + glitch offset + correlated noise
        (the same value until the next :meth:`step`)."""
        en, ee, ed = self._gps_err
        return np.array((self._n + en, self._e + ee, self._d + ed)) + self.gps_glitch_ned_m

    def position_estimate_ready(self, t_since_boot_s: float) -> bool:
        """True once the GPS has had ``params.gps_warmup_s`` seconds since boot."""
        return t_since_boot_s >= self.params.gps_warmup_s

    # -------------------------------------------------------------- simulation
    def step(self, dt_s: float) -> None:
        """Advance the simulation by ``dt_s`` seconds (sub-stepped above 20 ms)."""
        if not (dt_s > 0.0 and dt_s < math.inf):
            if dt_s == 0.0:
                return
            raise ValueError(f"step needs a finite dt_s >= 0, got {dt_s!r}")
        if dt_s > _MAX_SUBSTEP_S:
            n = math.ceil(dt_s / _MAX_SUBSTEP_S)
            for _ in range(n):
                self._step(dt_s / n)
        else:  # the fleet's 20 ms step: one sub-step
            self._step(dt_s)
        std = self.params.gps_noise_std_m
        if std > 0.0:
            self._gps_err = gauss_markov_step(self._gps_err, dt_s, self.params.gps_noise_tau_s, std,
                                              self._normals)
        elif self._gps_err != (0.0, 0.0, 0.0):
            self._gps_err = (0.0, 0.0, 0.0)

    def _step(self, dt: float) -> None:
        mode = self._mode
        if mode == _MODE_FALLING:
            self._fall(dt)
            return
        if mode == _MODE_IDLE:
            self._idle_step(dt)
            return
        cn, ce, cd = self._velocity_command()
        # on the ground and not asked to climb: stay there
        if self._d >= -_GROUND_EPS_M and cd >= 0.0:
            self._stay_on_ground(dt)
            return
        p = self.params
        self._vn, self._ve, self._vd = velocity_loop_step(
            self._vn, self._ve, self._vd, cn, ce, cd, p.kp_vel_per_s, p.max_accel_m_s2, dt)
        if p.drag_per_s > 0.0:
            self._wind_step(dt)
        self._integrate(dt)

    def _idle_step(self, dt: float) -> None:
        """Idle: sit on the ground (motors idling if armed); in the air hold if armed, else fall."""
        if not self.on_ground:  # idle in the air (teleported)
            if self.armed:
                self.command_hold()
            else:
                self._mode = _MODE_FALLING
            return
        self._vn = self._ve = self._vd = 0.0
        self._load = 0.1 if self.armed else 0.0
        self._drain(dt)
        self.landed = True

    def _velocity_command(self) -> tuple[float, float, float]:
        """Velocity command (NED m/s) of the current mode, within its speed limits."""
        p = self.params
        mode = self._mode
        if mode == _MODE_VELOCITY:
            cn, ce, cd = self._vel_tgt
        else:
            tn, te, td = self._tgt
            cn, ce, cd = position_velocity_command(tn - self._n, te - self._e, td - self._d,
                                                   p.kp_pos_per_s, 0.5 * p.max_accel_m_s2)
            fn, fe, fd = self._vel_tgt
            cn, ce, cd = cn + fn, ce + fe, cd + fd
        # speed limits (per mode)
        up_max, down_max = p.max_speed_up_m_s, p.max_speed_down_m_s
        if mode == _MODE_TAKEOFF:
            up_max = min(up_max, p.takeoff_speed_m_s)
        elif mode == _MODE_LAND:
            # descend at a constant rate until touchdown (faster high up: LAND_SPEED_HIGH)
            fast = self._land_fast_high and -self._d > _LAND_HIGH_ALT_M
            cd = max(down_max, p.land_speed_m_s) if fast else p.land_speed_m_s
            down_max = max(down_max, p.land_speed_m_s)
        return limit_velocity_command(cn, ce, cd, p.max_speed_h_m_s, up_max, down_max)

    def _stay_on_ground(self, dt: float) -> None:
        """On the ground with no climb commanded: stop there (a takeoff or landing ends)."""
        self._d = 0.0
        self._vn = self._ve = self._vd = 0.0
        self.landed = True
        self._load = 0.1
        if self._mode in (_MODE_LAND, _MODE_TAKEOFF):
            self._mode = _MODE_IDLE
        self._drain(dt)

    def _wind_step(self, dt: float) -> None:
        """Wind: drag towards the air mass (constant + gusts), minus the autopilot's compensation."""
        p = self.params
        wn, we, wd = p.wind_ned_m_s
        if p.wind_gust_std_m_s > 0.0:
            g = self._gust = gauss_markov_step(self._gust, dt, p.gust_tau_s, p.wind_gust_std_m_s,
                                               self._normals)
            wn, we, wd = wn + g[0], we + g[1], wd + g[2]
        c = self._wind_comp
        if wn or we or wd or c[0] or c[1] or c[2]:
            self._wind_comp, (dn, de, dd) = wind_drag_step((wn, we, wd), c, p.drag_per_s,
                                                           p.wind_comp_tau_s, dt)
            self._vn += dn
            self._ve += de
            self._vd += dd

    def _integrate(self, dt: float) -> None:
        """Integrate the position; ground contact, liftoff, end of takeoff, yaw, battery."""
        self._n += self._vn * dt
        self._e += self._ve * dt
        self._d += self._vd * dt
        if self._d >= 0.0:
            self._d, self._vd = 0.0, min(self._vd, 0.0)
        if self.landed and self._d < -_LIFTOFF_M:
            self.landed = False
        if self._mode == _MODE_TAKEOFF and abs(self._tgt[2] - self._d) < 0.05:
            self._mode = _MODE_POSITION
        self._yaw_step(dt)
        self._load = 1.0 + 0.5 * max(-self._vd, 0.0) / self.params.max_speed_up_m_s
        self._drain(dt)

    def _yaw_step(self, dt: float) -> None:
        if self._yaw_tgt is None:
            return
        err = _wrap_pi(self._yaw_tgt - self.yaw_rad)
        lim = self.params.yaw_rate_max_rad_s * dt
        self.yaw_rad = _wrap_pi(self.yaw_rad + max(-lim, min(lim, err)))

    def _drain(self, dt: float) -> None:
        if self._load > 0.0 and self.battery_remaining > 0.0:
            self.battery_remaining = max(
                0.0, self.battery_remaining - self._load * dt / self.params.battery_flight_time_s)
            if self.battery_remaining == 0.0 and not self.on_ground:
                self.armed = False
                self._mode = _MODE_FALLING

    def _fall(self, dt: float) -> None:
        self._load = 0.0
        if self.on_ground and self._vd <= 0.0:
            self._vn = self._ve = self._vd = 0.0
            self._d = 0.0
            self.landed = True
            return
        k = GRAVITY_M_S2 / _TERMINAL_SPEED_M_S
        self._vd += (GRAVITY_M_S2 - k * self._vd) * dt
        decay = max(0.0, 1.0 - k * dt)
        self._vn, self._ve = self._vn * decay, self._ve * decay
        self._n += self._vn * dt
        self._e += self._ve * dt
        self._d += self._vd * dt
        self.landed = False
        if self._d >= 0.0:
            if self._vd > _CRASH_IMPACT_M_S:
                self.crashed = True
            self._d = 0.0
            self._vn = self._ve = self._vd = 0.0
            self.landed = True
