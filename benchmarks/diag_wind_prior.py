"""Calibration of :func:`mission.flight.wind_prior.fleet_wind_prior` on the mock's wind estimates.

Each trial gives N vehicles a fresh :class:`sitl_mock.ap_wind.WindEstimateModel` (true wind from
270 degrees, its error independent per vehicle), sends each estimate through ArduPilot's WIND
convention and the ground station's decoder, and asks for the fleet's prior. Printed: how often
the true direction lies within 1.96 ``std_deg`` of the prior (the prior is meant to be
conservative: >= 0.95), the median ``std_deg``, and how many trials gave no prior (too weak).

    PYTHONPATH=$PWD python benchmarks/diag_wind_prior.py [--trials 2000] [--seed 123]
"""
from __future__ import annotations

import argparse
import types

import numpy as np

from mission.flight.wind_prior import fleet_wind_prior
from mission.vehicle.state import VehicleState
from mission.vehicle.wind import decode_wind
from sitl_mock.ap_wind import WindEstimateModel, wind_fields, wind_ned_from_met

TRUE_FROM_DEG = 270.0


def _trial(n: int, speed_m_s: float, rng: np.random.Generator):
    snaps = []
    for i in range(n):
        model = WindEstimateModel(wind_ned_from_met(TRUE_FROM_DEG, speed_m_s), rng)
        state = VehicleState(sysid=i + 1, flavour="ardupilot")
        fields = wind_fields(model.estimate_ned_m_s(0.0))
        state.wind = decode_wind(types.SimpleNamespace(**fields), 0.0)
        snaps.append(state)
    return fleet_wind_prior(snaps)


def main() -> None:
    """Print the calibration table."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=123)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    print("| vehicles | wind (m/s) | true direction within 1.96 std_deg | median std_deg | no prior |")
    print("|---|---|---|---|---|")
    for n in (1, 8):
        for speed in (1.0, 3.0):
            priors = [_trial(n, speed, rng) for _ in range(args.trials)]
            got = [p for p in priors if p is not None]
            inside = sum(abs((p.from_deg - TRUE_FROM_DEG + 180.0) % 360.0 - 180.0) <= 1.96 * p.std_deg
                         for p in got)
            print(f"| {n} | {speed:g} | {inside / len(got):.3f} ({len(got)} priors) | "
                  f"{np.median([p.std_deg for p in got]):.1f} | {args.trials - len(got)} |")


if __name__ == "__main__":
    main()
