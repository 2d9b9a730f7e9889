"""A whole signed mission against the embedded mock fleet while an intruder injects frames.

Run from the repository root (needs ``mission.link.endpoint.MavEndpoint.open(..., signing=...)``, the
change described with :mod:`mission.link.signing`; says so and exits otherwise)::

    python benchmarks/bench_signing_mission.py [--n 4] [--attack-hz 20] [--provision]

The fleet is PX4 over UDP (the intruder can reach both the vehicles' and the ground station's
ports). Once every vehicle signs, an intruder on 127.0.0.1 sends, per vehicle and ``--attack-hz``:

* to the vehicle: a DO_SET_MODE to AUTO.LAND signed with a wrong key, an unsigned forced
  DISARM, a SET_POSITION_TARGET_LOCAL_NED 500 m away signed with a wrong key;
* to the ground station, as the vehicle: a LOCAL_POSITION_NED 100 m away signed with a wrong
  key, an unsigned disarmed HEARTBEAT, and a genuine signed frame it captured at least 0.5 s
  earlier (it made itself a peer of the vehicle, which then streams to it too).

Prints the outcome and estimation error with and without the intruder, the frames injected and
the rejections counted on both sides (they must match), and whether anything changed.
``--provision`` starts the vehicles without a key (the ground station sends SETUP_SIGNING).
"""
from __future__ import annotations

import argparse
import asyncio
import inspect
import os
import socket
import sys
import threading
import time
from collections import Counter, deque

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import numpy as np  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mav  # noqa: E402

from mission.core.signing_config import SigningConfig
from mission.link.signing import apply_signing

KEY = bytes(range(1, 33))
WRONG_KEY = bytes(range(101, 133))
_PX4_LAND = (4 << 16) | (6 << 24)  # custom_mode of AUTO.LAND: main 4, sub 6


class _Intruder(threading.Thread):
    """Sends forged, unsigned and replayed frames at ``rate_hz`` until stopped."""

    def __init__(self, fleet, rate_hz: float):
        super().__init__(name="intruder", daemon=True)
        self.fleet = fleet
        self.period_s = 1.0 / rate_hz
        self.stop_event = threading.Event()
        self.sent: Counter = Counter()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.0)
        self._captured: deque = deque(maxlen=20000)

    def _capture(self) -> None:
        while True:
            try:
                data = self.sock.recv(65536)
            except (BlockingIOError, InterruptedError):
                return
            self._captured.append((time.monotonic(), data))

    def _replayable(self) -> bytes | None:
        while self._captured and time.monotonic() - self._captured[0][0] > 0.5:
            _t, data = self._captured.popleft()
            if data[0] == 0xFD and data[2] & 1:
                return data[:data[1] + 12 + 13]  # the first frame of the datagram
        return None

    def run(self) -> None:
        for v in self.fleet.vehicles:
            self.sock.sendto(b"\x00", ("127.0.0.1", v.udp_bind_port))  # become a peer
        forger = {v.sysid: apply_signing(mav.MAVLink(None, 255, 190),
                                         SigningConfig(WRONG_KEY).new_state(time.time() + 3600))
                  for v in self.fleet.vehicles}
        plain = mav.MAVLink(None, 255, 190)
        ports = {v.sysid: v.udp_send_port for v in self.fleet.vehicles}
        while not self.stop_event.wait(self.period_s):
            self._capture()
            for v in self.fleet.vehicles:
                self._attack(v, forger[v.sysid], plain)
            old = self._replayable()
            if old is not None and old[5] in ports:
                self._send(("127.0.0.1", ports[old[5]]), old, "down_replayed")
        self.sock.close()

    def _attack(self, v, f, plain) -> None:
        s = v.sysid
        up = ("127.0.0.1", v.udp_bind_port)
        down = ("127.0.0.1", v.udp_send_port)
        land = f.command_long_encode(s, 1, mav.MAV_CMD_DO_SET_MODE, 0, 1, 4, 6, 0, 0, 0, 0)
        self._send(up, land.pack(f), "up_bad_signature")
        disarm = plain.command_long_encode(s, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                           0, 21196, 0, 0, 0, 0, 0)
        self._send(up, disarm.pack(plain), "up_unsigned")
        away = f.set_position_target_local_ned_encode(0, s, 1, 1, 0xDF8, 500, 500, -50,
                                                      0, 0, 0, 0, 0, 0, 0, 0)
        self._send(up, away.pack(f), "up_bad_signature")
        veh = apply_signing(mav.MAVLink(None, s, 1), f.signing)
        self._send(down, veh.local_position_ned_encode(0, 100.0, 100.0, -50.0, 0, 0, 0).pack(veh),
                   "down_bad_signature")
        fake = mav.MAVLink(None, s, 1)
        hb = fake.heartbeat_encode(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, 0, _PX4_LAND,
                                   mav.MAV_STATE_STANDBY, 3)
        self._send(down, hb.pack(fake), "down_unsigned")

    def _send(self, addr, frame: bytes, kind: str) -> None:
        try:
            self.sock.sendto(frame, addr)
            self.sent[kind] += 1
        except OSError:
            self.sent["send_error"] += 1


