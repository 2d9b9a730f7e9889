"""Processes that need only geodesy (a mock fleet, a sensor, ``ctl``) start without scipy.

``formation`` loads its submodules on first use and the plume models import scipy.special at their
first call: scipy.optimize, scipy.spatial and scipy.special cost about a CPU second at every start of
a mock fleet (1.1 -> 0.5 CPU s measured for ``swarmseek mock --help``).
"""
from __future__ import annotations

import json
import subprocess
import sys
import types

import pytest

import formation

_SCIPY_HEAVY = ("scipy.optimize", "scipy.spatial", "scipy.special")


def _modules_after(statement: str) -> set[str]:
    code = f"import sys, json\n{statement}\nprint(json.dumps(sorted(sys.modules)))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return set(json.loads(done.stdout.splitlines()[-1]))


@pytest.mark.parametrize("statement", [
    "import formation.geodesy",
    "import sitl_mock.fleet",
    "import sitl_mock.fields_config",
    "import mission.cli.cmd_ctl",
])
def test_geodesy_users_start_without_scipy(statement):
    loaded = _modules_after(statement)
    assert not [m for m in _SCIPY_HEAVY if m in loaded], sorted(m for m in loaded if m.startswith("scipy."))


def test_the_ground_station_loads_what_it_reforms_with_at_start():
    """Not in its event loop at the first loss: the re-formation's modules come with the flight code."""
    loaded = _modules_after("import mission.flight.faults.loss, mission.flight.faults.rejoin")
    assert {"formation.assignment", "formation.cvt", "formation.symmetric", "scipy.optimize"} <= loaded


@pytest.mark.parametrize("name", formation.__all__)
def test_every_public_name_resolves(name):
    value = getattr(formation, name)
    assert not isinstance(value, types.ModuleType) or name == "geodesy"


def test_a_function_named_as_its_module_stays_the_function():
    import formation.lloyd_mesh  # noqa: F401  (the import sets the package's attribute, normally)
    import formation.metrics  # noqa: F401
    import formation.spherical_cells  # noqa: F401

    for name in ("metrics", "spherical_cells", "lloyd_mesh"):
        assert callable(getattr(formation, name)) and not isinstance(getattr(formation, name), types.ModuleType)
    assert formation.metrics is sys.modules["formation.metrics"].metrics


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'cvt_cube'"):
        formation.cvt_cube  # noqa: B018
