"""The embedded mission of ``swarmseek run``: a mock fleet, a plan for it, free loopback ports.

The default: 8 mock vehicles (PX4 personality), CVT formation of radius 4 m, the paper's
``sigma_2`` field with its source drawn (from the seed) in the box ``E, N in [-20, 20] m,
U in [12, 18] m``, the formation starting 25 m away horizontally (3 m lower), the fleet's
``SimClock`` at 10x shared with the coordinator, zenoh: the fleet listens on a free loopback
port and the coordinator connects to it.

Choice of ``eps``: near the source of a Gaussian ``A exp(-d^T S d)`` the step is
``eps * 2 A S d``, which contracts the error along each eigenvector of ``S`` by
``1 - 2 eps A lambda``. ``eps = 1 / (2 A lambda_max(S))`` (a Newton step along the stiffest
axis) converges fastest without oscillation; for ``sigma_2`` it is 49.9, and 25 m away it gives
``eps ||grad|| ~ 1.1 m``, i.e. steps of about ``gamma = 1 m`` from the start. The paper's
``eps = 1`` with ``sigma_2`` (``||grad|| ~ 1e-3..4e-2 /m``) would move the centre by centimetres per
iteration: thousands of iterations. ``--eps`` and ``--gamma`` override (``--eps 1 --gamma 0.1``
gives the paper's parameters). Plumes (``--field plume`` / ``intermittent``, ``docs/fields.md``)
give their own Newton gain across the centreline near the release (``s0^2 / C0``), and the start
is drawn downwind of the release (within 10 degrees of the wind's axis): upwind of a plume there
is nothing to climb.
"""
from __future__ import annotations

import os
import random
import socket
import tempfile
from pathlib import Path

import numpy as np

from mission.core.plan_types import FormationPlan, GeofencePlan, Plan, SeekingPlan, VehiclePlan
from mission.core.zenoh_config import ZenohPlan
from mission.sim.leases import take_leases

__all__ = ["DEFAULT_ORIGIN", "FENCE_MIN_ALT_M", "FENCE_MAX_ALT_M", "FENCE_POLYGON_EN_M", "MAX_VEHICLES",
           "PORT_LEASE_S", "free_port_block", "port_lease_dir", "default_eps", "default_radius_m",
           "default_source_and_start", "downwind_en", "embedded_plan", "fleet_ports", "search_fence_en_m"]

DEFAULT_ORIGIN = (45.1885, 5.7245, 212.0)
#: MAVLink system ids 1..254 (255 is the ground station's own)
MAX_VEHICLES = 254
#: the embedded plan's geofence floor and ceiling, m
FENCE_MIN_ALT_M = 2.0
FENCE_MAX_ALT_M = 80.0
#: how long a port :func:`free_port_block` handed out stays reserved against its other calls, s
#: (the caller binds it within seconds; once bound, the bind check keeps others off it)
PORT_LEASE_S = 120.0
#: the embedded plan's geofence polygon, (east, north) m about the origin
FENCE_POLYGON_EN_M = ((-150.0, -150.0), (150.0, -150.0), (150.0, 150.0), (-150.0, 150.0))


def free_port_block(count: int, step: int = 1, kinds: tuple[str, ...] = ("udp",), lo: int = 20000,
                    hi: int = 32000, tries: int = 200, lease_dir: str | Path | None = None) -> int:
    """A base port such that ``base + step * i`` (i < count) are free for every kind in ``kinds``,
    leased to the caller for :data:`PORT_LEASE_S` seconds.

    Free means: no socket is bound to it (checked by binding and closing), and no other call of
    this function, in any process of this user, handed it out less than :data:`PORT_LEASE_S` ago.
    The lease closes the gap between the check and the caller's own bind, in which another
    process's check would find the port free too (two pytest-xdist workers starting missions at
    once were handed the same ports: "cannot start the embedded fleet or zenoh"). The leases are
    one JSON file (``lease_dir``, default :func:`port_lease_dir`) read and written under an
    exclusive ``flock``, so allocations in every process take turns.

    The default range ends below Linux's ephemeral range (32768-60999): a port found free there
    can be taken a moment later by any socket bound to port 0 (a fake vehicle's, a zenoh
    client's), which made benchmarks fail with "Address already in use" on a busy host.

    Raises
    ------
    OSError
        No free block found, or the lease file cannot be opened.
    """
    directory = Path(lease_dir) if lease_dir is not None else port_lease_dir()

    def choose(leases: dict[int, float]) -> tuple[int, list[int]]:
        base = _unleased_free_block(count, step, kinds, range(lo, hi - step * (count - 1)), tries, leases)
        return base, [base + step * i for i in range(count)]

    return take_leases(directory / "leases.json", choose, PORT_LEASE_S)


