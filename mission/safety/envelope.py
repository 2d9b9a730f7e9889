"""The safety envelope: geofence, altitude band, speed limit and separation (pure maths).

Everything is in the mission ENU frame (metres): ``x = east_m``, ``y = north_m``, ``z = up_m``
about the mission origin (``docs/interfaces.md``). Altitudes of the band are mission-frame ``up_m``.

The rule the mission relies on: **no setpoint leaves the geofence or the altitude band, ever,
whatever the maths says.** :meth:`SafetyEnvelope.clamp_setpoints` makes setpoints safe (inside
the fence and band, speed-limited, separated: vehicles that would come too close are held at their
previous setpoints, :mod:`mission.safety.separation`) and ends with
:meth:`SafetyEnvelope.assert_safe`, which raises :class:`SafetyViolation` if anything would still leave.

Separation is checked on the paths, not only on the end points: two vehicles flying straight
lines simultaneously at constant speed (start together, arrive together) are closest at a time
given in closed form (:func:`mission.safety.geometry.synchronous_distance`).
:func:`plan_transfer` (in :mod:`mission.safety.transfer`) plans assembly, reconfiguration and
return moves that keep separation.
"""
from __future__ import annotations

import numpy as np

from mission.safety.geometry import (
    boundary_distance,
    inside_fraction,
    synchronous_distance,
)
from mission.safety.report import (
    CentreClamp,
    ClampedSetpoints,
    EmptyFenceError,
    SafetyError,
    SafetyViolation,
    SetpointReport,
    Violation,
)
from mission.safety.fence import Geofence, _as_points
from mission.safety.separation import close_pairs as _close_pairs
from mission.safety.separation import hold_for_separation

__all__ = ["SafetyEnvelope", "pairwise_path_separation"]

#: numerical slack (m) when checking a point against a boundary it was projected onto
_TOL_M = 1e-7


def _mask(mask, n: int) -> np.ndarray:
    return np.zeros(n, dtype=bool) if mask is None else mask


def pairwise_path_separation(prev_positions, new_positions) -> np.ndarray:
    """``(N, N)`` minimum distance of each pair flying straight ``prev -> new`` simultaneously
    (diagonal = +inf)."""
    p0 = np.asarray(prev_positions, dtype=float)
    p1 = np.asarray(new_positions, dtype=float)
    d = synchronous_distance(p0[:, None], p1[:, None], p0[None, :], p1[None, :])
    np.fill_diagonal(d, np.inf)
    return d


