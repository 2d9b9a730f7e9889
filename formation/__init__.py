"""Formation geometry for swarmseek (pure numpy/scipy/pymap3d, no I/O).

* :func:`symmetric_cylinder`: the Symmetric Cylindrical formation, paper eq. (1).
* :func:`cvt_sphere`: the CVT-based Spherical formation, paper eq. (7), with exact spherical
  Voronoi cells; :func:`lloyd_mesh` is the paper's discretised (mesh) Lloyd for comparison and
  :func:`distributed_lloyd` the asynchronous neighbour-only version.
* :func:`reconfigure` / :func:`assign_slots`: formation change after a vehicle loss and
  minimum-travel assignment of vehicles to slots.
* :func:`metrics`: d_min, r_bar, M, M_alpha, ||(n D^2/3) M^-1||, cond(M).
* :mod:`formation.geodesy`: WGS-84 <-> ENU/NED conversions (the ellipsoid maths from pymap3d).
"""
from __future__ import annotations

import importlib
import sys
import types

#: each public name and the submodule that defines it; loaded on first use (PEP 562), so that a
#: process that needs only :mod:`formation.geodesy` (a mock fleet, a sensor, ``ctl``) does not import
#: scipy.optimize and scipy.spatial (half a CPU second at every start)
_WHERE = {
    "Reconfiguration": "assignment", "assign_slots": "assignment", "kabsch_rotation": "assignment",
    "reconfigure": "assignment",
    "cvt_from": "cvt", "cvt_sphere": "cvt", "cvt_sphere_result": "cvt", "random_sphere_points": "cvt",
    "DistributedResult": "distributed", "distributed_lloyd": "distributed", "local_centroid": "distributed",
    "CVTResult": "fast_cvt",
    "MeshLloydResult": "lloyd_mesh", "fibonacci_sphere": "lloyd_mesh", "lloyd_mesh": "lloyd_mesh",
    "lloyd_mesh_result": "lloyd_mesh",
    "FormationMetrics": "metrics", "metrics": "metrics",
    "GeneratorError": "spherical_cells", "SphericalCells": "spherical_cells", "cell_areas": "spherical_cells",
    "constrained_centroids": "spherical_cells", "cvt_energy": "spherical_cells",
    "cvt_energy_gradient": "spherical_cells", "delaunay_neighbours": "spherical_cells",
    "spherical_cells": "spherical_cells",
    "THETA_F_RAD": "symmetric", "symmetric_cylinder": "symmetric", "symmetric_cylinder_dmin": "symmetric",
}


#: public functions named as the submodule that defines them: ``formation.metrics`` is the function
#: (as when this package imported every submodule at once), even after ``formation.metrics`` the
#: module was imported (the import system then sets the package's attribute to the module)
_SHADOWED = frozenset(name for name, module in _WHERE.items() if name == module)


class _Package(types.ModuleType):
    """This package's module type: a submodule import does not replace a function of its name."""

    def __setattr__(self, name: str, value) -> None:
        if name in _SHADOWED and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package


def __getattr__(name: str):
    """The public name ``name`` from its submodule (imported on first use)."""
    if name == "geodesy":
        return importlib.import_module(".geodesy", __name__)
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


__all__ = [
    "geodesy",
    "THETA_F_RAD",
    "symmetric_cylinder",
    "symmetric_cylinder_dmin",
    "cvt_sphere",
    "cvt_sphere_result",
    "cvt_from",
    "random_sphere_points",
    "CVTResult",
    "GeneratorError",
    "SphericalCells",
    "spherical_cells",
    "cell_areas",
    "constrained_centroids",
    "cvt_energy",
    "cvt_energy_gradient",
    "delaunay_neighbours",
    "FormationMetrics",
    "metrics",
    "lloyd_mesh",
    "lloyd_mesh_result",
    "MeshLloydResult",
    "fibonacci_sphere",
    "distributed_lloyd",
    "DistributedResult",
    "local_centroid",
    "assign_slots",
    "reconfigure",
    "Reconfiguration",
    "kabsch_rotation",
]
