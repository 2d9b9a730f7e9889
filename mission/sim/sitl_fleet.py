"""A fleet of real SITL autopilots (PX4 SIH or ArduCopter) for tests, dry runs and ``swarmseek sitl``.

API (stable)::

    from mission.sim.sitl_fleet import SitlFleetConfig, SitlFleet

    cfg = SitlFleetConfig(flavour="px4", n=4)            # sitl_dir from SWARMSEEK_PX4_SITL
    with SitlFleet(cfg) as fleet:                           # starts, waits until ready
        fleet.vehicles[0].connection                        # "udpin:127.0.0.1:..." for a plan
        fleet.vehicles[0].sensor_connection                 # for `swarmseek sensor --connect`
        fleet.vehicles[0].sysid, fleet.origin               # system id; plan origin (lat, lon, alt)
        fleet.write_plan("plan.toml", zenoh_port=7447)      # a ready-to-fly plan (validated)
    # every process group stopped, lock files removed, run dir deleted (unless kept)

:meth:`SitlFleetConfig.free` picks instance numbers and a port offset that no other fleet on
the host uses. Each instance runs in its own process group (session) and receives SIGTERM
when the launching thread dies (``PR_SET_PDEATHSIG``), so a killed launcher leaves no orphans;
:func:`sigterm_as_interrupt` turns SIGTERM into :class:`KeyboardInterrupt` so that ``with``
blocks stop the fleet on SIGTERM as on Ctrl-C.
"""
from __future__ import annotations

import contextlib
import ctypes
import functools
import signal
import subprocess
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path

from mission.sim.sitl_launch import (
    DEFAULT_HOMES,
    DEFAULT_PARAMS,
    PX4_MAX_INSTANCES,
    InstanceSpec,
    instance_specs,
    pick_layout,
)
from mission.sim.sitl_plan import write_plan
from mission.sim.sitl_procs import cleanup_px4_files, stop_groups
from mission.sim.sitl_ready import wait_ready
from mission.sim.sitl_settings import FLAVOURS, SitlSetupError, resolve_sitl_dir

__all__ = ["SitlFleetConfig", "SitlFleet", "SitlVehicle", "sigterm_as_interrupt"]

_PR_SET_PDEATHSIG = 1
#: FS_GCS_TIMEOUT of a SITL fleet at real time (PX4's COM_DL_LOSS_T; ArduCopter's default is 5)
#: and ArduCopter's maximum (seconds)
_AP_FS_GCS_TIMEOUT_S = 10.0
_AP_FS_GCS_TIMEOUT_MAX_S = 120.0


