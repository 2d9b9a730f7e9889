"""How one real SITL instance is started: command line, environment, ports, home, parameters.

One :class:`InstanceSpec` per instance, built by :func:`instance_specs` for a flavour:

* ``px4`` (PX4 SITL with the SIH quadrotor): instance ``i`` (0..9) and port offset ``K`` give
  system id ``i + 1``, the API/offboard link ``udpin:127.0.0.1:14540+i+K`` (the ground station),
  the 4 kB/s onboard link ``udpin:127.0.0.1:14030+i+K`` (a ``swarmseek sensor``) and the GCS link
  to ``127.0.0.1:14550+K`` shared by every instance (the launcher's readiness check listens there);
  ``PX4_PORT_OFFSET=K``; home through ``PX4_HOME_LAT/LON/ALT``; parameters through
  ``PX4_PARAM_<NAME>``; ``PX4_SIM_SPEED_FACTOR`` when the speed-up is not 1.
* ``ardupilot`` (ArduCopter SITL, built-in ``+`` physics): instance ``k`` and base port
  ``B = 5760 + K`` give system id ``k + 1`` and MAVLink on TCP ``B+10k`` (SERIAL0, the ground
  station), ``B+2+10k`` (SERIAL1, a sensor) and ``B+3+10k`` (SERIAL2, the readiness check);
  parameters through an extra defaults file; ``--speedup``.

:func:`pick_layout` chooses a first instance number and a port offset whose ports (and, for
PX4, host-wide instance lock files ``/tmp/px4_lock-<i>`` and a per-user lease of the numbers
it handed out) are free, so that concurrent fleets never collide.
"""
from __future__ import annotations

import fcntl
import os
import random
import socket
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from formation.geodesy import enu_to_geodetic
from mission.sim.leases import take_leases
from mission.sim.sitl_settings import SitlSetupError

__all__ = ["InstanceSpec", "DEFAULT_HOMES", "DEFAULT_PARAMS", "PX4_API_STREAMS_OFF", "PX4_MAX_INSTANCES", "instance_specs",
           "pick_layout", "px4_instance_free", "spread_homes"]

#: flavour -> default home of the fleet's first vehicle (lat_deg, lon_deg, alt_m)
DEFAULT_HOMES = {"px4": (47.397742, 8.545594, 489.4), "ardupilot": (-35.363261, 149.165230, 584.0)}
#: parameters set on every instance: GCS-loss failsafe on (land), flight logs off. PX4's offboard
#: loss action stays its default (hold, re-engaged by the coordinator's watchdog): a stall of the
#: ground station longer than COM_OF_LOSS_T (1 s) on a busy host must not land the fleet; the
#: data-link loss (COM_DL_LOSS_T, 10 s: the ground station is gone) lands it.
DEFAULT_PARAMS = {
    "px4": {"NAV_DLL_ACT": 3, "SDLOG_MODE": -1},
    "ardupilot": {"FS_GCS_ENABLE": 5, "LOG_BACKEND_TYPE": 0},
}
#: PX4 instances 10 and above share API port 14549: at most 10 per host
PX4_MAX_INSTANCES = 10
#: how long a PX4 instance number handed out by :func:`pick_layout` stays reserved against its other
#: calls, s (PX4 takes its own lock file within a second of its start)
PX4_INSTANCE_LEASE_S = 30.0
#: PX4's API link is an "onboard" mode link: ~400 messages/s at real time (x the speed-up). A
#: ground station uses none of these; the launcher turns them off once the instance is ready
#: (``mavlink stream -r 0``), so a sped-up fleet sends no more than a real-time one.
PX4_API_STREAMS_OFF = ("ATTITUDE", "HIGHRES_IMU", "ATTITUDE_QUATERNION", "ODOMETRY", "ALTITUDE",
                       "DISTANCE_SENSOR", "ATTITUDE_TARGET", "SERVO_OUTPUT_RAW_0", "VFR_HUD")
