"""CPU time of the coordinator's hot paths during the seek, per call, on process CPU time.

``bench_setpoints.py`` measures the whole coordinator against fake autopilots in cores (CPU time
over wall time): on a host loaded by other jobs the processes are starved, fewer setpoints go
out and the figure falls with the work done. This script times the paths its profile names in one
process, on ``time.process_time`` (another job's time is not counted), so that a change can be
compared on a loaded host:

* ``poll``: :meth:`mission.link.poller.UdpPoller.poll_once` over N real loopback UDP sockets
  holding 1 or 2 queued datagrams each (a 60-byte payload; the consumer does nothing): CPU per
  datagram read, ``sendto`` of the queueing not counted;
* ``gate``: one :meth:`mission.safety.gate.SafetyGate.step` of N vehicles moving as a formation
  (every batch through the safety envelope: fence, speed, separation on the paths) into a
  :class:`mission.vehicle.streamer.SetpointStreamer` (its ``tick``, the sending, not included);
* ``pack``: one SET_POSITION_TARGET_LOCAL_NED frame, CPU per frame, three ways giving the same
  bytes: pymavlink's ``msg.pack``, the payload ``struct`` + header + CRC of
  ``MavEndpoint.send_payload`` (the setpoint path before :class:`~mission.link.setpoint_frame.SetpointFramer`),
  and ``SetpointFramer.frame`` (the path now);
* ``record``: one seek ``iteration`` record of N vehicles written to a mission log, CPU per record,
  with every vehicle's whole status (``status``, the old record) and with ``status_changes``
  (what changed: nothing here, the steady seek).

Each figure is the best (least CPU) of ``--repeat`` runs: on a loaded host the noise only adds. Usage::

    python benchmarks/bench_hot_paths.py --n 100 254
"""
from __future__ import annotations

import argparse
import asyncio
import os
import socket
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def poll_cost_us(n: int, per_socket: int, polls: int = 200) -> float:
    """CPU microseconds per datagram of ``poll_once`` over ``n`` sockets with ``per_socket`` queued."""
    from mission.link.poller import UdpPoller

    async def run() -> float:
        poller = UdpPoller(interval_s=3600.0)
        socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(n)]
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        payload = bytes(60)
        try:
            for s in socks:
                s.bind(("127.0.0.1", 0))
                s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
                poller.register(s, lambda data, addr: None)
            await asyncio.sleep(0)
            addrs = [s.getsockname() for s in socks]
            cpu = 0.0
            read = 0
            for _ in range(polls):
                for a in addrs:
                    for _ in range(per_socket):
                        tx.sendto(payload, a)
                t0 = time.process_time()
                read += poller.poll_once()
                cpu += time.process_time() - t0
            return 1e6 * cpu / max(read, 1)
        finally:
            await poller.close()
            for s in socks + [tx]:
                s.close()

    return asyncio.run(run())


class _Vehicle:
    def __init__(self, sysid: int) -> None:
        self.sysid = sysid

    def send_position_enu(self, position_enu_m, yaw_rad=None) -> None:
        pass


def gate_cost_ms(n: int, steps: int = 400) -> float:
    """CPU milliseconds per ``SafetyGate.step`` of ``n`` vehicles moving as a formation."""
    from mission.core.clock import WallClock
    from mission.flight.targets import formation_offsets
    from mission.safety.envelope import SafetyEnvelope
    from mission.safety.fence import Geofence
    from mission.safety.gate import SafetyGate
    from mission.sim.embedded import default_radius_m
    from mission.vehicle.streamer import SetpointStreamer

    radius_m = default_radius_m(n)
    fence = Geofence(np.array([[-150.0, -150.0], [150.0, -150.0], [150.0, 150.0], [-150.0, 150.0]]), 2.0, 80.0)
    envelope = SafetyEnvelope(fence, 3.0, 1.5, radius_m)
    offsets = formation_offsets("cvt", n, radius_m)
    streamer = SetpointStreamer([_Vehicle(s + 1) for s in range(n)], 20.0)
    gate = SafetyGate(streamer, WallClock(), 3.0, envelope=envelope)
    centre = np.array([0.0, 0.0, 20.0])
    for i in range(n):
        gate.add(i + 1, centre + offsets[i])
    cpu = 0.0
    for k in range(steps):
        if k % 20 == 0:  # a new seek step every second (20 Hz): 3 m east, flown at 3 m/s
            centre = centre + [3.0, 0.0, 0.0]
            gate.set_goals({i + 1: centre + offsets[i] for i in range(n)})
        t0 = time.process_time()
        gate.step(0.05)
        cpu += time.process_time() - t0
    return 1e3 * cpu / steps


