#!/usr/bin/env python3
"""What the ground station makes of a fleet's sensor readings (docs/real-sensor.md).

Listens on zenoh like the ground station, passes every reading through the ground station's own
checks (``mission.telemetry.readings.ReadingStore``: schema, fleet, vehicle, sequence, age on
this computer's clock) and prints each reading it accepts and each rejection with its reason.
It has no telemetry, so it does not check the position against the vehicle's (``position_far``).

    python examples/real_sensor/listen.py --fleet demo --sysid 1 --origin 45.19,5.72,230 \\
        --zenoh-listen tcp/127.0.0.1:7447
"""
from __future__ import annotations

import argparse
import sys
import time

import zenoh

from mission.core.clock import WallClock
from mission.telemetry.readings import ReadingStore, ReadingSubscriber
from wire.cli_args import origin_geodetic
from wire.zenoh_config import zenoh_config


def _report(store: ReadingStore, sysids: list[int], last_s: dict, rejected: dict) -> int:
    """Print what is new since the last call; the number of new accepted readings."""
    new = 0
    for sysid in sysids:
        for r in store.history(sysid):
            if r.received_s > last_s[sysid]:
                last_s[sysid] = r.received_s
                new += 1
                east, north, up = r.position_enu_m
                print(f"accepted sysid {r.sysid} seq {r.seq} value {r.value:g} age {r.received_s - r.time_s:.3f} s "
                      f"at E {east:.1f} N {north:.1f} U {up:.1f} m", flush=True)
    counts, errors = store.counts()["rejected"], store.last_errors()
    for reason, n in counts.items():
        if n > rejected.get(reason, 0):
            print(f"rejected {n - rejected.get(reason, 0)} ({errors.get(reason, reason)})", flush=True)
            rejected[reason] = n
    return new


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fleet", required=True, help="the plan's fleet")
    parser.add_argument("--sysid", type=int, action="append", required=True, help="a vehicle's sysid (repeatable)")
    parser.add_argument("--origin", type=origin_geodetic, required=True, metavar="LAT,LON,ALT",
                        help="the plan's origin (degrees, degrees, metres AMSL)")
    parser.add_argument("--zenoh-listen", action="append", default=[], help="zenoh endpoint to listen on")
    parser.add_argument("--zenoh-connect", action="append", default=[], help="zenoh endpoint to connect to")
    parser.add_argument("--count", type=int, default=None, help="stop after this many accepted readings")
    args = parser.parse_args()
    if not args.zenoh_listen and not args.zenoh_connect:
        parser.error("give --zenoh-listen and/or --zenoh-connect")
    store = ReadingStore(args.fleet, args.sysid, args.origin, WallClock())
    session = zenoh.open(zenoh_config(listen=args.zenoh_listen or None, connect=args.zenoh_connect or None))
    subscriber = ReadingSubscriber(session, store)
    print(f"listening for swarmseek/{args.fleet}/vehicle/*/sensor", file=sys.stderr, flush=True)
    last_s, rejected, accepted = dict.fromkeys(args.sysid, float("-inf")), {}, 0
    try:
        while args.count is None or accepted < args.count:
            time.sleep(0.1)
            accepted += _report(store, args.sysid, last_s, rejected)
    except KeyboardInterrupt:
        pass
    finally:
        subscriber.close()
        session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
