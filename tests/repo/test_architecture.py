"""The rooms and their one-way doors (docs/architecture.md), checked on the source.

Every import (module level or inside a function: a lazy import ties two modules together just
the same) is read with ``ast``; an import that goes up a layer, or into a room a package must
not know, fails with the file, the line and the rule it breaks.
"""
from __future__ import annotations

import ast
import functools
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

#: the ground station's rooms, lowest first: a room may import only rooms before it
MISSION_LAYERS = ["core", "link", "vehicle", "telemetry", "safety", "flight", "sim", "cli"]

#: top-level packages and the project packages each may import (besides itself)
PACKAGE_RULES = {
    "wire": set(),
    "formation": set(),
    "estimator": {"formation"},
    "sitl_mock": {"formation", "estimator", "wire", "companion"},
    "experiments": {"formation", "estimator", "sitl_mock", "wire"},
    "mission": {"formation", "estimator", "sitl_mock", "experiments", "wire"},
    "companion": {"wire"},
}
#: within mission, the rooms that may import the simulated world and the experiments
MISSION_OUTSIDE_RULES = {"sitl_mock": {"sim"}, "experiments": {"cli"}}
#: and the single modules besides them: ``run`` launches the simulated world (the mock fleet,
#: its clock and its field flags); every other command (``watch``, ``ctl``, ``sitl``, ...) shares
#: only ``wire`` with the simulator
MISSION_OUTSIDE_MODULES = {"sitl_mock": {"mission.cli.cmd_run"}}


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
            if (t_top in MISSION_OUTSIDE_RULES and room not in MISSION_OUTSIDE_RULES[t_top]
                    and module not in MISSION_OUTSIDE_MODULES.get(t_top, ())):
                allowed = sorted(f"mission.{r}" for r in MISSION_OUTSIDE_RULES[t_top])
                allowed += sorted(MISSION_OUTSIDE_MODULES.get(t_top, ()))
                found.append(f"{where}: only {{{', '.join(allowed)}}} may import {t_top}")
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


@pytest.mark.parametrize("where, source, expected", [
    ("mission/core/bad.py", "from mission.flight.coordinator import Coordinator\n",
     "mission.core must not import the higher room"),
    ("mission/core/bad.py", "def f():\n    import sitl_mock.fleet\n",
     "only {mission.sim, mission.cli.cmd_run} may import sitl_mock"),
    ("mission/cli/cmd_watch.py", "from sitl_mock.sensor import sensor_key\n",
     "only {mission.sim, mission.cli.cmd_run} may import sitl_mock"),
    ("wire/bad.py", "from mission.core.plan import parse_plan\n", "wire must not import mission"),
    ("wire/bad.py", "def f():\n    from sitl_mock import fields\n", "wire must not import sitl_mock"),
    ("formation/bad.py", "import wire.fleet_name\n", "formation must not import wire"),
    ("companion/bad.py", "def f():\n    import sitl_mock.fleet\n", "companion must not import sitl_mock"),
    ("mission/cli/bad.py", "from companion.publisher import Publisher\n", "mission must not import companion"),
])
def test_the_check_sees_an_upward_or_forbidden_import(tmp_path, monkeypatch, where, source, expected):
    """The check is not vacuous: a planted upward (even lazy) import is reported."""
    fake_root = tmp_path
    for package in PACKAGE_RULES:
        (fake_root / package).mkdir(exist_ok=True)
        (fake_root / package / "__init__.py").write_text("")
    bad = fake_root / where
    bad.parent.mkdir(parents=True, exist_ok=True)
    (bad.parent / "__init__.py").write_text("")
    bad.write_text(source)
    monkeypatch.setattr(sys.modules[__name__], "ROOT", fake_root)
    problems = _violations()
    assert any(expected in p and where in p for p in problems), problems


