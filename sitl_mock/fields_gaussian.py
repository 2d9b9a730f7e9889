"""The paper's Gaussian fields, the sum of fields (several sources) and the field protocol.

Fields are defined in the mission frame, ENU metres (x east, y north, z up) about the mission
origin. Every field evaluates many points at once: ``value(points, t_s=0.0)`` takes
``(..., 3)`` and returns ``(...)``; ``gradient(points, t_s=0.0)`` returns ``(..., 3)``. Static
fields ignore ``t_s``; time-dependent ones (:class:`sitl_mock.fields_filament.FilamentPlume`)
take it as simulated seconds (a scalar, or an array broadcastable to ``points.shape[:-1]``).

The paper's fields (Sec. V): ``sigma_l(r) = A_l exp(-(r - r*)^T S_l (r - r*))`` with
``A_1 = 100, S_1 = 1e-4 [[100,1,1],[1,1,0],[1,0,10]]`` and
``A_2 = 1, S_2 = 1e-4 [[20,5,2],[5,20,2],[2,2,100]]``.
"""
from __future__ import annotations

from dataclasses import dataclass, field as dc_field
from typing import Protocol, Sequence

import numpy as np

__all__ = ["Field", "GaussianField", "SumField", "S1", "S2", "sigma1", "sigma2"]

S1 = 1e-4 * np.array([[100.0, 1.0, 1.0], [1.0, 1.0, 0.0], [1.0, 0.0, 10.0]])
S2 = 1e-4 * np.array([[20.0, 5.0, 2.0], [5.0, 20.0, 2.0], [2.0, 2.0, 100.0]])


class Field(Protocol):
    """What the world, the sensors and the offline simulation need from a field."""

    def value(self, points: np.ndarray, t_s=0.0) -> np.ndarray: ...

    def gradient(self, points: np.ndarray, t_s=0.0) -> np.ndarray: ...

    def source_enu(self) -> np.ndarray: ...


@dataclass(frozen=True)
class GaussianField:
    """Anisotropic Gaussian ``A exp(-(r - r0)^T S (r - r0))``.

    Parameters
    ----------
    amplitude : float
        Peak value ``A`` (> 0) at the source.
    S : array_like, shape (3, 3)
        Symmetric positive-definite shape matrix, 1/m^2.
    source : array_like, shape (3,)
        Source position ``r0``, ENU metres in the mission frame.
    """

    amplitude: float
    S: np.ndarray
    source: np.ndarray = dc_field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        S = np.asarray(self.S, dtype=float)
        src = np.asarray(self.source, dtype=float).reshape(3)
        if S.shape != (3, 3):
            raise ValueError(f"S must be 3x3, got shape {S.shape}")
        if not np.allclose(S, S.T):
            raise ValueError("S must be symmetric")
        if np.any(np.linalg.eigvalsh(S) <= 0):
            raise ValueError("S must be positive definite (the field must decay in every direction)")
        if not (np.isfinite(self.amplitude) and self.amplitude > 0):
            raise ValueError(f"amplitude must be a positive finite number, got {self.amplitude!r}")
        object.__setattr__(self, "S", S)
        object.__setattr__(self, "source", src)

    def value(self, points, t_s=0.0):
        """Field value at ``points`` (..., 3), shape (...); ``t_s`` is ignored (static field)."""
        d = np.asarray(points, dtype=float) - self.source
        q = np.einsum("...i,ij,...j->...", d, self.S, d)
        return self.amplitude * np.exp(-q)

    def gradient(self, points, t_s=0.0):
        """Exact gradient, shape (..., 3); ``t_s`` is ignored."""
        d = np.asarray(points, dtype=float) - self.source
        v = self.value(points)
        return -2.0 * v[..., None] * (d @ self.S)

    def hessian(self, points):
        """Exact Hessian, shape ``(..., 3, 3)``."""
        d = np.asarray(points, dtype=float) - self.source
        v = self.value(points)[..., None, None]
        sd = d @ self.S
        return v * (4.0 * sd[..., :, None] * sd[..., None, :] - 2.0 * self.S)

    def source_enu(self):
        return self.source.copy()


@dataclass(frozen=True)
class SumField:
    """Sum of several fields (several sources) plus a constant ``background``.

    ``source_enu`` is the release point of the strongest part when every part has a
    ``release_enu`` (plumes: the part whose summed value is highest at its own release point);
    otherwise the global maximum's location, found by quasi-Newton ascent started from each
    part's source. :meth:`sources_enu` lists every part's source.
    """

    parts: Sequence
    background: float = 0.0

    def __post_init__(self):
        if len(self.parts) < 1:
            raise ValueError("a SumField needs at least one part")
        if not (np.isfinite(self.background) and self.background >= 0.0):
            raise ValueError(f"background must be a finite number >= 0, got {self.background!r}")
        object.__setattr__(self, "parts", tuple(self.parts))

    @property
    def time_dependent(self) -> bool:
        """True when a part's value depends on time."""
        return any(getattr(p, "time_dependent", False) for p in self.parts)

    def value(self, points, t_s=0.0):
        """Sum of the parts' values plus the background, shape (...)."""
        return sum(p.value(points, t_s) for p in self.parts) + self.background

    def gradient(self, points, t_s=0.0):
        """Sum of the parts' gradients, shape (..., 3)."""
        return sum(p.gradient(points, t_s) for p in self.parts)

    def sources_enu(self) -> np.ndarray:
        """Every part's source, shape (P, 3)."""
        return np.array([p.source_enu() for p in self.parts], dtype=float)

    def source_enu(self):
        """The source a seeker should find (see the class docstring)."""
        if all(hasattr(p, "release_enu") for p in self.parts):
            rel = self.sources_enu()
            return rel[int(np.argmax(self.value(rel)))].copy()
        from scipy.optimize import minimize

        best, best_v = None, -np.inf
        for p in self.parts:
            res = minimize(
                lambda x: -float(self.value(x)),
                p.source_enu(),
                jac=lambda x: -self.gradient(x),
                method="BFGS",
                options={"gtol": 1e-12},
            )
            v = float(self.value(res.x))
            if v > best_v:
                best, best_v = res.x, v
        return np.asarray(best, dtype=float)


def sigma1(source=(0.0, 0.0, 0.0)) -> GaussianField:
    """The paper's strong, noise-free field: ``A_1 = 100``, ``S_1``."""
    return GaussianField(100.0, S1, np.asarray(source, dtype=float))


def sigma2(source=(0.0, 0.0, 0.0)) -> GaussianField:
    """The paper's weak field used with noise: ``A_2 = 1``, ``S_2``."""
    return GaussianField(1.0, S2, np.asarray(source, dtype=float))
