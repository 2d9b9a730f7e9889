"""Benchmark: the ground station's setpoint streaming to N vehicles at 20 Hz, with telemetry parsed.

For every N and every stack, three processes:

* the *vehicles* (``--role vehicles``): N fake autopilots (``tests/support/fake_autopilot.py``), one UDP
  socket each, sending telemetry like an autopilot at the rates the mission asks for
  (GLOBAL_POSITION_INT and LOCAL_POSITION_NED 5 Hz; HEARTBEAT, SYS_STATUS, EXTENDED_SYS_STATE
  1 Hz) and time-stamping every setpoint they receive (``time.perf_counter``): the intervals and
  rates are MEASURED AT THE VEHICLES;
* the *coordinator* (``--role coordinator``): the stack under test connects, then streams 20 Hz
  setpoints to every vehicle while parsing all their telemetry; its CPU (process CPU time / wall
  time, in cores, all threads included) and memory (RSS) are measured over the window;
* this driver, which starts both, tells the vehicles when the measurement window opens and
  closes, and prints the table.

Stacks:

* ``bare-pymavlink``: the floor: one non-blocking socket, pymavlink ``pack`` + ``sendto`` for
  every vehicle at 20 Hz, nothing received or parsed ("bare pymavlink sending alone");
* ``swarmseek``: ``mission.link.endpoint`` + ``mission.vehicle.vehicle_link`` + ``mission.vehicle.streamer``, one ``udpin``
  endpoint per vehicle (PX4 SITL style ports);
* ``swarmseek-polled``: the same with a shared ``UdpPoller`` (sockets drained every 10 ms by one
  task instead of one event-loop wake-up per datagram);
* ``swarmseek-shared`` (``-shared-polled``): every vehicle on one shared UDP port (demultiplexed
  by sysid), without (with) the poller;
* ``mavsdk``: MAVSDK 4.x (``mavsdk.asyncio``), one Mavsdk instance with one connection per vehicle,
  ``Offboard.set_position_ned`` once per vehicle then ``Offboard.start`` (MAVSDK then streams it
  at its fixed 20 Hz from its own threads, MAVSDK's cheapest way to stream; ``--rate`` does not
  apply to it);
* ``mavsdk-shared``: the same with all vehicles on one shared ``udpin://`` connection.

Extending (e.g. to add estimation to the load): :func:`run_swarmseek` takes ``extra_load``, an
async callable ``extra_load(vehicles, streamer, clock)`` started instead of the streamer's own task
(it sends by calling ``streamer.tick()``, as the mission's safety gate does) and cancelled
at the end of the window; its cost is then part of the coordinator CPU figure. From the command
line: ``--extra-load package.module:function`` (swarmseek stacks only; modules of ``benchmarks/``
are found by name, e.g. ``--extra-load seek_load:seek_load`` for the coordinator's seek-loop work).

Run::

    python benchmarks/bench_setpoints.py                     # N = 8, 32, 100, 200, all stacks
    python benchmarks/bench_setpoints.py --n 100 --stacks swarmseek mavsdk --duration 10
"""
from __future__ import annotations

import argparse
import asyncio
import collections
import json
import os
import queue as queue_mod
import socket
import subprocess
import sys
import threading
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mission.sim.embedded import free_port_block  # noqa: E402 - after the path set-up

STACKS = ("bare-pymavlink", "swarmseek", "swarmseek-polled", "swarmseek-shared", "swarmseek-shared-polled",
          "mavsdk", "mavsdk-shared")
ORIGIN = (45.19, 5.72, 230.0)


def _rss_mb() -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def _stdin_commands(loop, queue) -> None:
    for line in sys.stdin:
        loop.call_soon_threadsafe(queue.put_nowait, line.strip())
    loop.call_soon_threadsafe(queue.put_nowait, "STOP")


