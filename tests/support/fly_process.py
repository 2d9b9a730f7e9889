"""What the tests that run ``swarmseek`` in its own process share: the environment that makes
the child import this checkout, and the plan of a small wall-clock mission with a slow
gradient seek (long enough for the faults and commands a test sends during it).

Used by tests/support/ctl_processes.py (``watch``/``ctl`` beside ``fly``), by
tests/support/gcs_fault_support.py (the ground station's own faults) and by the tests that run
a command in a child process.
"""
from __future__ import annotations

import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def subprocess_env() -> dict:
    """This process's environment with the checkout first on ``PYTHONPATH``."""
    return dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))


def gradient_seek_plan(path: Path, *, fleet: str, n: int, udp_base: int, origin: tuple, zenoh_section: str,
                       takeoff_alt_m: float, stagger_s: float, radius_m: float, start_alt_m: float,
                       fence_half_m: float, max_alt_m: float, min_alt_m: float = 3.0,
                       max_iterations: int | None = None, link_timeout_s: float | None = None) -> Path:
    """Write the plan of ``n`` vehicles on ``udpin:127.0.0.1:udp_base + i`` to ``path``.

    Parameters
    ----------
    path : Path
        The TOML file written (and returned).
    fleet : str
        The plan's fleet name.
    n : int
        Vehicles, system ids 1..n.
    udp_base : int
        The first vehicle's UDP port (``mission.sim.embedded.fleet_ports``).
    origin : tuple of float
        ``(lat_deg, lon_deg, alt_m)`` of the plan's origin (where the vehicles are).
    zenoh_section : str
        The body of the ``[zenoh]`` section.
    takeoff_alt_m, stagger_s, radius_m : float
        Take-off altitude, delay between take-offs, CVT formation radius.
    start_alt_m : float
        Altitude of the seek's start ``[0, 0, start_alt_m]``.
    fence_half_m, max_alt_m : float
        The geofence: a square of side ``2 fence_half_m`` round the origin, ``min_alt_m`` to ``max_alt_m``.
    min_alt_m : float
        The geofence's floor (default 3 m).
    max_iterations : int, optional
        The seek's iterations (the plan's default when None).
    link_timeout_s : float, optional
        ``[faults] link_timeout_s`` (the plan's default when None).
    """
    vehicles = "\n".join(f'[[vehicles]]\nid = "v{i + 1}"\nsysid = {i + 1}\n'
                         f'connection = "udpin:127.0.0.1:{udp_base + i}"\n' for i in range(n))
    iterations = "" if max_iterations is None else f"max_iterations = {max_iterations}\n"
    faults = "" if link_timeout_s is None else f"[faults]\nlink_timeout_s = {link_timeout_s}\n"
    h = float(fence_half_m)
    path.write_text(f'''version = 1
fleet = "{fleet}"
max_speed_m_s = 3.0
min_separation_m = 1.5
takeoff_alt_m = {float(takeoff_alt_m)}
stagger_s = {float(stagger_s)}
return = "land"
[origin]
lat_deg = {origin[0]}
lon_deg = {origin[1]}
alt_m = {origin[2]}
{vehicles}
[formation]
type = "cvt"
radius_m = {float(radius_m)}
[seeking]
seeker = "gradient"  # the paper's slow ascent: a seek long enough for the faults and commands
eps = 50.0
gamma_m = 1.0
rate_hz = 2.0
{iterations}start_enu_m = [0.0, 0.0, {float(start_alt_m)}]
arrival_tol_m = 0.5
[geofence]
polygon_enu_m = [[{-h}, {-h}], [{h}, {-h}], [{h}, {h}], [{-h}, {h}]]
min_alt_m = {float(min_alt_m)}
max_alt_m = {float(max_alt_m)}
{faults}[zenoh]
{zenoh_section}
''')
    return path
