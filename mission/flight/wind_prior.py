"""A wind-direction prior for the seekers from the autopilots' own wind estimates.

Each vehicle's autopilot may publish its wind estimate (PX4 WIND_COV, ArduPilot WIND; decoded
into :attr:`mission.vehicle.state.VehicleState.wind`). :func:`fleet_wind_prior` combines the
fleet's estimates into one :class:`WindPrior`, the ``wind_from_deg`` / ``wind_std_deg`` a
source-term-estimation seeker takes as its prior when the plan does not give the wind:

* the direction is that of the mean wind vector (a circular mean weighted by speed: a vehicle
  that measures a stronger wind knows its direction better);
* its uncertainty combines the spread across vehicles (the circular standard deviation
  ``sqrt(-2 ln R)`` of the speed-weighted mean resultant length ``R``) and one estimate's error
  turned into an angle (``atan(error / speed)``: 0.5 m/s is ~10 degrees in a 3 m/s wind, ~27 in
  1 m/s), with a floor (10 degrees) for what all the EKFs may share;
* no prior (None) when no vehicle has a fresh estimate, or when the mean wind is weaker than
  ``min_speed_m_s`` (0.5 m/s): a calm, or estimates that cancel, have no direction. An autopilot
  that does not estimate the wind (ArduCopter without drag fusion sends speed 0) gives None too.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable

from mission.vehicle.wind import wrap_360_deg

__all__ = ["WindPrior", "fleet_wind_prior"]


@dataclass(frozen=True)
class WindPrior:
    """The fleet's wind, as a prior.

    Attributes
    ----------
    from_deg : float
        Where the wind comes FROM, degrees clockwise from north, in [0, 360) (meteorological;
        the convention of ``SteSeeker(wind_from_deg=...)`` and of the plume fields).
    std_deg : float
        Standard deviation of the direction (``SteSeeker(wind_std_deg=...)``), >= the floor.
    speed_m_s : float
        Speed of the mean wind vector.
    speed_std_m_s : float
        Spread of the vehicles' speeds, at least one estimate's error.
    spread_deg : float
        Circular standard deviation of the vehicles' directions (0 for one vehicle).
    n_vehicles : int
        Estimates combined.
    n_ignored : int
        Snapshots with an estimate left out: stale (older than ``max_age_s``) or not finite.
    """

    from_deg: float
    std_deg: float
    speed_m_s: float
    speed_std_m_s: float
    spread_deg: float
    n_vehicles: int
    n_ignored: int


def _usable(wind, now_s: float | None, max_age_s: float) -> bool:
    if not (math.isfinite(wind.from_deg) and math.isfinite(wind.speed_m_s) and wind.speed_m_s >= 0.0):
        return False
    return now_s is None or now_s - wind.time_s <= max_age_s


def _fresh_winds(snapshots: Iterable, now_s: float | None, max_age_s: float) -> tuple[list, int]:
    """The usable estimates of ``snapshots`` and how many were left out (stale, not finite)."""
    winds, ignored = [], 0
    for snap in snapshots:
        if snap is None:
            continue
        if not hasattr(snap, "wind"):   # e.g. the keys of co.vehicles: a caller's mistake, said
            raise TypeError(f"fleet_wind_prior takes vehicle state snapshots, got {type(snap).__name__}")
        wind = snap.wind
        if wind is None:
            continue
        if _usable(wind, now_s, max_age_s):
            winds.append(wind)
        else:
            ignored += 1
    return winds, ignored


def fleet_wind_prior(snapshots: Iterable, *, now_s: float | None = None, max_age_s: float = 10.0,
                     min_speed_m_s: float = 0.5, floor_std_deg: float = 10.0,
                     estimate_error_m_s: float = 0.5) -> WindPrior | None:
    """Combine the vehicles' wind estimates into one direction prior.

    Parameters
    ----------
    snapshots : iterable of VehicleState
        The vehicles' state snapshots (anything with a ``wind`` attribute holding a
        :class:`mission.vehicle.wind.WindEstimate` or None; None entries are skipped).
    now_s : float, optional
        Ground-station clock time; with it, estimates older than ``max_age_s`` are left out.
    max_age_s : float
        Oldest estimate used (s).
    min_speed_m_s : float
        Below this mean wind speed there is no direction to give: None.
    floor_std_deg : float
        Smallest ``std_deg`` returned.
    estimate_error_m_s : float
        One estimate's horizontal error (m/s), turned into a direction error at the mean speed.

    Returns
    -------
    WindPrior or None
        None when no vehicle has a usable estimate or the mean wind is weaker than
        ``min_speed_m_s``.

    Raises
    ------
    TypeError
        An item that is neither None nor has a ``wind`` attribute (not a snapshot).
    """
    winds, ignored = _fresh_winds(snapshots, now_s, max_age_s)
    if not winds:
        return None
    vectors = [w.toward_en_m_s() for w in winds]
    mean_e = sum(v[0] for v in vectors) / len(vectors)
    mean_n = sum(v[1] for v in vectors) / len(vectors)
    speed = math.hypot(mean_e, mean_n)
    if not speed >= min_speed_m_s:
        return None
    total = sum(w.speed_m_s for w in winds)
    resultant = min(1.0, speed * len(winds) / total)   # speed-weighted mean resultant length
    spread_deg = math.degrees(math.sqrt(-2.0 * math.log(resultant)))
    error_deg = math.degrees(math.atan2(estimate_error_m_s, speed))
    speeds = [w.speed_m_s for w in winds]
    mean_speed = total / len(winds)
    speed_sd = math.sqrt(sum((s - mean_speed) ** 2 for s in speeds) / len(speeds))
    return WindPrior(from_deg=wrap_360_deg(math.degrees(math.atan2(-mean_e, -mean_n))),
                     std_deg=max(floor_std_deg, math.hypot(spread_deg, error_deg)),
                     speed_m_s=speed, speed_std_m_s=max(estimate_error_m_s, speed_sd),
                     spread_deg=spread_deg, n_vehicles=len(winds), n_ignored=ignored)
