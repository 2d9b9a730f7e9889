"""Cooperative gradient estimation and gradient-ascent seeking (pure numpy, no I/O).

Public API
----------
gradient, gradient_batch, estimator_weights, GeometryError, METHODS
    Paper eq. (3) (``"symmetric"``) and Theorem 2 (``"cvt"``) estimators.
seek_step, ConvergenceMonitor, ConvergenceVerdict, convergence_scan
    The capped gradient-ascent step and the convergence test.
RobustGradientEstimator, weighted_gradient
    Weighted Theorem 2 and the online estimator that finds and sidelines faulty sensors.
SensorRetirement
    The rule that retires a persistently faulty sensor from the formation.
"""
from estimator.gradient import (
    DEFAULT_MAX_CONDITION,
    METHODS,
    GeometryError,
    estimator_weights,
    gradient,
    gradient_batch,
)
from estimator.retire import SensorRetirement
from estimator.robust import RobustGradientEstimator
from estimator.robust_wls import weighted_gradient
from estimator.seeking import ConvergenceMonitor, ConvergenceVerdict, convergence_scan, seek_step

__all__ = [
    "DEFAULT_MAX_CONDITION",
    "METHODS",
    "GeometryError",
    "estimator_weights",
    "gradient",
    "gradient_batch",
    "seek_step",
    "ConvergenceMonitor",
    "ConvergenceVerdict",
    "convergence_scan",
    "RobustGradientEstimator",
    "weighted_gradient",
    "SensorRetirement",
]
