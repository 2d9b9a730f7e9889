"""Write the example gridded field, ``grid_example.npz`` (docs/fields.md, "Gridded data").

A release at (10, -5, 12) m ENU whose Gaussian cloud (15 m wide) drifts 0.5 m around it and
breathes over 6 frames 5 s apart, looping; a 3D grid of 31 x 31 x 9 nodes, 4 m apart, from
(-50, -65, 0) m. Stored as float32, compressed (about 0.1 MB)::

    python examples/fields/make_grid_example.py [OUT.npz]
    swarmseek run --field-npz examples/fields/grid_example.npz --json
"""
import sys
from pathlib import Path

import numpy as np

SOURCE_ENU_M = np.array([10.0, -5.0, 12.0])
ORIGIN_ENU_M = np.array([-50.0, -65.0, 0.0])
SPACING_M = np.array([4.0, 4.0, 4.0])
SHAPE = (31, 31, 9)
N_FRAMES, FRAME_PERIOD_S, WIDTH_M = 6, 5.0, 15.0


def frames() -> np.ndarray:
    """(T, nx, ny, nz) concentrations, float32."""
    axes = [o + s * np.arange(n) for o, s, n in zip(ORIGIN_ENU_M, SPACING_M, SHAPE)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    out = []
    for k in range(N_FRAMES):
        phase = 2.0 * np.pi * k / N_FRAMES
        centre = SOURCE_ENU_M + 0.5 * np.array([np.cos(phase), np.sin(phase), 0.0])
        d2 = np.sum((grid - centre) ** 2, axis=-1)
        out.append((1.0 + 0.05 * np.sin(phase)) * np.exp(-d2 / (2.0 * WIDTH_M ** 2)))
    return np.array(out, dtype=np.float32)


def write(path) -> Path:
    """Write the example to ``path``; returns it."""
    path = Path(path)
    np.savez_compressed(path, frames=frames(), origin_enu_m=ORIGIN_ENU_M, spacing_m=SPACING_M,
                        frame_period_s=FRAME_PERIOD_S, loop=True, source_enu_m=SOURCE_ENU_M)
    return path


if __name__ == "__main__":
    out = write(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).with_name("grid_example.npz"))
    print(f"wrote {out} ({out.stat().st_size} bytes)")
