"""Cost of MAVLink 2 signing: per-frame signing and checking, ground station and mock.

Run from the repository root::

    python benchmarks/bench_signing.py [--frames 20000]

Prints microseconds per frame (CPU time of this process, best of 3) for:

1. pymavlink ``msg.pack`` of a SET_POSITION_TARGET_LOCAL_NED, unsigned and signed;
2. :func:`mission.link.signing.sign_frame` on an already packed frame (the setpoint fast path);
3. :meth:`mission.link.signing.SignatureVerifier.check_frame` (accepted frames);
4. the mock autopilot's receive gate (``MockAutopilot.accept_frame``) with signing off and on;
5. frame sizes (a signed frame is 13 bytes longer).
"""
from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import numpy as np  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mav  # noqa: E402

from mission.link.signing import SignatureVerifier, apply_signing, sign_frame
from mission.core.signing_config import SigningConfig
from sitl_mock.autopilot import MockAutopilot  # noqa: E402
from sitl_mock.dynamics_params import DynamicsParams
from sitl_mock.dynamics import Multicopter
from sitl_mock.transport import make_parser  # noqa: E402

KEY = bytes(range(1, 33))
T0_S = 1_763_700_000.0


def _best_us(fn, n: int, repeat: int = 3) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.process_time()
        fn(n)
        best = min(best, time.process_time() - t0)
    return best / n * 1e6


def _setpoint(enc):
    return enc.set_position_target_local_ned_encode(0, 1, 1, 1, 0xDF8, 1.0, 2.0, -10.0,
                                                    0, 0, 0, 0, 0, 0, 0, 0)


def main() -> int:
    """Print the figures; returns 0."""
    ap_ = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap_.add_argument("--frames", type=int, default=20000)
    n = ap_.parse_args().frames
    cfg = SigningConfig(KEY)
    plain = mav.MAVLink(None, 255, 190)
    signed = apply_signing(mav.MAVLink(None, 255, 190), cfg.new_state(T0_S))
    msg = _setpoint(plain)

    def pack_plain(k):
        for _ in range(k):
            msg.pack(plain)

    def pack_signed(k):
        for _ in range(k):
            msg.pack(signed)

    raw = msg.pack(plain)
    state = cfg.new_state(T0_S)

    def by_hand(k):
        for _ in range(k):
            sign_frame(raw, msg.crc_extra, state)

    frames = [msg.pack(signed) for _ in range(3 * n)]
    verifier = SignatureVerifier(cfg, cfg.new_state(T0_S))
    it = iter(frames)

    def check(k):
        for _ in range(k):
            verifier.check_frame(next(it))

    ap = MockAutopilot(1, "ardupilot", Multicopter(DynamicsParams(), np.random.default_rng(0)),
                       (45.19, 5.72, 230.0), T0_S)
    parser = make_parser()
    msgs_plain = [parser.parse_buffer(msg.pack(plain))[0] for _ in range(n)]
    msgs_signed = [parser.parse_buffer(f)[0] for f in frames]

    def gate(items):
        def run(k):
            for m in items[:k]:
                ap.accept_frame(m)
        return run

    print(f"signing cost per frame, best of 3, {n} frames (CPU us per frame)")
    print(f"  pack SET_POSITION_TARGET_LOCAL_NED unsigned : {_best_us(pack_plain, n):7.2f}")
    print(f"  pack SET_POSITION_TARGET_LOCAL_NED signed   : {_best_us(pack_signed, n):7.2f}")
    print(f"  sign_frame on a packed frame (fast path)    : {_best_us(by_hand, n):7.2f}")
    print(f"  SignatureVerifier.check_frame (accepted)    : {_best_us(check, n):7.2f}")
    print(f"  mock accept_frame, signing off              : {_best_us(gate(msgs_plain), n):7.2f}")
    ap.set_signing_key(KEY, T0_S)
    items = iter([msgs_signed[i * n:(i + 1) * n] for i in range(3)])
    best = min(_time_once(gate(next(items)), n) for _ in range(3))
    print(f"  mock accept_frame, signing on (accepted)    : {best:7.2f}")
    print(f"frame bytes: unsigned {len(raw)}, signed {len(frames[0])}")
    return 0


def _time_once(fn, n: int) -> float:
    t0 = time.process_time()
    fn(n)
    return (time.process_time() - t0) / n * 1e6


if __name__ == "__main__":
    sys.exit(main())
