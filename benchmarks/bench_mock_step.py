"""CPU cost of one mock-fleet physics step per vehicle (prints figures; asserts nothing).

A :class:`sitl_mock.fleet.MockFleet` of ``--n`` PX4 vehicles (no sockets, no zenoh; sensors on a
``sigma1`` field at 10 Hz, taken but not published) is stepped by hand with
:meth:`~sitl_mock.fleet.MockFleet.step_until`, the way ``swarmseek run``'s lock-step world steps
it: autopilot logic, failsafe checks, dynamics, telemetry frames, sensor readings. Three phases,
each ``--seconds`` of simulated time:

* ``ground``: disarmed on the ground (GPS warm-up done), telemetry and sensors running;
* ``hover``: armed, taken off to 10 m, holding (PX4 AUTO.LOITER);
* ``offboard``: in OFFBOARD following position setpoints a ground station sends at 10 Hz (the
  setpoints' parsing and handling are in the figure: the mock's receive path).

For each phase: process CPU microseconds per vehicle-step (best and median of ``--repeat``),
and what that is for 50 vehicles at 50 Hz in cores. ``--profile PATH`` writes a cProfile of one
offboard phase (``python -m pstats PATH``).

``PYTHONPATH=$PWD python benchmarks/bench_mock_step.py --n 50 --seconds 10 --repeat 3``
"""
from __future__ import annotations

import argparse
import cProfile
import math
import statistics
import time

from pymavlink.dialects.v20 import ardupilotmega as mav

from sitl_mock.dynamics_params import DynamicsParams
from sitl_mock.fields_gaussian import sigma1
from sitl_mock.fleet import PHYSICS_RATE_HZ, MockFleet
from sitl_mock.transport import make_parser

_POS_ONLY = 0b110111111000


class _Clock:
    speedup = math.inf

    def __init__(self, t_s):
        self.t_s = t_s

    def time(self):
        return self.t_s


class _Sink:
    """Takes the readings the fleet would put on zenoh."""

    def publish(self, reading):
        pass

    def close(self):
        pass


class _Bench:
    def __init__(self, n: int):
        self.clock = _Clock(1_750_000_000.0)
        self.fleet = MockFleet(n, field=sigma1(), clock=self.clock, udp_base_port=0, tcp_base_port=0,
                               zenoh=False, sensor_noise_std=0.05,
                               dynamics=DynamicsParams(gps_noise_std_m=0.3))
        self.fleet.start(thread=False)
        self.fleet.publish_readings_to(_Sink())  # readings built, not published (zenoh's put is not the mock's)
        self.enc = mav.MAVLink(None, srcSystem=255, srcComponent=190)
        self.parser = make_parser()

    def send(self, ap, msg):
        for parsed in self.parser.parse_buffer(msg.pack(self.enc)) or []:
            ap.handle_message(parsed, self.clock.t_s)

    def command(self, ap, cmd, *params):
        p = list(params) + [0.0] * (7 - len(params))
        self.send(ap, self.enc.command_long_encode(ap.sysid, 1, cmd, 0, *p))

    def run(self, seconds: float, setpoints: bool = False) -> float:
        """Step ``seconds``; returns process CPU seconds spent in the fleet's steps only."""
        cpu = 0.0
        for k in range(int(round(seconds * PHYSICS_RATE_HZ))):
            t_s = self.fleet.next_step_s
            self.clock.t_s = t_s
            if setpoints and k % 5 == 0:
                self._setpoints()
            c0 = time.process_time()
            self.fleet.step_until(t_s)
            cpu += time.process_time() - c0
        return cpu

    def _setpoints(self):
        for i, v in enumerate(self.fleet.vehicles):
            x, y = 10.0 + i % 7, -5.0 + i // 7
            self.send(v.autopilot, self.enc.set_position_target_local_ned_encode(
                0, v.sysid, 1, mav.MAV_FRAME_LOCAL_NED, _POS_ONLY, x, y, -10.0, 0, 0, 0, 0, 0, 0, 0, 0))

    def take_off(self):
        for v in self.fleet.vehicles:
            ap = v.autopilot
            self.command(ap, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
            self.command(ap, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan,
                         ap.home_origin[2] + 10.0)
        self.run(12.0)

    def offboard(self):
        self._setpoints()
        for v in self.fleet.vehicles:
            cm = v.autopilot.personality.custom_mode("OFFBOARD")
            self.command(v.autopilot, mav.MAV_CMD_DO_SET_MODE, 1, (cm >> 16) & 0xFF, (cm >> 24) & 0xFF)

    def close(self):
        self.fleet.stop()


def _phases(n: int, seconds: float, profile: cProfile.Profile | None) -> dict:
    b = _Bench(n)
    try:
        b.run(3.0)  # GPS warm-up
        steps = n * seconds * PHYSICS_RATE_HZ
        out = {"ground": b.run(seconds) / steps}
        b.take_off()
        out["hover"] = b.run(seconds) / steps
        b.offboard()
        if profile is not None:
            profile.enable()
        out["offboard"] = b.run(seconds, setpoints=True) / steps
        if profile is not None:
            profile.disable()
        modes = {v.autopilot.mode_name for v in b.fleet.vehicles}
        if b.fleet.errors or modes != {"OFFBOARD"}:
            raise SystemExit(f"the fleet did not fly the benchmark: modes {modes}, errors {b.fleet.errors[:1]}")
    finally:
        b.close()
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=50, help="vehicles (default 50)")
    ap.add_argument("--seconds", type=float, default=10.0, help="simulated seconds per phase (default 10)")
    ap.add_argument("--repeat", type=int, default=3, help="runs; best and median shown (default 3)")
    ap.add_argument("--profile", metavar="PATH", help="cProfile one offboard phase into PATH")
    args = ap.parse_args(argv)
    runs = [_phases(args.n, args.seconds, None) for _ in range(args.repeat)]
    print(f"mock fleet step, {args.n} PX4 vehicles, {args.seconds:g} s per phase, {args.repeat} runs "
          f"(process CPU per vehicle-step)")
    for phase in ("ground", "hover", "offboard"):
        vals = [r[phase] * 1e6 for r in runs]
        best, med = min(vals), statistics.median(vals)
        cores = med * 1e-6 * 50 * PHYSICS_RATE_HZ
        print(f"  {phase:9s} best {best:6.1f} us  median {med:6.1f} us  "
              f"-> 50 vehicles at 50 Hz: {cores:.3f} core")
    if args.profile:
        prof = cProfile.Profile()
        _phases(args.n, args.seconds, prof)
        prof.dump_stats(args.profile)
        print(f"profile of one offboard phase: {args.profile}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
