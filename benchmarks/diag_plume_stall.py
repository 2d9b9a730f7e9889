"""Why newton and model stop downwind of a plume's release (docs/seekers.md, "Plumes: the diagnosis").

Default steady plume (release 15 m up, west wind 2 m/s, class C), the default formation (8-vehicle
CVT, radius 4 m, not rotated), no noise. Prints, in the wind frame (x downwind of the release):

* each seeker's path from three starts: where it ends, its trust radius, whether the fitted
  maximum (Newton step) was accepted, the step's length and its uncertainty;
* the mean of the 8 readings with the centre on the axis, averaged over 200 random formation
  orientations, against x (its maximum is where a seeker that sees the field through the
  formation stops), and the paper's Theorem 2 gradient along the axis against the true one.

Usage::

    python benchmarks/diag_plume_stall.py
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402


def _paths(field, offsets) -> None:
    from estimator.seekers import cap_move, make_seeker

    for name in ("newton", "model"):
        for start in ([25.0, 0.0, 12.0], [40.0, 2.0, 18.0], [15.0, -1.0, 15.0]):
            seeker = make_seeker(name)
            c = np.array([start])
            steps = []
            for _ in range(120):
                pos = c[:, None, :] + offsets[None]
                new = cap_move(c, seeker.propose(c, pos, field.value(pos)), 20.0)
                steps.append(float(np.linalg.norm(new - c)))
                c = new
            x, y, z = field.wind_frame(c[0])
            fit = seeker.last_fit
            print(f"{name:6s} start {start}: ends x {x:.2f} y {y:.2f} z-H {z - 15.0:.2f} m, trust radius "
                  f"{seeker.radius_m[0]:.2f} m, Newton step accepted {bool(seeker.last_newton[0])}, "
                  f"|p| {np.linalg.norm(np.nan_to_num(fit.newton[0])):.2f} m, std(p) {fit.newton_std_m[0]:.2f} m, "
                  f"mean step over the last 20 iterations {np.mean(steps[-20:]):.3f} m")


def _formation_view(field, offsets) -> None:
    from scipy.spatial.transform import Rotation

    from estimator.gradient import estimator_weights

    rot = np.einsum("kij,nj->kni", Rotation.random(200, random_state=1).as_matrix(), offsets)
    xs = np.linspace(0.0, 40.0, 81)
    mean = np.array([field.value(np.array([x, 0.0, 15.0]) + rot).mean() for x in xs])
    print(f"mean of the 8 readings on the axis (200 orientations): maximum at x = {xs[np.argmax(mean)]:.1f} m "
          f"({mean.max():.4f}; the release reads {float(field.value(np.array([0.0, 0.0, 15.0]))):.4f})")
    for x in (0.0, 8.0, 16.0, 24.0, 32.0):
        sy, sz = field.spreads(x)
        c = np.array([x, 0.0, 15.0])
        pos = c + rot
        w, _ = estimator_weights(pos - pos.mean(axis=1, keepdims=True), "cvt", 1e12)
        g = np.einsum("kn,kni->ki", field.value(pos), w)[:, 0].mean()
        print(f"  x {x:4.1f} m: s_y {sy:.2f} m, s_z {sz:.2f} m, formation mean {np.interp(x, xs, mean):.4f}, "
              f"centreline {float(field.value(c)):.4f}, Theorem 2 d/dx {g:+.5f} (true {field.gradient(c)[0]:+.5f})")


def main() -> int:
    import formation
    from sitl_mock.fields_config import make_field

    field = make_field("plume", (0.0, 0.0, 15.0))
    offsets = formation.cvt_sphere(8, 4.0, seed=0)
    _paths(field, offsets)
    _formation_view(field, offsets)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
