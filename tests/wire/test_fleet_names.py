"""One rule for fleet names (wire.fleet_name): plans, ctl, watch, sitl, mock, sensor, the world's keys.

A fleet name is one zenoh key chunk naming exactly one fleet: ``ctl '**' land`` must not
address every fleet on the network, and no name may reach zenoh only to be refused there with
a traceback (``ctl '' pause`` did).
"""
from __future__ import annotations

import copy
import tomllib
from pathlib import Path

import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st

from mission.cli import main as cli_main
from mission.core.plan import parse_plan
from mission.core.plan_types import PlanError
from companion.sensor_wire import sensor_key
from wire.fleet_name import FLEET_NAME_MAX_CHARS, check_fleet_name, fleet_name_problem

SAMPLE = Path(__file__).resolve().parents[2] / "mission" / "examples" / "sitl_plan.toml"

BAD = [
    ("", "must not be empty"),
    ("*", "must not contain '\\*'"),
    ("**", "must not contain '\\*'"),
    ("$*", "must not contain '\\$'"),
    ("a$*b", "must not contain '\\$'"),
    ("a/b", "must not contain '/'"),
    ("/", "must not contain '/'"),
    ("a#b", "must not contain '#'"),
    ("a?b", "must not contain '\\?'"),
    ("a b", "whitespace"),
    ("tab\there", "whitespace"),
    ("nul\x00", "control characters"),
    ("@admin", "must not start with '@'"),
    ("x" * (FLEET_NAME_MAX_CHARS + 1), f"at most {FLEET_NAME_MAX_CHARS} characters"),
    (3, "must be a string"),
]
GOOD = ["swarmseek", "sitl", "f", "fleet-2_north.a", "é", "x" * FLEET_NAME_MAX_CHARS, "a@b", ".."]
KEYS = ("swarmseek/{}/mission/state", "swarmseek/{}/mission/control", "swarmseek/{}/vehicle/1/sensor")


@pytest.mark.parametrize("name, why", BAD)
def test_a_bad_fleet_name_is_refused_with_the_reason(name, why):
    with pytest.raises(ValueError, match=f"fleet name .* {why}"):
        check_fleet_name(name)


@pytest.mark.parametrize("name", GOOD)
def test_a_good_fleet_name_is_one_canonical_zenoh_chunk(name):
    assert check_fleet_name(name) == name
    for key in KEYS:
        assert str(zenoh.KeyExpr(key.format(name))) == key.format(name)  # accepted, not rewritten


_NAMES = st.one_of(
    st.text(max_size=FLEET_NAME_MAX_CHARS + 2),
    st.text(alphabet="ab/*$?#@ \t.-_é", max_size=6),
)


@settings(max_examples=300, deadline=None)
@given(_NAMES)
def test_zenoh_accepts_every_name_the_rule_accepts_and_the_world_applies_it(name):
    """What passes the rule is a wildcard-free canonical key chunk for zenoh; the simulated
    sensors' key (``companion.sensor_wire.sensor_key``) refuses the others with the rule's reason."""
    problem = fleet_name_problem(name)
    ok = problem is None
    if ok:
        assert sensor_key(name, 1) == f"swarmseek/{name}/vehicle/1/sensor"
    else:
        with pytest.raises(ValueError) as info:
            sensor_key(name, 1)
        assert problem in str(info.value)
    if ok:
        for key in KEYS:
            expr = zenoh.KeyExpr(key.format(name))
            assert str(expr) == key.format(name) and "*" not in str(expr)


@pytest.mark.parametrize("name, why", [b for b in BAD if isinstance(b[0], str) and b[0].strip()])
def test_a_plan_refuses_the_same_names(name, why):
    doc = tomllib.loads(SAMPLE.read_text())
    bad = copy.deepcopy(doc)
    bad["fleet"] = name
    with pytest.raises(PlanError) as info:
        parse_plan(bad)
    problems = dict(info.value.problems)
    assert "fleet" in problems, problems
    assert fleet_name_problem(name) in problems["fleet"]
    assert parse_plan(doc).fleet == "sitl"


_ARGV = {
    "ctl": lambda f: ["ctl", f, "land", "--zenoh-connect", "tcp/127.0.0.1:7447"],
    "watch": lambda f: ["watch", f, "--zenoh-connect", "tcp/127.0.0.1:7447"],
    "sitl": lambda f: ["sitl", "--flavour", "px4", f"--fleet={f}"],
    "mock": lambda f: ["mock", f"--fleet={f}"],
    "sensor": lambda f: ["sensor", "--connect", "tcp:127.0.0.1:5762", "--origin", "47,8,500", "--field", "sigma2",
                         "--zenoh-connect", "tcp/127.0.0.1:7447", f"--fleet={f}"],
}


@pytest.mark.parametrize("command", sorted(_ARGV))
@pytest.mark.parametrize("name", ["", "**", "*", "$*", "a/b", "@x", "a b"])
def test_every_command_refuses_a_bad_fleet_name_before_doing_anything(command, name, capsys):
    """``ctl '**' land`` would address every fleet on the network: exit 2, a one-line reason,
    before any zenoh session, SITL or mock fleet starts."""
    with pytest.raises(SystemExit) as info:
        cli_main(_ARGV[command](name))
    err = capsys.readouterr().err
    assert info.value.code == 2
    assert f"swarmseek {command}: error:" in err and "fleet name" in err, err
    assert fleet_name_problem(name).split(":")[0] in err
    assert "Traceback" not in err