class SafetyEnvelope:
    """Geofence, speed limit and minimum separation for a formation of radius ``D``.

    Parameters
    ----------
    fence : Geofence
        The hard fence for every vehicle.
    max_speed_m_s : float
        Speed limit of every vehicle (> 0).
    min_separation_m : float
        Minimum distance between any two vehicles (>= 0), on paths and end points.
    formation_radius_m : float
        Radius of the formation; the centre is kept inside the fence shrunk by it.

    Raises
    ------
    SafetyError
        Bad limits; :class:`EmptyFenceError` if the fence cannot hold the formation.
    """

    def __init__(self, fence: Geofence, max_speed_m_s: float, min_separation_m: float,
                 formation_radius_m: float):
        if not isinstance(fence, Geofence):
            raise SafetyError(f"fence must be a Geofence, got {type(fence).__name__}")
        for name, val, strict in (("max_speed_m_s", max_speed_m_s, True),
                                  ("min_separation_m", min_separation_m, False),
                                  ("formation_radius_m", formation_radius_m, False)):
            if not isinstance(val, (int, float, np.floating, np.integer)) or not np.isfinite(val) \
                    or (val <= 0 if strict else val < 0):
                raise SafetyError(f"{name} must be a finite number {'> 0' if strict else '>= 0'}, got {val!r}")
        self.fence = fence
        self.max_speed_m_s = float(max_speed_m_s)
        self.min_separation_m = float(min_separation_m)
        self.formation_radius_m = float(formation_radius_m)
        try:
            self.centre_fence = fence.shrunk(self.formation_radius_m)
        except EmptyFenceError as exc:
            raise EmptyFenceError(f"the formation (radius {self.formation_radius_m:g} m) does not fit "
                                  f"in the geofence: {exc}") from None

    def clamp_centre(self, centre_prev, centre_new) -> CentreClamp:
        """Keep the formation centre inside the fence shrunk by the radius.

        If ``centre_new`` is outside, or the straight move from ``centre_prev`` leaves the
        shrunk fence (non-convex fences), the centre stops at the boundary and
        ``at_boundary`` is set with a message saying so. A ``centre_prev`` outside the shrunk
        fence is ignored (the nearest allowed point of ``centre_new`` is used).
        """
        prev = _as_points(centre_prev, "centre_prev").reshape(3)
        new = _as_points(centre_new, "centre_new").reshape(3)
        inner = self.centre_fence
        target = inner.clamp(new)
        clamped = not inner.contains(new)
        if inner.contains(prev) and not inner.segment_inside(prev, target):
            target = inner.last_inside_point(prev, target)
            clamped = True
        msg = ""
        if clamped:
            why = ("is outside" if not inner.contains(new)
                   else "cannot be reached in a straight line inside")
            msg = (f"requested centre ({new[0]:.2f}, {new[1]:.2f}, {new[2]:.2f}) {why} the fence "
                   f"shrunk by the formation radius {self.formation_radius_m:g} m: stopped at the "
                   f"boundary ({target[0]:.2f}, {target[1]:.2f}, {target[2]:.2f}), "
                   f"{float(np.linalg.norm(new - target)):.2f} m short")
        return CentreClamp(target, clamped, new, msg)

    def check_setpoints(self, prev_positions, new_positions, dt_s: float) -> SetpointReport:
        """Every violation of moving all vehicles ``prev -> new`` in ``dt_s`` seconds.

        Checks the new setpoints against the fence and band, each straight path against the
        (possibly non-convex) fence, speed ``||new - prev|| / dt_s``, and separation at the end
        points and along the simultaneous straight-line paths.
        """
        p0, p1 = self._check_shapes(prev_positions, new_positions, dt_s)
        return self._check(p0, p1, dt_s)

    def _check(self, p0, p1, dt_s, pairs=None, horiz_in0=None, horiz_in=None) -> SetpointReport:
        """:meth:`check_setpoints` on checked arrays; ``pairs``: ``_close_pairs(p0, p1, sep)``,
        ``horiz_in0`` / ``horiz_in``: ``fence.horizontal_contains`` of ``p0`` / ``p1`` if known."""
        out = []
        n = len(p0)
        fence = self.fence
        poly = fence.polygon_en_m
        horiz_in = fence.horizontal_contains(p1, _TOL_M) if horiz_in is None else horiz_in
        horiz_in0 = fence.horizontal_contains(p0, _TOL_M) if horiz_in0 is None else horiz_in0
        # paths: horizontal part only (the band is convex), for vehicles that start inside
        if fence.convex and horiz_in.all():
            # a segment between inside points of a convex polygon is inside: no path leaves
            path_out = np.zeros(n, dtype=bool)
        else:
            flat0 = np.c_[p0[:, :2], np.full(n, fence.min_alt_m)]
            flat1 = np.c_[p1[:, :2], np.full(n, fence.min_alt_m)]
            path_out = horiz_in & horiz_in0 & ~np.atleast_1d(fence.segment_inside(flat0, flat1))
        z = p1[:, 2]
        low, high = z < fence.min_alt_m - _TOL_M, z > fence.max_alt_m + _TOL_M
        for i in np.flatnonzero(~horiz_in):
            d = float(boundary_distance(p1[i, :2], poly))
            out.append(Violation("fence", (int(i),), d, 0.0, f"vehicle {i} setpoint is {d:.2f} m outside the geofence"))
        for i in np.flatnonzero(path_out):
            out.append(Violation("fence_path", (int(i),), 0.0, 0.0,
                                 f"vehicle {i} path leaves the geofence between its setpoints"))
        for i in np.flatnonzero(low | high):
            out.append(Violation("altitude", (int(i),), float(z[i]), fence.min_alt_m if low[i] else fence.max_alt_m,
                                 f"vehicle {i} setpoint altitude {z[i]:.2f} m is outside the band "
                                 f"{fence.min_alt_m:g}..{fence.max_alt_m:g} m"))
        speed = np.linalg.norm(p1 - p0, axis=1) / dt_s
        for i in np.nonzero(speed > self.max_speed_m_s * (1 + 1e-9) + 1e-12)[0]:
            out.append(Violation("speed", (int(i),), float(speed[i]), self.max_speed_m_s,
                                 f"vehicle {i} would fly {speed[i]:.2f} m/s > limit {self.max_speed_m_s:g} m/s"))
        sep_min = float("inf")
        if n >= 2:
            ii, jj, d_path, d_end = _close_pairs(p0, p1, self.min_separation_m) if pairs is None else pairs
            sep_min = float(d_path.min()) if len(d_path) else float("inf")
            lim = self.min_separation_m * (1 - 1e-9)
            for i, j, de in zip(ii, jj, d_end):
                if de < lim:
                    out.append(Violation("separation", (int(i), int(j)), float(de), self.min_separation_m,
                                         f"vehicles {i} and {j} setpoints {de:.2f} m apart "
                                         f"< {self.min_separation_m:g} m"))
            for i, j, dp, de in zip(ii, jj, d_path, d_end):
                if dp < lim <= de:
                    out.append(Violation("separation_path", (int(i), int(j)), float(dp), self.min_separation_m,
                                         f"vehicles {i} and {j} come {dp:.2f} m close on their "
                                         f"paths < {self.min_separation_m:g} m"))
        return SetpointReport(tuple(out), sep_min, float(speed.max()) if n else 0.0)

    def clamp_setpoints(self, prev_positions, new_positions, dt_s: float) -> ClampedSetpoints:
        """Safe setpoints: inside the fence and band, speed-limited, separated.

        Each new setpoint is moved to the nearest point of the fence; if the straight path from
        the previous position leaves a non-convex fence, it stops where it would leave; the
        step is then scaled to at most ``max_speed_m_s * dt_s``. The fence wins over the speed
        limit: a vehicle whose previous position is outside the fence gets the nearest inside
        point (and a ``speed`` violation in the report if that is too far). Last, separation is
        enforced: every vehicle of a pair that would come closer than ``min_separation_m``
        (end points, or on the simultaneous straight paths) is held at its previous setpoint,
        and again for the pairs those holds create, until none is left
        (:func:`mission.safety.separation.hold_for_separation`: if the previous batch was
        separated, the result is; a pair that already started closer may not come closer).
        Holding is inside the fence and within the speed limit, so the fence still holds. Then
        each held vehicle is moved aside where a shorter or sideways step keeps every pair
        separated and stays inside the fence (checked here), so that a pair that wants to cross
        is not frozen for good.

        Returns
        -------
        ClampedSetpoints
            With ``separation_held`` (the vehicles held), ``separation_conflicts`` and
            ``separation_note`` (why).

        Raises
        ------
        SafetyViolation
            If a setpoint would still be outside the fence or band (never expected).
        """
        p0, p1 = self._check_shapes(prev_positions, new_positions, dt_s)
        fence = self.fence
        horiz_in0 = fence.horizontal_contains(p0, _TOL_M)
        inside0 = horiz_in0 & fence.band_contains(p0[:, 2], _TOL_M)  # fence.contains(p0)
        out, fence_clamped, speed_limited = self._clamp_fence_speed(p0, p1, dt_s, horiz_in0, inside0)
        pairs = _close_pairs(p0, out, self.min_separation_m) if len(p0) >= 2 else None
        hold = hold_for_separation(p0, out, self.min_separation_m, inside0, pairs, allowed=self._move_allowed)
        out = hold.positions_enu
        horiz_in = fence.horizontal_contains(out, _TOL_M)
        self._assert_safe(p0, out, dt_s, inside0, horiz_in & fence.band_contains(out[:, 2], _TOL_M))
        report = self._check(p0, out, dt_s, pairs if not hold.conflicts else None, horiz_in0, horiz_in)
        return ClampedSetpoints(out, fence_clamped, speed_limited, report, hold.held,
                                hold.describe(self.min_separation_m), hold.conflicts,
                                _mask(hold.moved_aside, len(p0)))

    def _move_allowed(self, start, end) -> np.ndarray:
        """Whether each straight move ``start -> end`` (``(K, 3)``, starts inside) stays inside the
        fence and band: a vehicle moved aside for separation (the speed is the caller's)."""
        fence = self.fence
        ok = np.atleast_1d(fence.contains(end, _TOL_M))
        if not fence.convex and ok.any():
            n = len(start)
            flat0 = np.c_[start[:, :2], np.full(n, fence.min_alt_m)]
            flat1 = np.c_[end[:, :2], np.full(n, fence.min_alt_m)]
            ok &= np.atleast_1d(fence.segment_inside(flat0, flat1))
        return ok

    def _clamp_fence_speed(self, p0, p1, dt_s, inside0_h, inside0):
        """Steps (1) to (3) of :meth:`clamp_setpoints`: ``(out, fence_clamped, speed_limited)``;
        ``inside0_h`` / ``inside0``: ``p0`` inside the polygon / the prism."""
        fence = self.fence
        out = fence.clamp(p1)
        fence_clamped = np.any(out != p1, axis=1)
        # non-convex fences: stop where the straight (horizontal) path would leave the polygon
        poly = fence.polygon_en_m
        if not fence.convex:
            frac = np.where(inside0_h, inside_fraction(p0[:, :2], out[:, :2], poly, _TOL_M), 1.0)
            cut = frac < 1.0
            out = np.where(cut[:, None], p0 + frac[:, None] * (out - p0), out)
            out[:, 2] = np.clip(out[:, 2], fence.min_alt_m, fence.max_alt_m)
            fence_clamped |= cut
        # speed: scale each step (the shortened step stays on the inside part of the path)
        step = np.linalg.norm(out - p0, axis=1)
        step_max = self.max_speed_m_s * dt_s
        speed_limited = inside0 & (step > step_max)
        scale = np.where(speed_limited, step_max / np.maximum(step, 1e-300), 1.0)
        out = p0 + scale[:, None] * (out - p0)
        return out, fence_clamped, speed_limited

    def assert_safe(self, prev_positions, new_positions, dt_s: float) -> None:
        """Raise :class:`SafetyViolation` if a setpoint is outside the fence or band, or too
        fast from a previous position that was inside the fence."""
        p0, p1 = self._check_shapes(prev_positions, new_positions, dt_s)
        self._assert_safe(p0, p1, dt_s, np.atleast_1d(self.fence.contains(p0)),
                          np.atleast_1d(self.fence.contains(p1, _TOL_M)))

    @staticmethod
    def _fail_if(bad, what: str) -> None:
        if np.any(bad):
            raise SafetyViolation(f"setpoints of vehicles {np.nonzero(bad)[0].tolist()} {what}: not sent")

    def _assert_safe(self, p0, p1, dt_s, inside_before, inside_after) -> None:
        """:meth:`assert_safe` on checked arrays, with ``fence.contains`` of ``p0`` and ``p1`` known."""
        self._fail_if(~inside_after, "would leave the geofence or altitude band")
        speed = np.linalg.norm(p1 - p0, axis=1) / dt_s
        fast = inside_before & (speed > self.max_speed_m_s * (1 + 1e-6))
        if np.any(fast):
            raise SafetyViolation(f"setpoints of vehicles {np.nonzero(fast)[0].tolist()} exceed the speed "
                                  f"limit {self.max_speed_m_s:g} m/s: not sent")

    @staticmethod
    def _check_shapes(prev_positions, new_positions, dt_s):
        p0 = _as_points(prev_positions, "prev_positions")
        p1 = _as_points(new_positions, "new_positions")
        if p0.ndim != 2 or p0.shape != p1.shape:
            raise ValueError(f"prev_positions and new_positions must both be (N, 3), got {p0.shape} and {p1.shape}")
        if not (np.isfinite(dt_s) and dt_s > 0):
            raise ValueError(f"dt_s must be a finite number > 0, got {dt_s!r}")
        return p0, p1