def port_lease_dir() -> Path:
    """The directory of :func:`free_port_block`'s lease file: one per user, in the temp directory."""
    return Path(tempfile.gettempdir()) / f"swarmseek-ports-{os.getuid()}"


def _unleased_free_block(count: int, step: int, kinds: tuple[str, ...], bases: range, tries: int,
                         leases: dict[int, float]) -> int:
    """A base from ``bases`` whose block has no lease and binds for every kind: random bases, and the
    first base after each leased port (a wide block, e.g. 508 ports for 254 vehicles, then still
    finds the gaps between many scattered leases, which random bases alone once missed 200 times)."""
    rng = random.Random()
    after_leases = [port + 1 for port in leases if bases.start <= port + 1 < bases.stop
                    and not any(port + 1 + step * i in leases for i in range(count))]
    rng.shuffle(after_leases)
    for base in after_leases[:tries // 2] + [rng.choice(bases) for _ in range(tries)]:
        ports = [base + step * i for i in range(count)]
        if any(port in leases for port in ports):
            continue
        socks = []
        try:
            for port in ports:
                for kind in kinds:
                    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM if kind == "udp" else socket.SOCK_STREAM)
                    socks.append(s)
                    s.bind(("127.0.0.1", port))
            return base
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()
    raise OSError(f"no block of {count} free loopback ports found in {bases.start}-{bases.stop + step * (count - 1)}")


def default_eps(field) -> float:
    """``1 / (2 A lambda_max(S))`` for a Gaussian field (see the module docstring), the field's
    ``newton_gain()`` when it has one (plumes), the first part's for a sum; 1.0 otherwise."""
    if hasattr(field, "newton_gain"):
        return float(field.newton_gain())
    if getattr(field, "parts", None):
        return default_eps(field.parts[0])
    amp = getattr(field, "amplitude", None)
    S = getattr(field, "S", None)
    if amp is None or S is None:
        return 1.0
    return float(1.0 / (2.0 * amp * np.max(np.linalg.eigvalsh(np.asarray(S, dtype=float)))))


def downwind_en(field) -> np.ndarray | None:
    """The unit (east, north) vector the field's wind blows toward (a sum: its first part's);
    None for a field without wind."""
    for f in (field, getattr(field, "steady", None), *(getattr(field, "parts", None) or ())[:1]):
        if f is not None and getattr(f, "downwind_en", None) is not None:
            return np.asarray(f.downwind_en, dtype=float)
        if f is not None and getattr(f, "steady", None) is not None:
            return np.asarray(f.steady.downwind_en, dtype=float)
    return None


def default_source_and_start(seed: int, distance_m: float = 25.0,
                             downwind=None) -> tuple[np.ndarray, np.ndarray]:
    """Source in the default box and a start ``distance_m`` away horizontally (3 m lower).

    With ``downwind`` (a unit (east, north) vector) the start's bearing from the source is
    within 10 degrees of it (same source and draws as without).
    """
    rng = np.random.default_rng(seed)
    source = rng.uniform([-20.0, -20.0, 12.0], [20.0, 20.0, 18.0])
    heading = rng.uniform(0.0, 2.0 * np.pi)
    if downwind is not None:
        heading = np.arctan2(downwind[1], downwind[0]) + (heading / (2.0 * np.pi) - 0.5) * np.pi / 9.0
    start = source + np.array([distance_m * np.cos(heading), distance_m * np.sin(heading), -3.0])
    return source, start


def search_fence_en_m(side_m: float, points_en, margin_m: float, seed: int) -> tuple:
    """A square geofence polygon ``((e, n), ...)`` of side ``side_m`` placed at random (from ``seed``)
    among the placements holding every point of ``points_en`` (the source, the start, the takeoff
    area) at least ``margin_m`` inside; along an axis where none can, the side grows to the least that
    does. Where the release sits in its fence is as random as the fence (a plan's search area)."""
    pts = np.asarray(points_en, dtype=float)[:, :2]
    lo_pt, hi_pt = pts.min(axis=0), pts.max(axis=0)
    side = np.maximum(float(side_m), hi_pt - lo_pt + 2.0 * margin_m)
    first, last = hi_pt + margin_m - side, lo_pt - margin_m
    low = first + np.random.default_rng([seed, 6]).uniform(0.0, 1.0, 2) * (last - first)
    e0, n0 = (float(x) for x in low)
    e1, n1 = (float(x) for x in low + side)
    return (e0, n0), (e1, n0), (e1, n1), (e0, n1)


