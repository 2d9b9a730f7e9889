"""The flight modules moved to narrow collaborators take no Coordinator (docs/architecture.md,
"How a phase gets what it uses"): no function or method in them has a first parameter ``co``."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]

#: modules whose functions are handed the mission state, the fleet, the gate... and never ``co``
NARROW = ["faults/landing_guard", "readiness_mission", "failsafe_params", "faults/takeoff_loss", "obstacles", "services",
          "faults/loss", "faults/rejoin", "faults/retire", "faults/watchdog", "return_clear", "readiness_autopilot"]


def _takes_co(path: Path) -> list[str]:
    out = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            names = [a.arg for a in node.args.posonlyargs + node.args.args]
            if names[:1] == ["co"] or names[:2] == ["self", "co"]:
                out.append(f"{path.name}:{node.lineno} {node.name}")
    return out


@pytest.mark.parametrize("module", NARROW)
def test_a_narrow_flight_module_takes_no_coordinator(module):
    path = ROOT / "mission" / "flight" / f"{module}.py"
    assert path.is_file(), path
    assert _takes_co(path) == []


def test_the_check_finds_a_function_taking_the_coordinator(tmp_path):
    sample = tmp_path / "sample.py"
    sample.write_text("def f(co, x):\n    return x\n\nclass C:\n    def g(self, co):\n        return co\n")
    assert _takes_co(sample) == ["sample.py:1 f", "sample.py:5 g"]
