"""The seekers' common input check (pure numpy)."""
from __future__ import annotations

import numpy as np

__all__ = ["seeker_inputs"]


def seeker_inputs(centre, positions, values):
    """``(centre (K, 3), positions (K, N, 3), values (K, N))`` as float arrays; ``(N, 3)``/``(N,)``
    positions/values are one trial.

    Raises
    ------
    ValueError
        Shapes that do not match, or values that are not finite.
    """
    c = np.atleast_2d(np.asarray(centre, dtype=float))
    p = np.asarray(positions, dtype=float)
    v = np.asarray(values, dtype=float)
    if p.ndim == 2:
        p, v = p[None], v[None]
    if c.shape[-1] != 3 or p.shape[:1] != c.shape[:1] or p.shape[-1] != 3 or v.shape != p.shape[:2]:
        raise ValueError(f"expected centre (K,3), positions (K,N,3), values (K,N); got {c.shape}, {p.shape}, {v.shape}")
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(p)) and np.all(np.isfinite(v))):
        raise ValueError("centre, positions and values must be finite")
    return c, p, v
