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
from . import geodesy
from .assignment import Reconfiguration, assign_slots, kabsch_rotation, reconfigure
from .cvt import cvt_from, cvt_sphere, cvt_sphere_result, random_sphere_points
from .distributed import DistributedResult, distributed_lloyd, local_centroid
from .fast_cvt import CVTResult
from .lloyd_mesh import MeshLloydResult, fibonacci_sphere, lloyd_mesh, lloyd_mesh_result
from .metrics import FormationMetrics, metrics
from .spherical_cells import (
    GeneratorError,
    SphericalCells,
    cell_areas,
    constrained_centroids,
    cvt_energy,
    cvt_energy_gradient,
    delaunay_neighbours,
    spherical_cells,
)
from .symmetric import THETA_F_RAD, symmetric_cylinder, symmetric_cylinder_dmin

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