async def _mission(n: int, attack_hz: float, provision: bool, seed: int) -> dict:
    import zenoh

    from mission.flight.coordinator import Coordinator
    from mission.sim.embedded import DEFAULT_ORIGIN, default_eps, embedded_plan, fleet_ports
    from mission.core.plan_types import replace_plan
    from sitl_mock.fields_config import make_field
    from sitl_mock.fleet import MockFleet

    source = np.array([6.0, -4.0, 13.0])
    start = source + np.array([-8.0, 5.0, -2.0])
    field = make_field("sigma2", source)
    ports = fleet_ports(n, "px4")
    plan = embedded_plan(n, ports, personality="px4", start_enu_m=start, eps=default_eps(field),
                         max_iterations=150, origin=DEFAULT_ORIGIN)
    plan = replace_plan(plan, security=SigningConfig(KEY))
    fleet = MockFleet(n=n, personality="px4", field=field, origin=DEFAULT_ORIGIN, speedup=10.0,
                      seed=seed, udp_base_port=ports["udp_base_port"],
                      udp_bind_base_port=ports["udp_bind_base_port"], tcp_base_port=0,
                      fleet_name=plan.fleet, sensor_noise_std=0.005,
                      zenoh_listen=[f"tcp/127.0.0.1:{ports['zenoh_port']}"],
                      signing_key=None if provision else KEY)
    fleet.start()
    session = zenoh.open(plan.zenoh.to_config())
    intruder = _Intruder(fleet, attack_hz) if attack_hz > 0 else None
    try:
        co = Coordinator(plan, clock=fleet.clock, zenoh_session=session)
        task = asyncio.ensure_future(co.run())
        if intruder is not None:
            while not all(v.autopilot.signing.enabled for v in fleet.vehicles) and not task.done():
                await asyncio.sleep(0.05)  # provisioning first (SETUP_SIGNING is sent in clear)
            intruder.start()
        result = await task
    finally:
        if intruder is not None:
            intruder.stop_event.set()
            if intruder.is_alive():
                intruder.join(5.0)
        session.close()
        fleet.stop()
    gcs, vehicles = Counter(), Counter()
    for ep in co.endpoints.values():
        gcs.update({k: ep.counters[k] for k in ("unsigned", "bad_signature", "replayed",
                                                "setup_signing_sent")})
    for v in fleet.vehicles:
        vehicles.update({k: v.autopilot.counters[k] for k in (
            "rx_unsigned", "rx_bad_signature", "rx_replayed", "signing_setup_accepted")})
    error = (None if result.estimate_enu is None
             else float(np.linalg.norm(np.asarray(result.estimate_enu) - source)))
    return {"outcome": result.outcome, "error_m": error, "gcs": gcs, "vehicles": vehicles,
            "sent": intruder.sent if intruder is not None else Counter(), "errors": fleet.errors}


def main() -> int:
    """Run the mission without and with the intruder; print the figures."""
    from mission.link.endpoint import MavEndpoint

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=4)
    parser.add_argument("--attack-hz", type=float, default=20.0)
    parser.add_argument("--provision", action="store_true")
    parser.add_argument("--seed", type=int, default=3)
    args = parser.parse_args()
    if "signing" not in inspect.signature(MavEndpoint.open).parameters:
        print("skipped: mission.link.endpoint.MavEndpoint.open has no signing= yet")
        return 0
    for attack_hz in (0.0, args.attack_hz):
        t0 = time.monotonic()
        r = asyncio.run(_mission(args.n, attack_hz, args.provision, args.seed))
        err = "n/a" if r["error_m"] is None else f"{r['error_m']:.3f} m"
        print(f"intruder {attack_hz:g} Hz/vehicle: outcome {r['outcome']}, error {err}, "
              f"wall {time.monotonic() - t0:.1f} s, fleet errors {len(r['errors'])}")
        print(f"  injected: {dict(r['sent'])}")
        print(f"  ground station rejected: {dict(r['gcs'])}")
        print(f"  vehicles rejected: {dict(r['vehicles'])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
