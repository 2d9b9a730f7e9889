"""The rooms and their one-way doors (docs/architecture.md), checked on the source.

Every import (module level or inside a function: a lazy import ties two modules together just
the same) is read with ``ast``; an import that goes up a layer, or into a room a package must
not know, fails with the file, the line and the rule it breaks.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: the ground station's rooms, lowest first: a room may import only rooms before it
MISSION_LAYERS = ["core", "link", "vehicle", "telemetry", "safety", "flight", "sim", "cli"]

#: top-level packages and the project packages each may import (besides itself)
PACKAGE_RULES = {
    "formation": set(),
    "estimator": {"formation"},
    "sitl_mock": {"formation", "estimator"},
    "experiments": {"formation", "estimator", "sitl_mock"},
    "mission": {"formation", "estimator", "sitl_mock", "experiments"},
}
#: within mission, who may import the simulated world and the experiments
MISSION_OUTSIDE_RULES = {"sitl_mock": {"sim", "cli"}, "experiments": {"cli"}}


def _imports(path: Path, module: str):
    """``(line, imported module)`` for every import in ``path`` (relative ones resolved)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                parts = parts[: len(parts) - node.level + 1]
                base = ".".join(parts + ([base] if base else []))
            yield node.lineno, base
            for alias in node.names:
                yield node.lineno, f"{base}.{alias.name}"


def _modules():
    for package in PACKAGE_RULES:
        for path in sorted((ROOT / package).rglob("*.py")):
            rel = path.relative_to(ROOT).with_suffix("")
            parts = list(rel.parts)
            if parts[-1] == "__init__":
                parts.pop()
            yield path, ".".join(parts)


def _room(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] != "mission" or len(parts) < 2:
        return None
    return parts[1] if parts[1] in MISSION_LAYERS else None


def _violations():
    found = []
    for path, module in _modules():
        top = module.split(".")[0]
        room = _room(module)
        for line, target in _imports(path, module):
            t_top = target.split(".")[0]
            where = f"{path.relative_to(ROOT)}:{line} imports {target}"
            if t_top in PACKAGE_RULES and t_top != top and t_top not in PACKAGE_RULES[top]:
                found.append(f"{where}: {top} must not import {t_top}")
                continue
            if top != "mission" or room is None:
                continue
            if t_top in MISSION_OUTSIDE_RULES and room not in MISSION_OUTSIDE_RULES[t_top]:
                found.append(f"{where}: only mission.{{{', '.join(sorted(MISSION_OUTSIDE_RULES[t_top]))}}} "
                             f"may import {t_top}")
            t_room = _room(target)
            if t_room is not None and MISSION_LAYERS.index(t_room) > MISSION_LAYERS.index(room):
                found.append(f"{where}: mission.{room} must not import the higher room mission.{t_room}")
    return sorted(set(found))


def test_every_module_is_in_a_room():
    loose = [m for _, m in _modules()
             if m.startswith("mission.") and _room(m) is None and m not in ("mission.__main__",)]
    assert loose == [], f"modules of mission/ outside its rooms {MISSION_LAYERS}: {loose}"


def test_imports_only_go_down():
    assert _violations() == []


@pytest.mark.parametrize("source, expected", [
    ("from mission.flight.coordinator import Coordinator\n", "mission.core must not import the higher room"),
    ("def f():\n    import sitl_mock.fleet\n", "only mission.{cli, sim} may import sitl_mock"),
])
def test_the_check_sees_an_upward_or_forbidden_import(tmp_path, monkeypatch, source, expected):
    """The check is not vacuous: a planted upward (even lazy) import is reported."""
    fake_root = tmp_path
    (fake_root / "mission" / "core").mkdir(parents=True)
    (fake_root / "mission" / "__init__.py").write_text("")
    (fake_root / "mission" / "core" / "__init__.py").write_text("")
    (fake_root / "mission" / "core" / "bad.py").write_text(source)
    for package in PACKAGE_RULES:
        (fake_root / package).mkdir(exist_ok=True)
    monkeypatch.setattr(__import__(__name__), "ROOT", fake_root)
    problems = _violations()
    assert any(expected in p and "mission/core/bad.py" in p for p in problems), problems
