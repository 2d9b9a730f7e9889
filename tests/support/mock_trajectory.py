"""A fixed mock-fleet scenario recorded step by step, to prove a faster mock flies the same.

:func:`record_scenario` flies four vehicles (two PX4, two ArduPilot personalities) of a
:class:`~sitl_mock.fleet.MockFleet` without sockets or zenoh, on a clock that only moves when the
scenario moves it: GCS heartbeats, mode changes, arming, take-off, position and velocity
setpoints, a GPS glitch, geofences that are enabled but never breached, gusts, GPS noise and
sensor noise, then a landing. Every physics step it keeps each vehicle's true position, and it
keeps every telemetry frame the autopilots send and every sensor reading they take.

:func:`summarise` reduces that to what ``tests/sitl_mock/data/mock_trajectory_golden.json`` holds
(a digest of every position bit, of every frame byte and of every reading; the positions every
0.5 s in full), once over a Gaussian field and once over the intermittent plume. The file was written by the mock as it was before its per-step fast paths
(commit 10ec088), so the test comparing against it fails if an optimisation changes one bit of a
trajectory, frame or reading. A deliberate change of the mock's behaviour rewrites it with
``PYTHONPATH=$PWD python -m tests.support.mock_trajectory --write`` (say why in the commit).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import math
import struct
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mav

from sitl_mock.dynamics_params import DynamicsParams
from sitl_mock.fields_config import make_field
from sitl_mock.fleet import PHYSICS_RATE_HZ, MockFleet
from sitl_mock.transport import make_parser

GOLDEN_PATH = Path(__file__).resolve().parents[1] / "sitl_mock" / "data" / "mock_trajectory_golden.json"
T0_S = 1_750_000_000.0
DURATION_S = 60.0
KEEP_EVERY_STEPS = 25
_POS_ONLY = 0b110111111000
_VEL_ONLY = 0b110111000111
_PARAMS = [{"GF_MAX_HOR_DIST": 500.0, "GF_MAX_VER_DIST": 120.0}, {},
           {"FENCE_ENABLE": 1, "FS_GCS_ENABLE": 2}, {}]


class _Clock:
    """Simulated time that moves only when the scenario sets it."""

    speedup = math.inf

    def __init__(self, t_s: float):
        self.t_s = t_s

    def time(self) -> float:
        return self.t_s


class _ReadingSink:
    """Stands in for the fleet's zenoh publisher: keeps every reading."""

    def __init__(self):
        self.readings: list[dict] = []

    def publish(self, reading: dict) -> None:
        self.readings.append(dict(reading))

    def close(self) -> None:
        """Nothing to release."""


class _Gcs:
    """One ground-station encoder per vehicle; its messages go through the vehicle's parser."""

    def __init__(self, vehicle):
        self.ap = vehicle.autopilot
        self.enc = mav.MAVLink(None, srcSystem=255, srcComponent=190)
        self.parser = make_parser()

    def send(self, msg, t_s: float) -> None:
        for parsed in self.parser.parse_buffer(msg.pack(self.enc)) or []:
            self.ap.handle_message(parsed, t_s)

    def command(self, t_s: float, cmd, *params) -> None:
        p = list(params) + [0.0] * (7 - len(params))
        self.send(self.enc.command_long_encode(self.ap.sysid, 1, cmd, 0, *p), t_s)

    def set_mode(self, t_s: float, name: str) -> None:
        cm = self.ap.personality.custom_mode(name)
        if self.ap.personality.name == "px4":
            self.command(t_s, mav.MAV_CMD_DO_SET_MODE, 1, (cm >> 16) & 0xFF, (cm >> 24) & 0xFF)
        else:
            self.command(t_s, mav.MAV_CMD_DO_SET_MODE, 1, cm)

    def setpoint(self, t_s: float, xyz, mask=_POS_ONLY) -> None:
        n, e, d = xyz
        self.send(self.enc.set_position_target_local_ned_encode(
            0, self.ap.sysid, 1, mav.MAV_FRAME_LOCAL_NED, mask, n, e, d, n, e, d, 0, 0, 0, 0, 0), t_s)