_PX4_LOCAL_PORTS = (14580, 14540, 14280, 14030, 13030, 13280, 18570, 19450, 19410)
_AP_BASE_PORT = 5760


@dataclass(frozen=True)
class InstanceSpec:
    """Everything needed to start and use one SITL instance.

    Attributes
    ----------
    index : int
        Position in the fleet (0..n-1).
    instance : int
        SITL instance number (``-i`` / ``-I``).
    sysid : int
        MAVLink system id.
    home : tuple of float
        Home ``(lat_deg, lon_deg, alt_m)``.
    connection : str
        The ground station's connection string (a plan's ``connection``).
    sensor_connection : str
        A second link for ``swarmseek sensor --connect``.
    ready_connection : str
        The link the launcher watches until the instance is ready.
    argv : list of str
        Command line.
    env : dict
        Complete environment of the process.
    work_dir : Path
        Working directory (parameters, logs, ``sitl.log``).
    setup_commands : list of list of str
        Commands run once the instance is ready (PX4: streams of the API link turned off).
    """

    index: int
    instance: int
    sysid: int
    home: tuple[float, float, float]
    connection: str
    sensor_connection: str
    ready_connection: str
    argv: list[str] = field(repr=False)
    env: dict = field(repr=False)
    work_dir: Path
    setup_commands: list = field(default_factory=list, repr=False)


def spread_homes(home: tuple[float, float, float], n: int, spacing_m: float) -> list[tuple[float, float, float]]:
    """``n`` homes ``spacing_m`` apart along a line toward east, the first at ``home`` (the same
    latitude and altitude; the longitudes from :func:`formation.geodesy.enu_to_geodetic`)."""
    lat, lon, alt = home
    east_enu_m = np.zeros((n, 3))
    east_enu_m[:, 0] = spacing_m * np.arange(n)
    lons_deg = np.atleast_1d(enu_to_geodetic(east_enu_m, home)[1])
    return [(lat, round(float(lon_deg), 7), alt) for lon_deg in lons_deg]


