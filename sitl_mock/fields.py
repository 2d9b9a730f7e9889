"""Simulated scalar signal fields (the simulated world's ground truth), one import for all.

Fields are defined in the mission frame, ENU metres (x east, y north, z up) about the mission
origin, and evaluate many points at once: ``value(points, t_s=0.0)`` takes ``(..., 3)`` and
returns ``(...)``; ``gradient(points, t_s=0.0)`` returns ``(..., 3)``; ``source_enu()`` is the
point a seeker should find. Static fields ignore ``t_s``; a field whose ``time_dependent``
attribute is true (the intermittent plume) reads it as simulated seconds. See ``docs/fields.md``.

* the paper's Gaussians (Sec. V), :mod:`sitl_mock.fields_gaussian`:
  ``sigma_l(r) = A_l exp(-(r - r*)^T S_l (r - r*))`` with
  ``A_1 = 100, S_1 = 1e-4 [[100,1,1],[1,1,0],[1,0,10]]`` and
  ``A_2 = 1, S_2 = 1e-4 [[20,5,2],[5,20,2],[2,2,100]]``;
* the steady Gaussian plume with wind and ground reflection, :mod:`sitl_mock.fields_plume`;
* the intermittent (puff) plume, :mod:`sitl_mock.fields_filament`;
* several sources: :class:`SumField`, or ``make_field(..., extra_sources=...)``
  (:mod:`sitl_mock.fields_config`).
"""
from __future__ import annotations

from sitl_mock.fields_config import (
    FIELD_NAMES,
    FIELD_PARAMS,
    SENSOR_PARAMS,
    field_from_table,
    make_field,
    read_field_table,
)
from sitl_mock.fields_filament import FilamentPlume
from sitl_mock.fields_gaussian import S1, S2, Field, GaussianField, SumField, sigma1, sigma2
from sitl_mock.fields_plume import STABILITY_CLASSES, GaussianPlume, briggs_sigmas

__all__ = [
    "Field",
    "GaussianField",
    "SumField",
    "GaussianPlume",
    "FilamentPlume",
    "S1",
    "S2",
    "sigma1",
    "sigma2",
    "briggs_sigmas",
    "STABILITY_CLASSES",
    "FIELD_NAMES",
    "FIELD_PARAMS",
    "SENSOR_PARAMS",
    "make_field",
    "field_from_table",
    "read_field_table",
]
