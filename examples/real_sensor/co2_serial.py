#!/usr/bin/env python3
"""Your own sensor loop with swarmseek's Publisher (docs/real-sensor.md).

A serial CO2 sensor that prints lines like ``CO2 412.5 ppm`` (not a bare number, so not for
``swarmseek publish``): this loop reads them with pyserial, picks the number out and gives it to
``companion.publisher.Publisher``, which stamps it with this computer's clock and the
autopilot's position and publishes it for the ground station. Any other sensor (I2C, a vendor
SDK) fits the same loop: read a value, ``pub.put(value)``.

    python examples/real_sensor/co2_serial.py --serial /dev/ttyUSB0 --baud 9600 \\
        --connect /dev/ttyAMA0,921600 --fleet demo --sysid 3 --zenoh-connect tcp/192.168.1.10:7447
"""
from __future__ import annotations

import argparse
import re
import sys

import serial

from companion.publisher import Publisher

#: the sensor's line: ``CO2 <number> ppm``
LINE = re.compile(rb"CO2\s+(\S+)\s*ppm")


def parse_ppm(line: bytes) -> float | None:
    """The line's CO2 concentration in ppm, or None for a line that holds none."""
    match = LINE.search(line)
    if match is None:
        return None
    try:
        return float(match.group(1))
    except ValueError:
        return None


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--serial", required=True, help="the sensor's serial device")
    parser.add_argument("--baud", type=int, default=9600)
    parser.add_argument("--connect", required=True, help="pymavlink connection to the autopilot")
    parser.add_argument("--fleet", required=True, help="the plan's fleet")
    parser.add_argument("--sysid", type=int, default=None, help="the plan's sysid of this vehicle")
    parser.add_argument("--zenoh-connect", required=True, help="the ground station's zenoh endpoint")
    parser.add_argument("--count", type=int, default=None, help="stop after this many readings published")
    args = parser.parse_args()
    skipped = 0
    with serial.Serial(args.serial, args.baud, timeout=1.0) as port, \
            Publisher(args.fleet, args.sysid, mavlink=args.connect, zenoh_connect=[args.zenoh_connect]) as pub:
        print(f"publishing {pub.key}", file=sys.stderr, flush=True)
        pub.wait_for_subscriber(5.0)  # the ground station is listening (or we go on without it)
        try:
            while args.count is None or pub.counts["published"] < args.count:
                line = port.readline()
                if not line:
                    continue  # nothing within the port's timeout
                ppm = parse_ppm(line)
                if ppm is None:
                    skipped += 1
                    continue
                pub.put(ppm)  # NaN, no position yet, stale position: counted, see pub.summary()
        except KeyboardInterrupt:
            pass
        finally:
            print(f"{pub.summary()}; lines without a reading {skipped}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