@dataclass(frozen=True)
class SitlFleetConfig:
    """What fleet to start.

    Attributes
    ----------
    flavour : str
        ``"px4"`` (PX4 SIH) or ``"ardupilot"`` (ArduCopter).
    n : int
        Number of vehicles (PX4: ``first_instance + n <= 10``).
    sitl_dir : str or Path, optional
        The SITL folder; default: ``SWARMSEEK_PX4_SITL`` / ``SWARMSEEK_ARDUPILOT_SITL``.
    first_instance : int
        Instance number of the first vehicle (system id = instance + 1).
    port_offset : int
        PX4: ``PX4_PORT_OFFSET``; ArduPilot: base port ``5760 + port_offset``.
    spacing_m : float
        Homes this far apart toward east.
    home : tuple, optional
        ``(lat_deg, lon_deg, alt_m)`` of the first vehicle (default: the flavour's usual home).
    speedup : float
        Simulation speed-up (PX4 ``PX4_SIM_SPEED_FACTOR``, ArduPilot ``--speedup``).
    params : dict
        Extra parameters (over :data:`~mission.sim.sitl_launch.DEFAULT_PARAMS`).
    run_dir : str or Path, optional
        Working directories go here (default: a new temporary directory, deleted on stop).
    ready_timeout_s : float
        Wall seconds to wait for every instance to be ready.
    """

    flavour: str
    n: int
    sitl_dir: str | Path | None = None
    first_instance: int = 0
    port_offset: int = 0
    spacing_m: float = 4.0
    home: tuple[float, float, float] | None = None
    speedup: float = 1.0
    params: dict = field(default_factory=dict)
    run_dir: str | Path | None = None
    ready_timeout_s: float = 120.0

    def __post_init__(self):
        if self.flavour not in FLAVOURS:
            raise SitlSetupError(f"unknown SITL flavour {self.flavour!r}: expected one of {', '.join(FLAVOURS)}")
        if not isinstance(self.n, int) or self.n < 1:
            raise SitlSetupError(f"a SITL fleet has at least 1 vehicle, got {self.n!r}")
        if self.first_instance < 0 or self.port_offset < 0:
            raise SitlSetupError("first_instance and port_offset must be >= 0")
        if not self.speedup > 0 or not self.spacing_m >= 0 or not self.ready_timeout_s > 0:
            raise SitlSetupError("speedup and ready_timeout_s must be > 0, spacing_m >= 0")
        if self.flavour == "px4" and self.first_instance + self.n > PX4_MAX_INSTANCES:
            raise SitlSetupError(f"PX4 SITL: instances {self.first_instance}..{self.first_instance + self.n - 1} "
                                 f"asked for; instance numbers must stay below {PX4_MAX_INSTANCES} "
                                 f"(PX4 gives every instance from 10 on the same API port)")

    def all_params(self) -> dict:
        """The flavour's default parameters updated with :attr:`params`.

        ArduPilot: ``FS_GCS_TIMEOUT`` (simulated seconds) is 10 s times the speed-up unless given,
        as PX4's start-up script sets ``COM_DL_LOSS_T`` (ArduCopter's default is 5 s): the ground
        station's 1 Hz heartbeat is wall clock, and at speed-up 3 ArduCopter's 5 s is 1.7 wall
        seconds, which a loaded host's stall of the ground station exceeded (ArduCopter SITL
        landed two hovering vehicles, "GCS Failsafe": docs/faults.md).
        """
        scaled = {}
        if self.flavour == "ardupilot":
            scaled["FS_GCS_TIMEOUT"] = round(min(_AP_FS_GCS_TIMEOUT_S * self.speedup, _AP_FS_GCS_TIMEOUT_MAX_S), 3)
        return {**DEFAULT_PARAMS[self.flavour], **scaled, **self.params}

    def free(self) -> SitlFleetConfig:
        """This configuration with instance numbers and a port offset that are free on this host."""
        first, offset = pick_layout(self.flavour, self.n)
        return replace(self, first_instance=first, port_offset=offset)


@dataclass(frozen=True)
class SitlVehicle:
    """One running SITL vehicle: what a plan and a sensor need to reach it."""

    index: int
    instance: int
    sysid: int
    connection: str
    sensor_connection: str
    home: tuple[float, float, float]
    pid: int
    work_dir: Path


def _pdeathsig_setter():
    """A function for ``preexec_fn``: SIGTERM to the child when the launching thread dies.

    libc's ``prctl`` is looked up here, in the parent: the child (between fork and exec) only
    calls it. None where there is no ``prctl`` (not Linux).
    """
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    return functools.partial(prctl, _PR_SET_PDEATHSIG, int(signal.SIGTERM))