def px4_instance_free(instance: int) -> bool:
    """True when no running PX4 holds the host-wide lock file of ``instance``."""
    path = Path(f"/tmp/px4_lock-{instance}")
    if not path.exists():
        return True
    try:
        with open(path, "rb+") as fh:
            fcntl.lockf(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            fcntl.lockf(fh, fcntl.LOCK_UN)
        return True
    except OSError:
        return False


def _ports_free(udp: list[int], tcp: list[int]) -> bool:
    socks = []
    try:
        for kind, ports in ((socket.SOCK_DGRAM, udp), (socket.SOCK_STREAM, tcp)):
            for port in ports:
                if not 0 < port < 65536:
                    return False
                s = socket.socket(socket.AF_INET, kind)
                socks.append(s)
                s.bind(("0.0.0.0", port))
        return True
    except OSError:
        return False
    finally:
        for s in socks:
            s.close()


def _layout_ports(flavour: str, first: int, n: int, offset: int) -> tuple[list[int], list[int]]:
    if flavour == "px4":
        udp = [p + first + j + offset for j in range(n) for p in _PX4_LOCAL_PORTS] + [14550 + offset]
        return udp, []
    base = _AP_BASE_PORT + offset
    tcp = [base + 10 * (first + j) + d for j in range(n) for d in (0, 1, 2, 3)]
    udp = [5501 + 10 * (first + j) + d for j in range(n) for d in (0, 1, 2, 3)]
    return udp, tcp


def pick_layout(flavour: str, n: int, *, tries: int = 200, rng: random.Random | None = None,
                lease_dir: str | Path | None = None, lease_s: float = PX4_INSTANCE_LEASE_S) -> tuple[int, int]:
    """A free ``(first_instance, port_offset)`` for ``n`` instances of ``flavour``.

    PX4: the instance numbers handed out are leased for ``lease_s`` seconds in a per-user file
    (``lease_dir``, default :func:`px4_lease_dir`, read and written under an exclusive ``flock``):
    PX4 takes its host-wide lock file ``/tmp/px4_lock-<i>`` only once started, and two fleets picked
    at once (two pytest-xdist workers) were handed the same numbers ("PX4 server already running for
    instance 1").

    Raises
    ------
    SitlSetupError
        No free layout found (for PX4 also: more than 10 instances).
    """
    rng = rng or random.Random()
    if flavour == "px4" and n > PX4_MAX_INSTANCES:
        raise SitlSetupError(f"PX4 SITL runs at most {PX4_MAX_INSTANCES} instances per host, asked for {n}")
    if flavour == "px4":
        return _pick_px4_layout(n, tries, rng, Path(lease_dir) if lease_dir is not None else px4_lease_dir(),
                                lease_s)
    for _ in range(tries):
        first = rng.randrange(0, 100)
        offset = rng.randrange(0, 40000 - 10 * (first + n))
        if _ports_free(*_layout_ports(flavour, first, n, offset)):
            return first, offset
    raise SitlSetupError(f"no free instance numbers and ports for {n} {flavour} SITL instances")


def px4_lease_dir() -> Path:
    """The directory of :func:`pick_layout`'s PX4 instance leases: one per user, in the temp directory."""
    return Path(tempfile.gettempdir()) / f"swarmseek-px4-{os.getuid()}"


def _pick_px4_layout(n: int, tries: int, rng: random.Random, directory: Path, lease_s: float) -> tuple[int, int]:
    """The lowest block of ``n`` PX4 instance numbers neither locked by a running PX4 nor leased, and a
    random port offset whose ports are free; the block leased for ``lease_s`` s (see :func:`pick_layout`)."""
    def choose(leases: dict[int, float]) -> tuple[tuple[int, int], list[int]]:
        free = [i not in leases and px4_instance_free(i) for i in range(PX4_MAX_INSTANCES)]
        firsts = [f for f in range(PX4_MAX_INSTANCES - n + 1) if all(free[f:f + n])]
        for _ in range(tries if firsts else 0):
            offset = rng.randrange(1000, 45000)  # the lowest block: fleets pack, leaving room for others
            if _ports_free(*_layout_ports("px4", firsts[0], n, offset)):
                return (firsts[0], offset), [firsts[0] + j for j in range(n)]
        raise SitlSetupError(f"no free instance numbers and ports for {n} px4 SITL instances")

    return take_leases(directory / "instances.json", choose, lease_s)


def _px4_bin_dir(sitl_dir: Path, run_dir: Path) -> Path:
    """A private ``bin/``: ``px4`` and one ``px4-<module>`` link per module command.

    PX4's start-up script calls modules through ``px4-<module>`` links found on ``PATH`` next to
    the binary; a copied install may hold them as plain files. Links made here always work.
    """
    src = sitl_dir / "bin"
    dst = run_dir / "px4-bin"
    dst.mkdir(parents=True, exist_ok=True)
    for name in os.listdir(src):
        link = dst / name
        if link.is_symlink() or link.exists():
            continue
        if name == "px4" or not name.startswith("px4-") or name.endswith(".sh"):
            link.symlink_to(src / name)
        else:
            link.symlink_to("px4")
    return dst


def _base_env(prefix: str) -> dict:
    return {k: v for k, v in os.environ.items() if not k.startswith(prefix)}


def _px4_spec(j: int, inst: int, home, cfg, sitl_dir: Path, run_dir: Path, bin_dir: Path) -> InstanceSpec:
    off = cfg.port_offset
    wd = run_dir / f"inst{inst}"
    env = _base_env("PX4_")
    env.update(PX4_SYS_AUTOSTART="10040", PX4_SIMULATOR="sihsim", PX4_SIM_MODEL="sihsim_quadx",
               HEADLESS="1", PX4_PORT_OFFSET=str(off), PX4_HOME_LAT=f"{home[0]:.7f}",
               PX4_HOME_LON=f"{home[1]:.7f}", PX4_HOME_ALT=f"{home[2]:.2f}")
    for name, value in cfg.all_params().items():
        env[f"PX4_PARAM_{name}"] = str(value)
    if cfg.speedup != 1.0:
        env["PX4_SIM_SPEED_FACTOR"] = f"{cfg.speedup:g}"
    argv = [str(bin_dir / "px4"), "-i", str(inst), "-d", "-w", str(wd), str(sitl_dir / "etc")]
    api_local = str(14580 + inst + off)
    setup = [[str(bin_dir / "px4-mavlink"), "--instance", str(inst), "stream", "-u", api_local, "-s", name, "-r", "0"]
             for name in PX4_API_STREAMS_OFF]
    return InstanceSpec(index=j, instance=inst, sysid=inst + 1, home=home,
                        connection=f"udpin:127.0.0.1:{14540 + inst + off}",
                        sensor_connection=f"udpin:127.0.0.1:{14030 + inst + off}",
                        ready_connection=f"udpin:127.0.0.1:{14550 + off}",
                        argv=argv, env=env, work_dir=wd, setup_commands=setup)


def _ap_spec(j: int, inst: int, home, cfg, sitl_dir: Path, run_dir: Path, param_file: Path) -> InstanceSpec:
    port = _AP_BASE_PORT + cfg.port_offset + 10 * inst
    wd = run_dir / f"inst{inst}"
    argv = [str(sitl_dir / "bin" / "arducopter"), "--model", "+", "--speedup", f"{cfg.speedup:g}",
            "--base-port", str(port), f"-I{inst}", "--sysid", str(inst + 1), "--serial0", "tcp:0",
            "--defaults", f"{sitl_dir / 'copter.parm'},{param_file}",
            "--home", f"{home[0]:.7f},{home[1]:.7f},{home[2]:.2f},0"]
    return InstanceSpec(index=j, instance=inst, sysid=inst + 1, home=home,
                        connection=f"tcp:127.0.0.1:{port}", sensor_connection=f"tcp:127.0.0.1:{port + 2}",
                        ready_connection=f"tcp:127.0.0.1:{port + 3}",
                        argv=argv, env=_base_env("AP_SITL_"), work_dir=wd)


def instance_specs(cfg, sitl_dir: Path, run_dir: Path) -> list[InstanceSpec]:
    """One :class:`InstanceSpec` per vehicle of the fleet configuration ``cfg``.

    Creates the working directories (and, for ArduPilot, the parameter file; for PX4, the
    private ``bin/`` of module links) under ``run_dir``.
    """
    homes = spread_homes(cfg.home or DEFAULT_HOMES[cfg.flavour], cfg.n, cfg.spacing_m)
    specs = []
    run_dir.mkdir(parents=True, exist_ok=True)
    if cfg.flavour == "px4":
        if cfg.first_instance + cfg.n > PX4_MAX_INSTANCES:
            raise SitlSetupError(f"PX4 instances {cfg.first_instance}..{cfg.first_instance + cfg.n - 1}: "
                                 f"instance numbers must stay below {PX4_MAX_INSTANCES} (they share ports above)")
        bin_dir = _px4_bin_dir(sitl_dir, run_dir)
        for j in range(cfg.n):
            specs.append(_px4_spec(j, cfg.first_instance + j, homes[j], cfg, sitl_dir, run_dir, bin_dir))
    else:
        param_file = run_dir / "swarmseek.parm"
        param_file.write_text("".join(f"{k} {v}\n" for k, v in cfg.all_params().items()))
        for j in range(cfg.n):
            specs.append(_ap_spec(j, cfg.first_instance + j, homes[j], cfg, sitl_dir, run_dir, param_file))
    for spec in specs:
        spec.work_dir.mkdir(parents=True, exist_ok=True)
    return specs