def test_the_run_command_may_import_the_simulated_world(tmp_path, monkeypatch):
    """The one exception of the stricter rule holds (and only for that module)."""
    for package in PACKAGE_RULES:
        (tmp_path / package).mkdir(exist_ok=True)
    (tmp_path / "mission" / "cli").mkdir()
    (tmp_path / "mission" / "cli" / "cmd_run.py").write_text("from sitl_mock.fleet import MockFleet\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    assert _violations() == []


def _module_file(module: str) -> Path | None:
    """The source file of one of our modules (``None`` for a package or a foreign module)."""
    path = ROOT.joinpath(*module.split(".")).with_suffix(".py")
    return path if module.split(".")[0] in PACKAGE_RULES and path.is_file() else None


@functools.lru_cache(maxsize=None)
def _borrowed_names(path: Path, module: str) -> dict[str, str]:
    """Names that ``path`` binds at module level by importing them from another of our modules
    (name -> that module); a submodule imported by name (``from pkg import mod``) is not one."""
    borrowed = {}
    for node in ast.parse(path.read_text(encoding="utf-8"), str(path)).body:
        if not isinstance(node, ast.ImportFrom):
            continue
        base = _from_module(node, module, path.name == "__init__.py")
        if base.split(".")[0] not in PACKAGE_RULES:
            continue
        for alias in node.names:
            if _module_file(f"{base}.{alias.name}") is None and not (
                    ROOT.joinpath(*base.split("."), alias.name).is_dir()):
                borrowed[alias.asname or alias.name] = base
    return borrowed


def _from_module(node: ast.ImportFrom, module: str, is_package: bool) -> str:
    """The absolute module a ``from ... import`` in ``module`` reads from."""
    if not node.level:
        return node.module or ""
    parts = (module if is_package else module.rpartition(".")[0]).split(".")
    parts = parts[: len(parts) - node.level + 1]
    return ".".join(parts + ([node.module] if node.module else []))


def _reexports() -> list[str]:
    """Modules (not package ``__init__``s) listing in ``__all__`` a name imported from another."""
    found = []
    for path, module in _modules():
        if path.name == "__init__.py":
            continue
        borrowed = _borrowed_names(path, module)
        for node in ast.parse(path.read_text(encoding="utf-8"), str(path)).body:
            if isinstance(node, ast.Assign) and any(
                    isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets):
                for name in ast.literal_eval(node.value):
                    if name in borrowed:
                        found.append(f"{path.relative_to(ROOT)}: __all__ re-exports {name} "
                                     f"(defined in {borrowed[name]}); import it from there")
    return found


def _imports_through_a_shim() -> list[str]:
    """Imports, anywhere in the repository, of a name from a module that only imported it."""
    found = []
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT)
        if rel.parts[0].startswith("."):
            continue
        parts = list(rel.with_suffix("").parts)
        module = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if not isinstance(node, ast.ImportFrom):
                continue
            base = _from_module(node, module, path.name == "__init__.py")
            source = _module_file(base)
            if source is None or source.name == "__init__.py":
                continue
            borrowed = _borrowed_names(source, base)
            for alias in node.names:
                if alias.name in borrowed:
                    found.append(f"{rel}:{node.lineno} imports {alias.name} from {base}; "
                                 f"it is defined in {borrowed[alias.name]}")
    return found


def test_no_module_re_exports_what_another_defines():
    """One import path per name: a module's ``__all__`` lists only what it defines (package
    ``__init__`` files, the documented public API of ``formation`` and ``estimator``, excepted)."""
    assert _reexports() == []


def test_every_name_is_imported_from_the_module_that_defines_it():
    assert _imports_through_a_shim() == []


def test_the_shim_checks_see_a_planted_shim(tmp_path, monkeypatch):
    """Not vacuous: a module re-exporting an imported name, and an import through it, are reported."""
    for package in PACKAGE_RULES:
        (tmp_path / package).mkdir()
        (tmp_path / package / "__init__.py").write_text("")
    (tmp_path / "wire" / "real.py").write_text("def thing():\n    return 1\n")
    (tmp_path / "wire" / "shim.py").write_text(
        "from wire.real import thing\nfrom wire import real\n\n__all__ = [\"thing\", \"real\"]\n")
    (tmp_path / "mission" / "user.py").write_text(
        "def f():\n    from wire.shim import thing, real\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    assert _reexports() == [
        "wire/shim.py: __all__ re-exports thing (defined in wire.real); import it from there"]
    assert _imports_through_a_shim() == [
        "mission/user.py:2 imports thing from wire.shim; it is defined in wire.real"]


