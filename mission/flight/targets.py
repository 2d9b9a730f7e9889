"""Slots and transfers: the formation's slot offsets, their assignment, layered transfers.

:func:`layered_transfer` plans a formation change that keeps separation: vehicles first move
vertically to their altitude layers, then horizontally at them, then vertically to their goals
(proved in ``docs/mission.md``). The layers come from
:func:`mission.flight.layers.shared_layers` (shared by vehicles whose paths keep apart);
:func:`layered_altitudes` (one layer per vehicle) is kept for small fleets and tests.
"""
from __future__ import annotations

import asyncio

import numpy as np

from formation.assignment import assign_slots as _formation_assign_slots
from formation.cvt import cvt_sphere
from formation.symmetric import symmetric_cylinder

__all__ = ["assign_slots", "formation_offsets", "layered_altitudes", "layered_transfer", "solve_formation"]


def assign_slots(current_positions, slots) -> np.ndarray:
    """Minimum total squared travel assignment: ``perm[i]`` is the slot of vehicle ``i``.

    Uses :func:`formation.assignment.assign_slots` without rotation.
    """
    perm, _ = _formation_assign_slots(np.asarray(current_positions, dtype=float), np.asarray(slots, dtype=float),
                                      allow_rotation=False)
    return np.asarray(perm, dtype=int)


def layered_altitudes(n: int, low_m: float, high_m: float, min_separation_m: float) -> np.ndarray:
    """``n`` distinct altitudes from ``low_m`` upwards, ``1.25 * min_separation_m`` apart.

    Raises
    ------
    ValueError
        They do not fit below ``high_m``.
    """
    spacing = 1.25 * float(min_separation_m)
    alts = low_m + spacing * np.arange(n)
    if n and alts[-1] > high_m:
        raise ValueError(f"{n} altitude layers {spacing:.2f} m apart from {low_m:.1f} m need up to "
                         f"{alts[-1]:.1f} m, above the allowed {high_m:.1f} m: widen the geofence "
                         f"altitude band or lower takeoff_alt_m")
    return alts


def layered_transfer(start, goal, layer_alt_m) -> list[np.ndarray]:
    """Waypoint batches ``[(N,3), ...]`` from ``start`` to ``goal`` keeping the layers' separation.

    Step 1: each vehicle to its layer altitude above its start; step 2: horizontally to above its
    goal at its layer; step 3: vertically to its goal. Every vehicle finishes a step before any
    begins the next (the caller waits for arrival between batches). Separation holds when the
    layers are ordered like the goals' altitudes where goals are horizontally close: the caller
    orders layers by goal altitude.
    """
    s = np.asarray(start, dtype=float)
    g = np.asarray(goal, dtype=float)
    lay = np.asarray(layer_alt_m, dtype=float)
    up = s.copy()
    up[:, 2] = lay
    across = g.copy()
    across[:, 2] = lay
    return [up, across, g.copy()]


def formation_offsets(kind: str, n: int, radius_m: float, seed: int = 0) -> np.ndarray:
    """``(n, 3)`` slot offsets of the formation about its centre (ENU metres).

    A CVT solve takes about 0.2 s of CPU for 8 vehicles: inside the event loop, await
    :func:`solve_formation` instead.
    """
    if kind == "symmetric":
        return np.asarray(symmetric_cylinder(n, radius_m), dtype=float)
    return np.asarray(cvt_sphere(n, radius_m, seed=seed), dtype=float)


async def solve_formation(kind: str, n: int, radius_m: float, seed: int = 0) -> np.ndarray:
    """:func:`formation_offsets` in the loop's executor (a worker thread; inline, in zero simulated
    time, on a lock-step loop), so the event loop never waits on the solve."""
    return await asyncio.get_running_loop().run_in_executor(None, formation_offsets, kind, n, radius_m, seed)
