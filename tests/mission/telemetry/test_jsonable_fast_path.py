"""``to_jsonable``'s exact-type fast path for leaves gives what its general path gives."""
from __future__ import annotations

import json
import math
import random
import sys

import numpy as np

from mission.telemetry.mission_log import _jsonable_any, to_jsonable


def _leaves(rng: random.Random):
    yield from (0.0, -0.0, math.nan, math.inf, -math.inf, sys.float_info.max, 5e-324, 1e-7, 0.1234565,
                0, 1, -1, 2 ** 70, True, False, None, "", "x", "secret_key", "lat_deg")
    for _ in range(5000):
        yield rng.choice([rng.uniform(-1e6, 1e6), rng.gauss(0, 1e-4), rng.randrange(-2 ** 40, 2 ** 40),
                          math.ldexp(rng.random(), rng.randrange(-1074, 1024)), "s%d" % rng.randrange(100)])


def test_leaves_match_the_general_path():
    for leaf in _leaves(random.Random(7)):
        fast, plain = to_jsonable(leaf), _jsonable_any(leaf)
        assert type(fast) is type(plain) and (fast == plain or (fast != fast and plain != plain)), leaf


def test_subclasses_and_numpy_scalars_still_take_the_general_path():
    class Flag(int):
        pass

    assert to_jsonable(np.float64(1.23456789)) == _jsonable_any(np.float64(1.23456789)) == 1.234568
    assert to_jsonable(np.float32(math.nan)) is None
    assert to_jsonable(np.int64(3)) == 3 and type(to_jsonable(np.int64(3))) is int
    assert to_jsonable(np.bool_(True)) is True
    assert to_jsonable(Flag(4)) == 4


def test_nested_records_serialise_as_before():
    rng = random.Random(11)
    for _ in range(200):
        rec = {"t": rng.random(), "k": rng.randrange(9), "xs": [rng.uniform(-9, 9) for _ in range(5)],
               "lat_deg": rng.uniform(-90, 90), "password": "hunter2", "nan": math.nan,
               "arr": np.array([rng.random(), math.inf]), "tup": (1, "a", None, 2.5)}
        got = json.dumps(to_jsonable(rec), allow_nan=False)
        assert "hunter2" not in got
        back = json.loads(got)
        assert back["nan"] is None and back["arr"][1] is None and back["tup"] == [1, "a", None, 2.5]
        assert back["t"] == round(rec["t"], 6) and back["lat_deg"] == round(rec["lat_deg"], 9)
