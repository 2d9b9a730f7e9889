"""A seeker for intermittent plumes: track the upwind edge of the hit cloud (pure numpy).

On an intermittent plume (puffs advected by a meandering wind, ``docs/fields.md``) a reading
is background much of the time even on the plume's axis (about 40 % of the time there, more
off it), so a seeker comparing single readings (:class:`~estimator.seek_plume.PlumeSeeker`'s
passes) compares noise. Puffs, however, only ever exist **downwind** of the release: the most
upwind place where the signal has ever been detected (the *edge* of the cloud of hits of all
vehicles over all iterations) can only move upwind, toward the source, and stalls there. The
seeker (batched over ``K`` trials, ``propose(centre, positions, values)``):

1. **Hits**: readings above ``b + max(sigmas s, frac (peak - b))`` (:class:`~estimator.seek_signal.
   SignalFloor`: ``b`` and ``s`` the background and noise deviation from the readings' low
   quantiles, ``peak`` the highest recent reading): far above the noise (``sigmas`` 6: about one
   false hit in 10^9 readings, as the edge is a maximum over every hit) and a fraction of the
   strongest signal, so that far tails do not count.
2. **Wind axis**: ``wind_from_deg`` when given; otherwise the horizontal principal axis of the
   hit cloud (a plume is elongated along the wind), oriented toward stronger readings
   (the signal grows toward the source).
3. **Edge**: the hit with the largest upwind coordinate so far; its across-wind position is
   the reading-weighted centroid of the last ``memory`` iterations' hits within ``near_m``
   (along the wind) of the edge.
4. **Probe**: while the edge moves, the centre goes ``lead_m`` upwind of the edge on that
   centroid: the formation's upwind vehicles read the air upwind of the edge, and any puff
   there moves the edge.
5. **Hold**: the edge unmoved for ``stall`` iterations -> the centre goes ``back_m`` downwind of
   it (hits reach a little upwind of the release: a puff has the source's radius along the
   wind) and stays; a new edge resumes probing. :attr:`arrival` is "holding, with a hit this
   iteration" (background alone is never arrival).
6. **Search** (no hit yet): a square spiral across the wind about the start, ``spiral_m``
   between points, ``stall`` iterations at each (puffs come and go: wait before moving on).

The caller caps every move at ``gamma_m`` and applies the safety envelope.
"""
from __future__ import annotations

import numpy as np

from estimator.seek_inputs import seeker_inputs
from estimator.seek_plume import downwind_from_deg
from estimator.seek_signal import SignalFloor

__all__ = ["HitEdgeSeeker"]

_Z = np.array([0.0, 0.0, 1.0])


def _spiral(points: int) -> np.ndarray:
    """Unit square-spiral offsets ``(points, 2)``: (0, 0), (1, 0), (1, 1), (0, 1), (-1, 1), ..."""
    out, x, y, d, run = [(0, 0)], 0, 0, (1, 0), 1
    while len(out) < points:
        for _ in range(2):
            for _ in range(run):
                x, y = x + d[0], y + d[1]
                out.append((x, y))
            d = (-d[1], d[0])
        run += 1
    return np.array(out[:points], dtype=float)