class SitlFleet:
    """A running fleet of real SITL instances; a context manager that stops it on exit.

    Parameters
    ----------
    config : SitlFleetConfig
        What to start.
    """

    def __init__(self, config: SitlFleetConfig):
        self.config = config
        self.sitl_dir = resolve_sitl_dir(config.flavour, config.sitl_dir)
        self.vehicles: list[SitlVehicle] = []
        self.run_dir: Path | None = None
        self._tmp: tempfile.TemporaryDirectory | None = None
        self._procs: list[subprocess.Popen] = []
        self._specs: list[InstanceSpec] = []
        self._preexec = _pdeathsig_setter()

    # ------------------------------------------------------------------ lifecycle
    def __enter__(self) -> SitlFleet:
        try:
            self.start()
        except BaseException:
            self.stop()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def start(self) -> None:
        """Start every instance and wait until each is ready (heartbeat, position).

        Raises
        ------
        SitlSetupError
            An instance did not start or did not become ready (its log file is named).
        """
        cfg = self.config
        if cfg.run_dir is None:
            self._tmp = tempfile.TemporaryDirectory(prefix=f"swarmseek-sitl-{cfg.flavour}-")
            self.run_dir = Path(self._tmp.name)
        else:
            self.run_dir = Path(cfg.run_dir).resolve()
            self.run_dir.mkdir(parents=True, exist_ok=True)
        self._specs = instance_specs(cfg, self.sitl_dir, self.run_dir)
        for spec in self._specs:
            self._launch(spec)
        groups: dict[str, list[int]] = {}
        for spec in self._specs:
            groups.setdefault(spec.ready_connection, []).append(spec.sysid)
        wait_ready(groups, timeout_s=cfg.ready_timeout_s, check_alive=self.check_alive,
                   request_streams=cfg.flavour == "ardupilot")
        for spec in self._specs:
            for argv in spec.setup_commands:
                done = subprocess.run(argv, cwd=spec.work_dir, env=spec.env, capture_output=True, text=True,
                                      timeout=10.0, check=False)
                if done.returncode != 0:
                    raise SitlSetupError(f"SITL instance {spec.instance}: {' '.join(argv[1:])} failed: "
                                         f"{(done.stdout + done.stderr).strip()[-300:]}")

    def _launch(self, spec: InstanceSpec) -> None:
        log = open(spec.work_dir / "sitl.log", "wb")  # noqa: SIM115 - closed right after Popen
        try:
            proc = subprocess.Popen(spec.argv, cwd=spec.work_dir, env=spec.env, stdout=log,
                                    stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                    start_new_session=True, preexec_fn=self._preexec)
        except OSError as exc:
            raise SitlSetupError(f"cannot start {spec.argv[0]}: {exc}") from None
        finally:
            log.close()
        self._procs.append(proc)
        self.vehicles.append(SitlVehicle(index=spec.index, instance=spec.instance, sysid=spec.sysid,
                                         connection=spec.connection, sensor_connection=spec.sensor_connection,
                                         home=spec.home, pid=proc.pid, work_dir=spec.work_dir))

    def check_alive(self) -> None:
        """Raise :class:`SitlSetupError` naming the log of the first instance that has exited."""
        for proc, spec in zip(self._procs, self._specs):
            if proc.poll() is not None:
                tail = _tail(spec.work_dir / "sitl.log")
                raise SitlSetupError(f"SITL instance {spec.instance} (system id {spec.sysid}) exited with "
                                     f"status {proc.returncode}; log {spec.work_dir / 'sitl.log'}:\n{tail}")

    def stop(self) -> None:
        """Stop every process group (SIGTERM, then SIGKILL), reap, remove lock files and the run dir."""
        stop_groups(self._procs)
        if self.config.flavour == "px4":
            cleanup_px4_files([s.instance for s in self._specs])
        self._procs = []
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    # ------------------------------------------------------------------ use
    @property
    def origin(self) -> tuple[float, float, float]:
        """The mission origin of a plan for this fleet: the first vehicle's home."""
        return self.vehicles[0].home if self.vehicles else (self.config.home or DEFAULT_HOMES[self.config.flavour])

    @property
    def pids(self) -> list[int]:
        """Process ids (= process group ids) of the instances."""
        return [p.pid for p in self._procs]

    def write_plan(self, path: str | Path, **options) -> Path:
        """Write a ready-to-fly plan for this fleet (see :func:`mission.sim.sitl_plan.write_plan`).

        Wall-clock quantities are scaled for the fleet's speed-up unless ``speedup`` is given.
        """
        options.setdefault("speedup", self.config.speedup)
        return write_plan(path, self.vehicles, self.origin, flavour=self.config.flavour, **options)


def _tail(path: Path, lines: int = 8) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return "(no log)"


@contextlib.contextmanager
def sigterm_as_interrupt():
    """Within the block (main thread only), SIGTERM raises :class:`KeyboardInterrupt`."""
    def _raise(signum, frame):
        raise KeyboardInterrupt(f"signal {signum}")
    previous = signal.signal(signal.SIGTERM, _raise)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