def fleet_ports(n: int, personality: str) -> dict:
    """Free ports for a mock fleet of ``n``: MAVLink (UDP for PX4, TCP for ArduPilot) and zenoh.

    PX4: one free block of ``2 n`` UDP ports, vehicle ``i`` streaming to ``base + i`` and
    listening on ``base + n + i`` (two blocks searched apart could overlap: a vehicle would
    then stream to another's own port). ArduPilot: ``n`` TCP ports 10 apart.
    """
    if not 1 <= n <= MAX_VEHICLES:
        raise ValueError(f"a mock fleet has 1..{MAX_VEHICLES} vehicles, got {n}")
    ports: dict = {"udp_base_port": 0, "udp_bind_base_port": 0, "tcp_base_port": 0}
    if personality == "ardupilot":
        ports["tcp_base_port"] = free_port_block(n, step=10, kinds=("tcp",))
    else:
        base = free_port_block(2 * n, kinds=("udp",))
        ports["udp_base_port"] = base
        ports["udp_bind_base_port"] = base + n
    ports["zenoh_port"] = free_port_block(1, kinds=("tcp",))
    return ports


def default_radius_m(n: int) -> float:
    """Default formation radius: 4 m, ``1.5 n^(1/3)`` m for more than 18 vehicles.

    The CVT slots of a sphere are about ``1.1 R n^(-1/3)`` apart; this keeps them near 2 m
    (``min_separation_m`` 1.5 m) and leaves the paths into the formation room enough that
    shared altitude layers fit below the fence (``mission.flight.layers``).
    """
    return max(4.0, 1.7 * float(n) ** (1.0 / 3.0))


def embedded_plan(n: int, ports: dict, *, personality: str = "px4", formation: str = "cvt",
                  radius_m: float = 4.0, start_enu_m=(0.0, 0.0, 12.0), eps: float = 1.0,
                  gamma_m: float = 1.0, estimator: str | None = None, max_iterations: int = 300,
                  fleet: str = "swarmseek", origin=DEFAULT_ORIGIN, convergence_tol_m: float = 0.3,
                  convergence_window: int = 12, return_behaviour: str = "land",
                  stagger_s: float = 0.5, max_speed_m_s: float = 3.0) -> Plan:
    """The :class:`~mission.core.plan.Plan` that flies a mock fleet started with ``ports``."""
    vehicles = []
    for i in range(n):
        if personality == "ardupilot":
            conn = f"tcp:127.0.0.1:{ports['tcp_base_port'] + 10 * i}"
        else:
            conn = f"udpin:127.0.0.1:{ports['udp_base_port'] + i}"
        vehicles.append(VehiclePlan(id=f"{personality[:3]}{i + 1}", sysid=i + 1, connection=conn))
    seeking = SeekingPlan(eps=eps, gamma_m=gamma_m, estimator=estimator or formation, rate_hz=2.0,
                          max_iterations=max_iterations, convergence_tol_m=convergence_tol_m,
                          convergence_window=convergence_window,
                          start_enu_m=tuple(float(x) for x in start_enu_m), arrival_tol_m=0.35,
                          reading_window_s=0.3, max_reading_age_s=5.0, max_position_error_m=10.0)
    return Plan(
        fleet=fleet, origin=tuple(origin), vehicles=tuple(vehicles),
        formation=FormationPlan(type=formation, radius_m=radius_m, seed=0), seeking=seeking,
        geofence=GeofencePlan(polygon_en_m=FENCE_POLYGON_EN_M, min_alt_m=FENCE_MIN_ALT_M,
                              max_alt_m=FENCE_MAX_ALT_M),
        zenoh=ZenohPlan(mode="peer", connect=(f"tcp/127.0.0.1:{ports['zenoh_port']}",)),
        max_speed_m_s=max_speed_m_s, min_separation_m=1.5, takeoff_alt_m=8.0,
        return_behaviour=return_behaviour, stagger_s=stagger_s, setpoint_rate_hz=10.0,
        heartbeat_timeout_s=15.0, min_battery_pct=30.0)