#: inside ``mission.flight``: the builder (the only module that holds the coordinator) and the
#: groups whose doors it keeps: the phases are built by the builder only, the fault responses
#: never reach up into a phase, and nothing below the builder imports it
FLIGHT_BUILDER = "mission.flight.coordinator"
FLIGHT_PHASES = "mission.flight.phases"
FLIGHT_FAULTS = "mission.flight.faults"


def _inside(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def _flight_violations() -> list[str]:
    """Imports that break the flight room's inner doors (docs/architecture.md, "How a phase gets
    what it uses"): a phase imported by a flight module other than the builder or another phase;
    a fault response importing a phase; any mission module but the commands importing the builder."""
    found = []
    for path, module in _modules():
        if not _inside(module, "mission"):
            continue
        for line, target in _imports(path, module):
            where = f"{path.relative_to(ROOT)}:{line} imports {target}"
            if (_inside(target, FLIGHT_PHASES) and _inside(module, "mission.flight")
                    and module != FLIGHT_BUILDER and not _inside(module, FLIGHT_PHASES)):
                found.append(f"{where}: only {FLIGHT_BUILDER} builds the phases")
            if _inside(target, FLIGHT_PHASES) and _inside(module, FLIGHT_FAULTS):
                found.append(f"{where}: a fault response must not import a phase")
            if (_inside(target, FLIGHT_BUILDER) and module != FLIGHT_BUILDER
                    and not _inside(module, "mission.cli") and not _inside(module, "mission.sim")):
                found.append(f"{where}: only the commands (mission.cli, mission.sim) use the coordinator")
    return sorted(set(found))


def _functions_taking_the_coordinator() -> list[str]:
    """Functions of ``mission`` outside the builder whose first parameter (after ``self``/``cls``)
    is the coordinator ``co``."""
    found = []
    for path, module in _modules():
        if not _inside(module, "mission") or module == FLIGHT_BUILDER:
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                names = [a.arg for a in node.args.posonlyargs + node.args.args]
                names = names[1:] if names and names[0] in ("self", "cls") else names
                if names and names[0] == "co":
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name}(co, ...)")
    return found


def test_the_flight_room_keeps_its_inner_doors():
    assert _flight_violations() == []


def test_no_function_outside_the_builder_takes_the_coordinator():
    """A phase, a fault response or a helper is handed narrow services, never the coordinator."""
    assert _functions_taking_the_coordinator() == []


@pytest.mark.parametrize("where, source, expected", [
    ("mission/flight/return_clear.py", "def f():\n    from mission.flight.phases.seek import Seek\n",
     "only mission.flight.coordinator builds the phases"),
    ("mission/flight/faults/loss.py", "from mission.flight.phases.takeoff import Takeoff\n",
     "a fault response must not import a phase"),
    ("mission/flight/phases/seek.py", "from mission.flight.coordinator import Coordinator\n",
     "only the commands (mission.cli, mission.sim) use the coordinator"),
])
def test_the_flight_check_sees_a_planted_import(tmp_path, monkeypatch, where, source, expected):
    """Not vacuous: each inner door, broken by a planted (even lazy) import, is reported."""
    for package in PACKAGE_RULES:
        (tmp_path / package).mkdir(exist_ok=True)
    bad = tmp_path / where
    bad.parent.mkdir(parents=True, exist_ok=True)
    bad.write_text(source)
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    problems = _flight_violations()
    assert any(expected in p and where in p for p in problems), problems


def test_the_coordinator_check_sees_a_planted_function(tmp_path, monkeypatch):
    for package in PACKAGE_RULES:
        (tmp_path / package).mkdir(exist_ok=True)
    (tmp_path / "mission" / "flight").mkdir(parents=True)
    (tmp_path / "mission" / "flight" / "coordinator.py").write_text("def builder(co):\n    return co\n")
    (tmp_path / "mission" / "flight" / "helper.py").write_text(
        "class Helper:\n    async def move(self, co, goals):\n        return goals\n\n\ndef ok(state, co):\n    pass\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    assert _functions_taking_the_coordinator() == ["mission/flight/helper.py:2 move(co, ...)"]