# ---------------------------------------------------------------------------------- vehicles
async def _vehicles_main(n: int, port_base: int, shared: bool) -> None:
    from tests.support.fake_autopilot import FakeAutopilot, FakeUdpVehicle
    from formation.geodesy import enu_to_geodetic

    fakes = []
    for i in range(n):
        home = tuple(float(v) for v in enu_to_geodetic(np.array([5.0 * (i % 15), 5.0 * (i // 15), 0.0]), ORIGIN))
        ap = FakeAutopilot(i + 1, flavour="px4", home=home)
        gcs = ("127.0.0.1", port_base if shared else port_base + i)
        fakes.append(await FakeUdpVehicle([ap], gcs, telemetry_hz=5.0).start())
    loop = asyncio.get_running_loop()
    queue: asyncio.Queue = asyncio.Queue()
    threading.Thread(target=_stdin_commands, args=(loop, queue), daemon=True).start()
    print("READY", flush=True)
    window = None
    window_s = float("nan")
    frozen = None
    while (command := await queue.get()) != "STOP":
        if command == "MARK":
            for f in fakes:
                f.autopilots[0].setpoint_times.clear()
                f.autopilots[0].setpoints.clear()
            window = time.perf_counter()
        elif command == "END" and window is not None:
            window_s = time.perf_counter() - window
            frozen = [list(f.autopilots[0].setpoint_times) for f in fakes]
    if frozen is None:
        frozen = [list(f.autopilots[0].setpoint_times) for f in fakes]
    per_vehicle = []
    for recorded in frozen:
        times = np.array(recorded)
        intervals = np.diff(times)
        per_vehicle.append({
            "count": int(times.size),
            "p50_s": float(np.percentile(intervals, 50)) if intervals.size else None,
            "p99_s": float(np.percentile(intervals, 99)) if intervals.size else None,
            "max_s": float(intervals.max()) if intervals.size else None,
        })
    print("STATS " + json.dumps({"window_s": window_s, "vehicles": per_vehicle}), flush=True)
    for f in fakes:
        await f.stop()


# ------------------------------------------------------------------------------ coordinator
async def run_swarmseek(n: int, port_base: int, shared: bool, rate_hz: float, window_cb, extra_load=None,
                        polled: bool = False) -> dict:
    """Connect ``n`` vehicles with mission.link.endpoint/vehicle and stream setpoints at ``rate_hz``.

    ``window_cb`` is an async callable run while streaming (it opens and closes the measurement
    window and returns its measurements); ``extra_load(vehicles, streamer, clock)`` optional.
    """
    from mission.core.clock import WallClock
    from mission.link.endpoint import MavEndpoint
    from mission.link.poller import UdpPoller
    from mission.vehicle.streamer import SetpointStreamer
    from mission.vehicle.vehicle_link import DEFAULT_RATES_HZ, VehicleLink

    clock = WallClock()
    poller = UdpPoller() if polled else None
    if shared:
        endpoints = [await MavEndpoint.open(f"udpin:127.0.0.1:{port_base}", clock=clock, poller=poller)]
        ep_of = [endpoints[0]] * n
    else:
        endpoints = [await MavEndpoint.open(f"udpin:127.0.0.1:{port_base + i}", clock=clock, poller=poller)
                     for i in range(n)]
        ep_of = endpoints
    vehicles = list(await asyncio.gather(*(
        VehicleLink.create(ep_of[i], i + 1, clock=clock, mission_origin=ORIGIN, heartbeat_timeout_s=60.0)
        for i in range(n))))
    await asyncio.gather(*(v.set_message_rates(DEFAULT_RATES_HZ, strict=False) for v in vehicles))
    await asyncio.gather(*(v.wait_home(60.0) for v in vehicles))
    streamer = SetpointStreamer(vehicles, rate_hz=rate_hz, clock=clock)
    rng = np.random.default_rng(0)
    for v in vehicles:
        streamer.set_target(v.sysid, v.home_enu_m() + [0.0, 0.0, 10.0])
    if extra_load is None:  # with the seek load, its safety gate sends (as in a mission)
        await streamer.start()

    async def seek_like_updates():
        while True:   # the formation moves once a second, as a seek loop would
            await clock.sleep(1.0)
            shift = rng.normal(size=3)
            for v in vehicles:
                streamer.set_target(v.sysid, np.asarray(streamer.target(v.sysid)) + shift)

    tasks = [asyncio.ensure_future(seek_like_updates())]
    if extra_load is not None:
        tasks.append(asyncio.ensure_future(extra_load(vehicles, streamer, clock)))
    try:
        result = await window_cb()
    finally:
        for t in tasks:
            t.cancel()
        await streamer.stop()
    result["frames_in"] = sum(ep.counters["frames_in"] for ep in endpoints)
    result["bad_frames"] = sum(ep.counters["bad_crc"] + ep.counters["malformed"] for ep in endpoints)
    for ep in endpoints:
        await ep.close()
    if poller is not None:
        await poller.close()
    return result


async def run_bare(n: int, port_base: int, shared: bool, rate_hz: float, window_cb) -> dict:
    """Pack and send setpoints with pymavlink from one socket; vehicle addresses learnt first."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    loop = asyncio.get_running_loop()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", port_base))
    sock.setblocking(False)
    addresses: dict = {}
    parser = mavlink.MAVLink(None)
    deadline = time.monotonic() + 60.0
    while len(addresses) < n and time.monotonic() < deadline:     # learn who is where, then stop reading
        data, addr = await loop.sock_recvfrom(sock, 4096)
        for msg in parser.parse_buffer(data) or ():
            addresses[msg.get_srcSystem()] = addr
    encoder = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)

    async def stream():
        period_s = 1.0 / rate_hz
        next_s = time.perf_counter()
        while True:
            for sysid, addr in addresses.items():
                msg = mavlink.MAVLink_set_position_target_local_ned_message(
                    0, sysid, 1, mavlink.MAV_FRAME_LOCAL_NED, 0xDF8, 1.0, 2.0, -10.0, 0, 0, 0, 0, 0, 0, 0, 0)
                try:
                    sock.sendto(msg.pack(encoder), addr)
                except BlockingIOError:
                    pass
            next_s += period_s
            await asyncio.sleep(max(0.0, next_s - time.perf_counter()))

    task = asyncio.ensure_future(stream())
    try:
        return await window_cb()
    finally:
        task.cancel()
        sock.close()


async def run_mavsdk(n: int, port_base: int, shared: bool, rate_hz: float, window_cb) -> dict:
    """The same load with MAVSDK 4.x (which streams offboard setpoints at its own 20 Hz)."""
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.offboard import OffboardAsync, PositionNedYaw
    from mavsdk.logging import log_subscribe

    log_subscribe(lambda *args: True)
    mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    try:
        if shared:
            await mavsdk.add_any_connection(f"udpin://127.0.0.1:{port_base}")
        else:
            for i in range(n):
                await mavsdk.add_any_connection(f"udpin://127.0.0.1:{port_base + i}")
        deadline = time.monotonic() + 120.0
        while await mavsdk.system_count() < n:
            if time.monotonic() > deadline:
                raise RuntimeError(f"MAVSDK saw {await mavsdk.system_count()} of {n} systems")
            await asyncio.sleep(0.2)
        systems = await mavsdk.get_systems()
        offboards = [OffboardAsync(s) for s in systems]
        for off in offboards:
            await off.set_position_ned(PositionNedYaw(0.0, 0.0, -10.0, 0.0))
        # MAVSDK stops streaming after a few seconds unless offboard mode is started
        await asyncio.gather(*(off.start() for off in offboards))
        result = await window_cb()
        result["systems"] = len(systems)
        return result
    finally:
        mavsdk.destroy()


def _start_profile(path: str | None):
    """A running ``cProfile.Profile`` when ``path`` is given (the window's CPU figure then includes its overhead)."""
    if not path:
        return None
    import cProfile

    prof = cProfile.Profile(time.process_time)   # CPU time: a loaded machine's preemptions are not counted
    prof.enable()
    return prof


def _stop_profile(prof, path: str | None) -> None:
    """Stop ``prof`` and write its stats to ``path`` (read with ``python -m pstats PATH``)."""
    if prof is not None:
        prof.disable()
        prof.dump_stats(path)


def _load_callable(spec: str | None):
    if not spec:
        return None
    import importlib

    module_name, _, name = spec.partition(":")
    return getattr(importlib.import_module(module_name), name)


async def _coordinator_main(stack: str, n: int, port_base: int, rate_hz: float, duration_s: float, warmup_s: float,
                            extra_load: str | None = None, profile: str | None = None):
    loop = asyncio.get_running_loop()
    queue: asyncio.Queue = asyncio.Queue()
    threading.Thread(target=_stdin_commands, args=(loop, queue), daemon=True).start()
    rss0 = _rss_mb()

    async def window():
        await asyncio.sleep(warmup_s)
        print("MARK", flush=True)          # the driver forwards it to the vehicles
        assert await queue.get() == "GO"
        prof = _start_profile(profile)
        wall0, cpu0, t0 = time.perf_counter(), time.process_time(), os.times()
        await asyncio.sleep(duration_s)
        wall1, cpu1, t1 = time.perf_counter(), time.process_time(), os.times()
        _stop_profile(prof, profile)
        print("END", flush=True)
        return {"cpu_cores": (cpu1 - cpu0) / (wall1 - wall0), "rss_mb": _rss_mb(), "rss0_mb": rss0,
                "sys_cores": (t1.system - t0.system) / (wall1 - wall0)}

    shared = stack.endswith("-shared")
    if stack == "bare-pymavlink":
        result = await run_bare(n, port_base, True, rate_hz, window)
    elif stack.startswith("swarmseek"):
        result = await run_swarmseek(n, port_base, "-shared" in stack, rate_hz, window,
                                     extra_load=_load_callable(extra_load), polled=stack.endswith("-polled"))
    else:
        result = await run_mavsdk(n, port_base, shared, rate_hz, window)
    print("RESULT " + json.dumps(result), flush=True)


# ----------------------------------------------------------------------------------- driver
def _spawn(args: list[str]) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, os.path.abspath(__file__)] + args, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, bufsize=1)
    proc.lines = queue_mod.Queue()
    proc.err_tail = collections.deque(maxlen=3)   # the end of a traceback, for the FAILED row

    def pump_out():
        for line in proc.stdout:
            proc.lines.put(line)
        proc.lines.put(None)

    def pump_err():
        for line in proc.stderr:
            if line.strip():
                proc.err_tail.append(line.strip())
    threading.Thread(target=pump_out, daemon=True).start()
    threading.Thread(target=pump_err, daemon=True).start()
    return proc


def _expect(proc, prefix: str, timeout_s: float) -> str:
    """The rest of the child's next stdout line starting with ``prefix`` (others are skipped)."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            line = proc.lines.get(timeout=max(0.01, deadline - time.monotonic()))
        except queue_mod.Empty:
            raise RuntimeError(f"timed out after {timeout_s:g} s waiting for {prefix.strip()!r}") from None
        if line is None:
            time.sleep(0.2)   # let the stderr pump catch the end of the traceback
            tail = proc.err_tail[-1] if proc.err_tail else "no message"
            raise RuntimeError(f"process exited while waiting for {prefix.strip()!r}: {tail}")
        if line.startswith(prefix):
            return line[len(prefix):].strip()


def run_case(stack: str, n: int, rate_hz: float, duration_s: float, warmup_s: float,
             extra_load: str | None = None, profile: str | None = None) -> dict:
    """One benchmark case in fresh processes; returns the combined measurements."""
    port_base = free_port_block(n + 1)  # UDP, below the ephemeral range
    shared = "-shared" in stack or stack == "bare-pymavlink"
    vehicles = _spawn(["--role", "vehicles", "--n", str(n), "--port-base", str(port_base)]
                      + (["--shared"] if shared else []))
    coordinator = None
    try:
        _expect(vehicles, "READY", 60)
        coordinator = _spawn(["--role", "coordinator", "--stack", stack, "--n", str(n), "--port-base",
                              str(port_base), "--rate", str(rate_hz), "--duration", str(duration_s),
                              "--warmup", str(warmup_s)] + (["--extra-load", extra_load] if extra_load else [])
                             + (["--profile", profile] if profile else []))
        _expect(coordinator, "MARK", 180)
        vehicles.stdin.write("MARK\n")
        coordinator.stdin.write("GO\n")
        _expect(coordinator, "END", duration_s + 60)
        vehicles.stdin.write("END\n")
        coord = json.loads(_expect(coordinator, "RESULT", 120))
        vehicles.stdin.write("STOP\n")
        veh = json.loads(_expect(vehicles, "STATS", 60))
    finally:
        for proc in (coordinator, vehicles):
            if proc is not None:
                try:
                    proc.stdin.close()
                except OSError:
                    pass
                try:
                    proc.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    proc.kill()
    per = veh["vehicles"]
    window_s = veh["window_s"]
    p50 = [v["p50_s"] for v in per if v["p50_s"] is not None]
    p99 = [v["p99_s"] for v in per if v["p99_s"] is not None]
    rates = [v["count"] / window_s for v in per]
    return {
        "stack": stack, "n": n,
        "rate_hz_mean": float(np.mean(rates)), "rate_hz_min": float(np.min(rates)),
        "p50_ms_median": 1e3 * float(np.median(p50)) if p50 else float("nan"),
        "p99_ms_median": 1e3 * float(np.median(p99)) if p99 else float("nan"),
        "p99_ms_worst": 1e3 * float(np.max(p99)) if p99 else float("nan"),
        "starved": sum(1 for v in per if v["count"] == 0),
        "cpu_cores": coord["cpu_cores"], "sys_cores": coord["sys_cores"], "rss_mb": coord["rss_mb"],
    }


def _table(rows: list[dict]) -> str:
    head = (f"{'stack':<24}{'N':>5}{'rate Hz':>9}{'min Hz':>8}{'p50 ms':>8}{'p99 ms':>8}{'worst p99':>10}"
            f"{'starved':>8}{'CPU cores':>10}{'(kernel)':>9}{'RSS MB':>8}")
    lines = [head, "-" * len(head)]
    for r in rows:
        if "error" in r:
            lines.append(f"{r['stack']:<24}{r['n']:>5}  FAILED: {r['error']}")
            continue
        lines.append(f"{r['stack']:<24}{r['n']:>5}{r['rate_hz_mean']:>9.2f}{r['rate_hz_min']:>8.2f}"
                     f"{r['p50_ms_median']:>8.1f}{r['p99_ms_median']:>8.1f}{r['p99_ms_worst']:>10.1f}"
                     f"{r['starved']:>8d}{r['cpu_cores']:>10.3f}{r['sys_cores']:>9.3f}{r['rss_mb']:>8.0f}")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--role", choices=("driver", "vehicles", "coordinator"), default="driver")
    parser.add_argument("--n", type=int, nargs="+", default=[8, 32, 100, 200])
    parser.add_argument("--stacks", nargs="+", choices=STACKS, default=list(STACKS))
    parser.add_argument("--stack", choices=STACKS)
    parser.add_argument("--rate", type=float, default=20.0, help="setpoint rate per vehicle (Hz)")
    parser.add_argument("--duration", type=float, default=10.0, help="measurement window (s)")
    parser.add_argument("--warmup", type=float, default=2.0, help="streaming before the window (s)")
    parser.add_argument("--port-base", type=int)
    parser.add_argument("--shared", action="store_true")
    parser.add_argument("--json", action="store_true", help="also print the rows as JSON")
    parser.add_argument("--extra-load", metavar="MODULE:FUNCTION",
                        help="async extra_load(vehicles, streamer, clock) run during the window (swarmseek stacks)")
    parser.add_argument("--profile", metavar="PATH",
                        help="cProfile the coordinator over the window into PATH (one N and stack; "
                             "read with python -m pstats PATH)")
    args = parser.parse_args(argv)
    if args.role == "vehicles":
        asyncio.run(_vehicles_main(args.n[0], args.port_base, args.shared))
        return 0
    if args.role == "coordinator":
        asyncio.run(_coordinator_main(args.stack, args.n[0], args.port_base, args.rate, args.duration, args.warmup,
                                      args.extra_load, args.profile))
        return 0
    rows = []
    for n in args.n:
        for stack in args.stacks:
            try:
                row = run_case(stack, n, args.rate, args.duration, args.warmup, args.extra_load,
                               profile=os.path.abspath(args.profile) if args.profile else None)
            except Exception as exc:  # one failed case (e.g. MAVSDK collapsing) still prints the others
                row = {"stack": stack, "n": n, "error": str(exc)[:200]}
            rows.append(row)
            print(_table(rows[-1:]).splitlines()[-1], file=sys.stderr, flush=True)
    print(f"setpoints at {args.rate:g} Hz per vehicle, {args.duration:g} s window; intervals measured at the "
          f"vehicles (separate process); CPU = coordinator process CPU time / wall time")
    print(_table(rows))
    if args.json:
        print(json.dumps(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