class HitEdgeSeeker:
    """Upwind edge of the hit cloud (module docstring has the algorithm).

    Parameters
    ----------
    wind_from_deg : float or None
        Wind direction (where it comes from, degrees clockwise from north); None: estimated.
    frac : float
        Hit threshold as a fraction of the range (peak - background) seen, in (0, 1).
    sigmas : float
        ... and at least this many noise deviations above the background.
    lead_m, back_m : float
        Probe: centre this far upwind of the edge; hold: this far downwind of it.
    stall : int
        Iterations without a new edge before holding (and per search point).
    memory : int
        Iterations of hits in the across-wind centroid.
    near_m : float
        Hits within this distance (along the wind) of the edge make the centroid.
    spiral_m : float
        Spacing of the search spiral's points.
    """

    name = "plume"

    def __init__(self, wind_from_deg: float | None = None, *, frac: float = 0.05, sigmas: float = 6.0,
                 lead_m: float = 1.0, back_m: float = 1.0, stall: int = 10, memory: int = 30,
                 near_m: float = 3.0, spiral_m: float = 4.0):
        self._up_given = None if wind_from_deg is None else -downwind_from_deg(wind_from_deg)
        if not 0 < frac < 1:
            raise ValueError(f"frac must be in (0, 1), got {frac!r}")
        for name, v in (("lead_m", lead_m), ("back_m", back_m),
                        ("near_m", near_m), ("spiral_m", spiral_m)):
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
        for name, v in (("stall", stall), ("memory", memory)):
            if isinstance(v, bool) or int(v) != v or v < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
        self.floor = SignalFloor(sigmas=sigmas, rel_peak=frac)
        self.lead_m, self.back_m, self.near_m, self.spiral_m = map(float, (lead_m, back_m, near_m, spiral_m))
        self.stall, self.memory = int(stall), int(memory)
        self.reset()

    def reset(self) -> None:
        """Forget everything (a new run)."""
        self._k = None
        self.arrival = None
        self.floor.reset()

    def source_estimate(self, k: int = 0) -> None:
        """None: this seeker reacts to the latest readings and has no model of the source, so no
        region to give (where it holds, the mission reports the monitor's mean of the centres)."""
        return None

    def _init_state(self, c: np.ndarray, v: np.ndarray) -> None:
        k = c.shape[0]
        self._k, self.start = k, c.copy()
        self.edge_s, self.edge_pos = np.full(k, -np.inf), c.copy()
        self.age, self.search_i = np.zeros(k, dtype=int), np.zeros(k, dtype=int)
        self.seen = np.zeros(k, dtype=bool)
        self.cloud_sum = np.zeros((k, 6))  # weights, x, y, xx, xy, yy of the hits (horizontal)
        self.cloud_sv = np.zeros((k, 2))  # sum of w * log(v - b) * (x, y) - for the orientation
        self._buf: list = []

    def _upwind(self, p, v, hit) -> np.ndarray:
        """Unit upwind vectors ``(K, 3)``: given, else the hit cloud's axis (module doc, step 2)."""
        if self._up_given is not None:
            return np.broadcast_to(self._up_given, (self._k, 3)).copy()
        w = hit.astype(float)
        x, y = p[..., 0], p[..., 1]
        lv = np.log(np.maximum(v - self.background[:, None], 1e-12))
        self.cloud_sum += np.stack([w.sum(1), (w * x).sum(1), (w * y).sum(1), (w * x * x).sum(1),
                                    (w * x * y).sum(1), (w * y * y).sum(1)], axis=1)
        self.cloud_sv += np.stack([(w * lv * x).sum(1), (w * lv * y).sum(1)], axis=1)
        n = np.maximum(self.cloud_sum[:, 0], 1.0)
        mx, my = self.cloud_sum[:, 1] / n, self.cloud_sum[:, 2] / n
        cov = np.stack([np.stack([self.cloud_sum[:, 3] / n - mx * mx, self.cloud_sum[:, 4] / n - mx * my], 1),
                        np.stack([self.cloud_sum[:, 4] / n - mx * my, self.cloud_sum[:, 5] / n - my * my], 1)], 1)
        e = np.linalg.eigh(cov)[1][:, :, 1]
        sign = np.sign(np.einsum("ki,ki->k", self.cloud_sv / n[:, None], e) + 1e-300)
        return np.concatenate([e * sign[:, None], np.zeros((self._k, 1))], axis=1)

    def propose(self, centre, positions, values) -> np.ndarray:
        """Next centres ``(K, 3)`` from centres ``(K, 3)``, positions ``(K, N, 3)``, readings ``(K, N)``."""
        c, p, v = seeker_inputs(centre, positions, values)
        if self._k != c.shape[0]:
            self._init_state(c, v)
        hit = self.floor.update(v)
        self.background = self.floor.background
        up = self._upwind(p, v, hit)
        s = np.where(hit, np.einsum("kni,ki->kn", p, up), -np.inf)
        rows, j = np.arange(self._k), np.argmax(s, axis=1)
        if self._up_given is None:  # the axis moves: the edge is re-read along the current one
            self.edge_s = np.where(np.isfinite(self.edge_s), np.einsum("ki,ki->k", self.edge_pos, up), -np.inf)
        new = s[rows, j] > self.edge_s
        self.edge_s = np.where(new, s[rows, j], self.edge_s)
        self.edge_pos = np.where(new[:, None], p[rows, j], self.edge_pos)
        self.age = np.where(new, 0, self.age + 1)
        self.seen |= hit.any(axis=1)
        return self._target(c, p, v, hit, up)

    def _target(self, c, p, v, hit, up) -> np.ndarray:
        """Probe, hold or search (module doc, steps 3-6)."""
        self._buf = (self._buf + [(p, np.where(hit, v - self.background[:, None], 0.0))])[-self.memory:]
        pw = np.concatenate([b[0] for b in self._buf], axis=1)
        ww = np.concatenate([b[1] for b in self._buf], axis=1)
        edge_s = np.where(np.isfinite(self.edge_s), self.edge_s, np.einsum("ki,ki->k", c, up))
        ww = np.where(np.einsum("kni,ki->kn", pw, up) > (edge_s - self.near_m)[:, None], ww, 0.0)
        tot = ww.sum(axis=1)
        cen = np.einsum("kn,kni->ki", ww, pw) / np.where(tot > 0, tot, 1.0)[:, None]
        cen = np.where((tot > 0)[:, None], cen, self.edge_pos)
        across = cen - np.einsum("ki,ki->k", cen, up)[:, None] * up
        holding = self.age >= self.stall
        along = np.where(holding, edge_s - self.back_m, edge_s + self.lead_m)
        out = across + along[:, None] * up
        self.arrival = self.seen & holding & hit.any(axis=1)
        return np.where(self.seen[:, None], out, self._search(c, up))

    def _search(self, c, up) -> np.ndarray:
        """Square spiral across the wind about the start, ``stall`` iterations per point."""
        table = _spiral(49)
        e1 = np.cross(_Z, up)
        e1 /= np.maximum(np.linalg.norm(e1, axis=1, keepdims=True), 1e-12)
        self.search_i = np.where(self.seen, self.search_i, self.search_i + 1)
        xy = table[np.minimum(self.search_i // self.stall, len(table) - 1)] * self.spiral_m
        return self.start + xy[:, :1] * e1 + xy[:, 1:] * _Z
