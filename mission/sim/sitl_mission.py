"""A whole dry-run mission against a running SITL fleet: one ``swarmseek sensor`` per vehicle and
``swarmseek fly``, each a subprocess, exactly as a field team runs them; with CPU accounting.

Used by the real-SITL end-to-end tests and ``benchmarks/bench_sitl.py``. Blocking code.
"""
from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from mission.sim.sitl_procs import stop_groups

__all__ = ["SitlMissionResult", "fly_sitl_mission", "process_cpu_s", "sensor_argv"]


@dataclass
class SitlMissionResult:
    """What a flown SITL mission left: exit status, output, summary record and CPU times.

    Attributes
    ----------
    returncode : int
        Exit status of ``swarmseek fly``.
    stdout, stderr : str
        Its output.
    summary : dict or None
        The mission log's ``summary`` record.
    wall_s : float
        Wall time of ``swarmseek fly``.
    cpu_s : dict
        ``"fly"``: CPU seconds of the ground station; ``"sensors"``: of all sensors;
        ``"sitl"``: system id -> CPU seconds of its SITL process during the flight.
    """

    returncode: int
    stdout: str
    stderr: str
    summary: dict | None
    wall_s: float
    cpu_s: dict = field(default_factory=dict)


def process_cpu_s(pid: int) -> float:
    """User + system CPU seconds of a running process (all its threads), from ``/proc``."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def sensor_argv(vehicle, origin, source, *, fleet: str, zenoh: str, noise: float, rate_hz: float,
                field: str = "sigma2", field_args: Sequence[str] = ()) -> list[str]:
    """The ``swarmseek sensor`` command line of one vehicle's virtual sensor.

    Parameters
    ----------
    vehicle : mission.sim.sitl_fleet.SitlVehicle
        Its ``sensor_connection`` and ``sysid`` (also the sensor's noise seed).
    origin : tuple of float
        ``(lat_deg, lon_deg, alt_m)`` of the field frame (the plan's origin).
    source : tuple of float
        The field's source (plumes: the release point), mission ENU metres.
    fleet, zenoh : str
        The zenoh fleet name and the coordinator's endpoint.
    noise, rate_hz : float
        The sensor's noise standard deviation and readings per second.
    field : str
        ``swarmseek sensor --field``: ``sigma1``, ``sigma2`` (default), ``plume``, ``intermittent``.
    field_args : sequence of str
        Further field flags, e.g. ``("--wind-from", "270", "--wind-speed", "2")``.
    """
    if isinstance(field_args, str) or not all(isinstance(a, str) for a in field_args):
        raise TypeError(f"field_args must be a sequence of strings, got {field_args!r}")
    return [sys.executable, "-m", "mission", "sensor", "--connect", vehicle.sensor_connection,
            "--sysid", str(vehicle.sysid), "--fleet", fleet, "--field", field, *field_args,
            f"--source={','.join(f'{x:g}' for x in source)}",
            f"--origin={origin[0]:.7f},{origin[1]:.7f},{origin[2]:g}", "--noise", f"{noise:g}",
            "--seed", str(vehicle.sysid), "--rate", f"{rate_hz:g}", "--zenoh-connect", zenoh, "--quiet"]


def _wait_rusage(proc: subprocess.Popen, timeout_s: float) -> float:
    """Wait for ``proc`` (killing its group after ``timeout_s``); its CPU seconds."""
    deadline = time.monotonic() + timeout_s
    while True:
        pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
        if pid:
            proc.returncode = os.waitstatus_to_exitcode(status)
            return usage.ru_utime + usage.ru_stime
        if time.monotonic() > deadline:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
        time.sleep(0.1)


def fly_sitl_mission(fleet, plan: Path, log_dir: Path, source, *, fleet_name: str = "sitl",
                     zenoh: str = "tcp/127.0.0.1:7447", noise: float = 0.005, timeout_s: float = 300.0,
                     env: dict | None = None, field: str = "sigma2",
                     field_args: Sequence[str] = ()) -> SitlMissionResult:
    """Start the sensors, fly the plan, stop the sensors; return what happened.

    Parameters
    ----------
    fleet : mission.sim.sitl_fleet.SitlFleet
        A running fleet; ``plan`` was written for it.
    plan, log_dir : Path
        The plan file and ``swarmseek fly --log-dir``.
    source : tuple of float
        The simulated field's source (plumes: the release point), mission ENU metres.
    zenoh : str
        The endpoint the plan's coordinator listens on (the sensors connect to it).
    timeout_s : float
        ``fly`` is killed after this long (its return code is then negative).
    field, field_args
        The sensors' field and further field flags (:func:`sensor_argv`; default ``sigma2``).
    """
    rate_hz = min(10.0 * fleet.config.speedup, 40.0)
    sensors = []
    for v in fleet.vehicles:
        with open(log_dir.parent / f"{log_dir.name}-sensor-{v.sysid}.log", "wb") as err:
            sensors.append(subprocess.Popen(
                sensor_argv(v, fleet.origin, source, fleet=fleet_name, zenoh=zenoh, noise=noise, rate_hz=rate_hz,
                            field=field, field_args=field_args),
                env=env, stdout=err, stderr=subprocess.STDOUT, start_new_session=True))
    sitl_before = {v.sysid: process_cpu_s(v.pid) for v in fleet.vehicles}
    out_path, err_path = log_dir.with_suffix(".stdout"), log_dir.with_suffix(".stderr")
    started = time.monotonic()
    try:
        with open(out_path, "wb") as out, open(err_path, "wb") as err:
            fly = subprocess.Popen([sys.executable, "-m", "mission", "fly", "--plan", str(plan),
                                    "--log-dir", str(log_dir)], env=env, stdout=out, stderr=err,
                                   start_new_session=True)
            fly_cpu = _wait_rusage(fly, timeout_s)
        wall = time.monotonic() - started
        sitl_cpu = {v.sysid: round(process_cpu_s(v.pid) - sitl_before[v.sysid], 2) for v in fleet.vehicles}
        sensor_cpu = sum(process_cpu_s(p.pid) for p in sensors if p.poll() is None)
    finally:
        stop_groups(sensors)
    summary = None
    log = log_dir / "mission.jsonl"
    if log.is_file():
        for line in log.read_text().splitlines():
            record = json.loads(line)
            if record.get("type") == "summary":
                summary = record
    return SitlMissionResult(returncode=fly.returncode, stdout=out_path.read_text(errors="replace"),
                             stderr=err_path.read_text(errors="replace"), summary=summary, wall_s=wall,
                             cpu_s={"fly": round(fly_cpu, 2), "sensors": round(sensor_cpu, 2), "sitl": sitl_cpu})