def _act(k: int, i: int, gcs: _Gcs, fleet: MockFleet, t_s: float) -> None:
    """The scenario's commands for vehicle ``i`` before physics step ``k`` (50 steps a second)."""
    px4 = gcs.ap.personality.name == "px4"
    if k % 50 == 0:
        gcs.send(gcs.enc.heartbeat_encode(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3), t_s)
    goal = (15.0 + 3.0 * i, -10.0 + 2.0 * i, -12.0 - i)
    if k == 150:
        if not px4:
            gcs.set_mode(t_s, "GUIDED")
        gcs.command(t_s, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        alt = 8.0 + i
        if px4:  # PX4: AMSL altitude, NaN for "keep"; ArduPilot: relative altitude
            gcs.command(t_s, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan,
                        gcs.ap.home_origin[2] + alt)
        else:
            gcs.command(t_s, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt)
    elif 600 <= k < 1500 and k % 5 == 0:
        gcs.setpoint(t_s, goal)
        if px4 and k == 605:
            gcs.set_mode(t_s, "OFFBOARD")
    elif 1500 <= k < 1800 and k % 5 == 0:
        gcs.setpoint(t_s, (0.5, -0.5, 0.2), mask=_VEL_ONLY)
    elif k == 1800:
        gcs.command(t_s, mav.MAV_CMD_NAV_LAND)
    if i == 1 and k in (700, 1000):
        fleet.set_fault(gcs.ap.sysid, "gps_glitch_m", 4.0 if k == 700 else 0.0)


#: the fields the scenario is recorded on: a Gaussian and the intermittent (time-dependent) plume
FIELDS = ("sigma1", "intermittent")


def record_scenario(field: str = "sigma1", seed: int = 7) -> dict:
    """Fly the scenario over the field named ``field`` (:data:`FIELDS`); return ``positions`` (per step, per vehicle NED m), ``frames`` (per
    vehicle, every telemetry frame in order) and ``readings`` (every sensor reading in order)."""
    clock = _Clock(T0_S)
    fleet = MockFleet(4, personality=["px4", "px4", "ardupilot", "ardupilot"], field=make_field(field, (20.0, 5.0, 10.0)),
                      clock=clock, seed=seed, udp_base_port=0, tcp_base_port=0, zenoh=False,
                      sensor_noise_std=0.05, params=_PARAMS,
                      dynamics=DynamicsParams(gps_noise_std_m=0.3, wind_ned_m_s=(1.0, -0.5, 0.0),
                                              wind_gust_std_m_s=0.4))
    sink = _ReadingSink()
    frames: list[list[bytes]] = [[] for _ in fleet.vehicles]
    positions: list[list[tuple]] = []
    fleet.start(thread=False)
    try:
        fleet.publish_readings_to(sink)  # the readings, without a zenoh session
        for i, v in enumerate(fleet.vehicles):
            _record_frames(v.autopilot, frames[i])
        gcs = [_Gcs(v) for v in fleet.vehicles]
        for k in range(int(DURATION_S * PHYSICS_RATE_HZ)):
            t_s = fleet.next_step_s
            clock.t_s = t_s
            for i, g in enumerate(gcs):
                _act(k, i, g, fleet, t_s)
            fleet.step_until(t_s)
            positions.append([tuple(float(x) for x in v.dynamics.position_ned_m) for v in fleet.vehicles])
        errors = list(fleet.errors)
    finally:
        fleet.stop()
    return {"positions": positions, "frames": frames, "readings": sink.readings, "errors": errors}


def _record_frames(ap, sink: list) -> None:
    drain = ap.drain_outbox

    def recording_drain() -> list[bytes]:
        out = drain()
        sink.extend(out)
        return out

    ap.drain_outbox = recording_drain


#: the fields of a reading that come from the mock's geodetic conversion (``TangentFrame``): it calls
#: numpy's sin/cos/hypot/arctan as pymap3d does, whose last bit depends on the CPU (AVX-512 loops
#: on one machine, libm on another), so they are compared within a tolerance, not by digest
GEODETIC_KEYS = ("lat_deg", "lon_deg", "alt_m")


def summarise(run: dict) -> dict:
    """Digests of every position bit, frame byte and reading (but its geodetic fields: their sums and
    every 8th), and the positions every 0.5 s."""
    pos = hashlib.sha256()
    for step in run["positions"]:
        for ned in step:
            pos.update(struct.pack("<3d", *ned))
    frames = [hashlib.sha256(b"".join(f)).hexdigest() for f in run["frames"]]
    plain = [{k: v for k, v in r.items() if k not in GEODETIC_KEYS} for r in run["readings"]]
    readings = hashlib.sha256(json.dumps(plain, sort_keys=True).encode()).hexdigest()
    geodetic = [[r[k] for k in GEODETIC_KEYS] for r in run["readings"]]
    return {
        "steps": len(run["positions"]),
        "positions_sha256": pos.hexdigest(),
        "frames_per_vehicle": [len(f) for f in run["frames"]],
        "frames_sha256": frames,
        "readings": len(run["readings"]),
        "readings_sha256": readings,
        "readings_geodetic_fsum": [math.fsum(g[k] for g in geodetic) for k in range(len(GEODETIC_KEYS))],
        "readings_geodetic_every_8": geodetic[::8],
        "positions_every_0_5_s": [[list(ned) for ned in step]
                                  for step in run["positions"][::KEEP_EVERY_STEPS]],
    }


def main(argv=None) -> int:
    """``--write``: record the scenario and write the golden file; else print its summary."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help=f"write {GOLDEN_PATH}")
    args = ap.parse_args(argv)
    runs = {name: record_scenario(name) for name in FIELDS}
    for name, run in runs.items():
        if run["errors"]:
            print(f"fleet errors ({name}):", *run["errors"], sep="\n")
            return 1
    golden = {name: summarise(run) for name, run in runs.items()}
    if args.write:
        GOLDEN_PATH.parent.mkdir(parents=True, exist_ok=True)
        GOLDEN_PATH.write_text(json.dumps(golden, indent=None) + "\n")
        print(f"wrote {GOLDEN_PATH}")
    for name, summary in golden.items():
        print(name, json.dumps({k: v for k, v in summary.items() if k != "positions_every_0_5_s"}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