def pack_cost_us(frames: int = 20000) -> dict:
    """CPU microseconds per setpoint frame of pymavlink ``pack``, the ``send_payload`` build, the framer."""
    import struct

    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    from mission.link.setpoint_frame import SetpointFramer, crc16

    cls = mavlink.MAVLink_set_position_target_local_ned_message
    mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    framer = SetpointFramer(cls.id, 255, 190, 3, 1, mavlink.MAV_FRAME_LOCAL_NED)
    header = struct.Struct("<BBBBBBBHB")

    def by_pymavlink(k):
        return cls(k, 3, 1, 1, 0xDF8, 1.0 * k, 2.0, -20.0, 0, 0, 0, 0, 0, 0, 0.0, 0.0).pack(mav)

    def by_payload(k):   # EndpointSending.send_payload's build, routing and sending left out
        body = cls.unpacker.pack(k, 1.0 * k, 2.0, -20.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0xDF8, 3, 1, 1)
        body = body.rstrip(b"\x00") or b"\x00"
        frame = header.pack(0xFD, len(body), 0, 0, k & 0xFF, 255, 190, cls.id & 0xFFFF, cls.id >> 16) + body
        return frame + crc16(frame, cls.crc_extra).to_bytes(2, "little")

    def by_framer(k):
        return framer.frame(k & 0xFF, k, 1.0 * k, 2.0, -20.0, 0.0, 0xDF8)

    out = {}
    for name, fn in (("pymavlink", by_pymavlink), ("payload", by_payload), ("framer", by_framer)):
        mav.seq = 0
        t0 = time.process_time()
        for k in range(frames):
            fn(k)
        out[name] = 1e6 * (time.process_time() - t0) / frames
    return out


def record_cost_ms(n: int, records: int = 40) -> dict:
    """CPU milliseconds per ``iteration`` record of ``n`` vehicles: whole status lists, then changes."""
    import tempfile
    from pathlib import Path

    from mission.core.clock import WallClock
    from mission.telemetry.mission_log import MissionLog
    from mission.telemetry.status_changes import StatusChanges

    rng = np.random.default_rng(0)
    status = [{"sysid": s, "id": f"px4{s}", "status": "in formation", "sensor_retired": False,
               "flight_state": "flying", "flavour": "px4", "mode": "OFFBOARD", "armed": True,
               "relative_alt_m": 20.0 + rng.random(), "battery_pct": 97.0, "link_age_s": 0.04,
               "position_enu": np.round(rng.normal(size=3), 3), "setpoint_rate_hz": 20.00001,
               "setpoint_enu": np.round(rng.normal(size=3), 3)} for s in range(1, n + 1)]
    common = {"positions_enu": {s: rng.normal(size=3) for s in range(1, n + 1)},
              "setpoints_enu": {s: rng.normal(size=3) for s in range(1, n + 1)}, "centre_enu": np.zeros(3)}
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        log = MissionLog(Path(tmp) / "mission.jsonl", WallClock())
        changes = StatusChanges()
        changes.changes(status)   # the first record of the seek wrote everyone
        for name, extra in (("status", lambda: {"status": status}),
                            ("status_changes", lambda: {"status_changes": changes.changes(status)})):
            t0 = time.process_time()
            for k in range(records):
                log.write("iteration", k=k, **common, **extra())
            out[name] = 1e3 * (time.process_time() - t0) / records
        log.close()
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[100, 254])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    print("| N | poll, us per datagram (1 queued / 2 queued) | gate step, ms |")
    print("|---|---|---|")
    for n in args.n:
        one = min(poll_cost_us(n, 1) for _ in range(args.repeat))
        two = min(poll_cost_us(n, 2) for _ in range(args.repeat))
        gate = min(gate_cost_ms(n) for _ in range(args.repeat))
        print(f"| {n} | {one:.2f} / {two:.2f} | {gate:.3f} |")
    packs = [pack_cost_us() for _ in range(args.repeat)]
    print("\nsetpoint frame, us per frame: " + ", ".join(
        f"{k} {min(p[k] for p in packs):.2f}" for k in packs[0]))
    for n in args.n:
        recs = [record_cost_ms(n) for _ in range(args.repeat)]
        print(f"iteration record of {n} vehicles, ms per record: " + ", ".join(
            f"{k} {min(r[k] for r in recs):.2f}" for k in recs[0]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
