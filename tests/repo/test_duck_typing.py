"""Typed access in the ground station, checked on the source (docs/architecture.md, "Typed
attributes, duck typing only at a plug-in boundary" and "Private names stay in their module").

``getattr(x, "name", default)`` and ``hasattr(x, "name")`` ask whether an object has an
attribute: right where objects of many kinds arrive (a seeker or field plug-in, a pymavlink
message whose fields depend on its type, the argparse namespace of any command), a hidden
interface everywhere else. Every such call in ``mission/`` must stand in a module of
:data:`DUCK_TYPING_ALLOWED`, at most as many times as it says. A ``getattr`` whose name is
computed (a property factory, ``termios.B<baud>``) is reflection, not duck typing, and is not
counted.

Private fields of another object (``x._name``, ``x`` not ``self``/``cls``) are read or set
only in :data:`PRIVATE_REACH_IN_ALLOWED`: pymavlink's message fields, in its one wrapper.
"""
from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

#: module (path under the repository) -> (most calls, why objects of several kinds arrive there)
DUCK_TYPING_ALLOWED = {
    "mission/flight/seeking.py": (3, "seeker plug-ins: arrival, estimate_enu, formation_radius_m are optional"),
    "mission/sim/embedded.py": (8, "field plug-ins: parts, amplitude, S, steady, downwind_en, newton_gain "
                                   "are what some fields have"),
    "mission/link/forward.py": (1, "pymavlink messages: target_system exists on some message types only"),
    "mission/vehicle/state.py": (1, "pymavlink messages: COMMAND_ACK's target_system is a MAVLink 2 extension"),
    "mission/cli/__init__.py": (1, "the argparse namespace of any command: only some have a fleet name"),
    "mission/telemetry/mission_log.py": (1, "any value written to the log: an object may give its own to_json()"),
    "mission/flight/wind_prior.py": (1, "a caller's wrong argument said as a TypeError, not an AttributeError"),
}

#: module -> (most reach-ins, why)
PRIVATE_REACH_IN_ALLOWED = {
    "wire/fast_decode.py": (4, "pymavlink's message: the fields its own decoder sets"),
}


def _calls(tree: ast.AST):
    """``(line, text)`` of each ``getattr(x, "literal", ...)`` / ``hasattr(x, "literal")``."""
    for node in ast.walk(tree):
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                and node.func.id in ("getattr", "hasattr") and len(node.args) >= 2
                and isinstance(node.args[1], ast.Constant) and isinstance(node.args[1].value, str)
                and (node.func.id == "hasattr" or len(node.args) == 3)):
            yield node.lineno, f"{node.func.id}(..., {node.args[1].value!r})"


def _reach_ins(tree: ast.AST):
    """``(line, text)`` of each ``x._name`` where ``x`` is not ``self``, ``cls`` or ``super()``
    (``self.store._lock`` is a reach-in into the store)."""
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__")):
            continue
        owner = node.value
        if isinstance(owner, ast.Name) and owner.id in ("self", "cls"):
            continue
        if isinstance(owner, ast.Call) and isinstance(owner.func, ast.Name) and owner.func.id == "super":
            continue
        yield node.lineno, f"{ast.unparse(owner)}.{node.attr}"


def _over_budget(find, allowed: dict) -> list[str]:
    """Each module of ``mission/`` and ``wire/`` where ``find`` sees more than ``allowed`` lets it have."""
    problems = []
    for path in sorted(p for pkg in ("mission", "wire") for p in (ROOT / pkg).rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        found = list(find(ast.parse(path.read_text(encoding="utf-8"), rel)))
        budget = allowed.get(rel, (0, ""))[0]
        if len(found) > budget:
            sites = ", ".join(f"{line}: {text}" for line, text in found)
            problems.append(f"{rel}: {len(found)} (allowed {budget}) at {sites}")
    return problems


def test_duck_typing_only_where_objects_of_several_kinds_arrive():
    assert _over_budget(_calls, DUCK_TYPING_ALLOWED) == []


def test_no_private_reach_in_but_pymavlinks_in_its_wrapper():
    assert _over_budget(_reach_ins, PRIVATE_REACH_IN_ALLOWED) == []


def test_the_budgets_are_not_stale():
    """Each allowed module exists and still needs its allowance (a fixed place leaves the list)."""
    stale = []
    for allowed, find in ((DUCK_TYPING_ALLOWED, _calls), (PRIVATE_REACH_IN_ALLOWED, _reach_ins)):
        for rel, (budget, _) in allowed.items():
            path = ROOT / rel
            used = len(list(find(ast.parse(path.read_text(encoding="utf-8"))))) if path.is_file() else None
            if used != budget:
                stale.append(f"{rel}: allowed {budget}, uses {used}")
    assert stale == []


def _plant(tmp_path, monkeypatch, files: dict[str, str]) -> None:
    for rel, source in files.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(source)
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)


def test_the_checks_see_planted_duck_typing_and_reach_ins(tmp_path, monkeypatch):
    """Not vacuous: a planted call outside the list, or one too many inside it, is reported;
    computed names and two-argument getattr are not counted."""
    _plant(tmp_path, monkeypatch, {
        "mission/safety/gate.py": "def f(res):\n    return getattr(res, 'report', None)\n",
        "mission/flight/seeking.py": "def g(sk):\n    return [getattr(sk, 'a', 0), getattr(sk, 'b', 0),\n"
                                     "            hasattr(sk, 'c'), getattr(sk, 'd', None)]\n",
        "mission/core/ok.py": "def h(o, n):\n    return getattr(o, n, None), getattr(o, 'x'), getattr(o, f'B{n}', 0)\n",
        "mission/link/endpoint.py": "def k(self, store):\n    with store._lock:\n        return self._x, self.ep._on_data, super()._y\n",
    })
    assert _over_budget(_calls, DUCK_TYPING_ALLOWED) == [
        "mission/flight/seeking.py: 4 (allowed 3) at 2: getattr(..., 'a'), 2: getattr(..., 'b'), "
        "3: hasattr(..., 'c'), 3: getattr(..., 'd')",
        "mission/safety/gate.py: 1 (allowed 0) at 2: getattr(..., 'report')"]
    assert _over_budget(_reach_ins, PRIVATE_REACH_IN_ALLOWED) == [
        "mission/link/endpoint.py: 2 (allowed 0) at 2: store._lock, 3: self.ep._on_data"]
