"""Figures and output files of ``swarmseek paper`` (matplotlib Agg backend; no state kept)."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Line3DCollection  # noqa: E402
from scipy.spatial import SphericalVoronoi  # noqa: E402

__all__ = [
    "fig1_trajectory",
    "fig2_gradient",
    "fig3_error",
    "fig4_noise",
    "fig5_cvt",
    "write_csv",
    "write_json",
    "markdown_table",
    "rows_from_series",
]

_DPI = 120


def _save(fig, path: Path, note: str | None = None) -> None:
    """Lay out, write and close ``fig``; ``note`` (e.g. a quick run's label) in red across its top."""
    if note:
        fig.tight_layout(rect=(0.0, 0.0, 1.0, 0.92))
        fig.text(0.5, 0.99, note, ha="center", va="top", color="tab:red", fontsize=9, fontweight="bold")
    else:
        fig.tight_layout()
    fig.savefig(path, dpi=_DPI)
    plt.close(fig)


def _sphere_wire(ax, centre, radius_m, color):
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 25), np.linspace(0, np.pi, 13))
    ax.plot_wireframe(centre[0] + radius_m * np.cos(u) * np.sin(v),
                      centre[1] + radius_m * np.sin(u) * np.sin(v),
                      centre[2] + radius_m * np.cos(v), color=color, linewidth=0.3, alpha=0.4)


def fig1_trajectory(path, centres, offsets, k_mid: int, note: str | None = None) -> None:
    """Fig. 1: 3D trajectory of the centre, robots at k = 0 and k = ``k_mid``, the source.

    Parameters
    ----------
    path : path-like
        PNG to write.
    centres : ndarray, shape (T + 1, 3)
        Centre trajectory.
    offsets : ndarray, shape (N, 3)
        Formation offsets.
    k_mid : int
        Intermediate iteration drawn in green.
    """
    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    ax.plot(*centres.T, color="red", linewidth=1.5, label="centre trajectory")
    radius_m = float(np.mean(np.linalg.norm(offsets, axis=1)))
    for k, color, label in ((0, "blue", "robots, k = 0"), (k_mid, "green", f"robots, k = {k_mid}")):
        pos = centres[k] + offsets
        ax.scatter(*pos.T, s=40, facecolors="none", edgecolors=color, label=label)
        _sphere_wire(ax, centres[k], radius_m, color)
    ax.scatter([0], [0], [0], marker="*", s=150, color="black", label="source r*")
    ax.set_xlabel("east x (m)")
    ax.set_ylabel("north y (m)")
    ax.set_zlabel("up z (m)")
    span = np.ptp(np.vstack([centres, centres[0] + offsets]), axis=0).max() / 2 + radius_m
    mid = (centres.max(axis=0) + centres.min(axis=0)) / 2
    for setter, m in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), mid):
        setter(m - span, m + span)
    ax.set_title(f"N = {len(offsets)} CVT formation, D = {radius_m:g} m, sigma_1, Theorem 2")
    ax.legend(loc="upper left", fontsize=8)
    _save(fig, Path(path), note)


def fig2_gradient(path, k, exact, eq3, thm2, note: str | None = None) -> None:
    """Fig. 2: gradient components along the run: exact, eq. (3), Theorem 2 (each (T, 3))."""
    fig, axes = plt.subplots(3, 1, figsize=(7, 7), sharex=True)
    for i, (ax, axis) in enumerate(zip(axes, "xyz")):
        ax.plot(k, exact[:, i], color="black", linewidth=2.0, label="exact")
        ax.plot(k, eq3[:, i], color="tab:orange", linestyle="--", label="eq. (3)")
        ax.plot(k, thm2[:, i], color="tab:blue", linestyle=":", linewidth=2.0, label="Theorem 2")
        ax.set_ylabel(f"d sigma / d{axis}")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("iteration k")
    axes[0].set_title("Gradient along the Fig. 1 run (N = 7 CVT, D = 4 m, sigma_1)")
    _save(fig, Path(path), note)


def fig3_error(path, k, errors: dict, note: str | None = None) -> None:
    """Fig. 3: ||g_hat - grad|| along the run for each radius (dict label -> (T,))."""
    fig, ax = plt.subplots(figsize=(7, 4))
    for label, err in errors.items():
        ax.semilogy(k, np.maximum(err, 1e-12), label=label.replace("D", "D = ") + " m")
    ax.set_xlabel("iteration k")
    ax.set_ylabel("||g_hat - grad sigma_1(c)||")
    ax.set_title("Theorem 2 estimation error, N = 7 CVT, sigma_1")
    ax.grid(alpha=0.3, which="both")
    ax.legend()
    _save(fig, Path(path), note)


def fig4_noise(path, k, runs: dict, note: str | None = None) -> None:
    """Fig. 4: mean +- std of ||c - r*|| over trials; ``runs[(case, kind)]`` is (T + 1, K).

    Left: the whole run; right: the last third, zoomed, where the formations differ.
    """
    fig, axes = plt.subplots(2, 2, figsize=(10, 7), sharex="col",
                             gridspec_kw={"width_ratios": [3, 2]})
    colors = {"symmetric": "tab:orange", "cvt": "tab:blue"}
    titles = {"equal": "noise 0.1 on every robot", "faulty": "robot 1 at 0.5, others 0.1"}
    zoom = k >= k[-1] * 2 // 3
    for row, case in enumerate(("equal", "faulty")):
        for col, sel in enumerate((slice(None), zoom)):
            ax = axes[row, col]
            for kind in ("symmetric", "cvt"):
                d = runs[(case, kind)]
                mean, std = d.mean(axis=1)[sel], d.std(axis=1)[sel]
                ax.plot(k[sel], mean, color=colors[kind], label=f"{kind}: mean +- std")
                ax.fill_between(k[sel], mean - std, mean + std, color=colors[kind], alpha=0.25)
            ax.grid(alpha=0.3)
        axes[row, 0].set_title(f"sigma_2, N = 8, {d.shape[1]} trials: {titles[case]}", fontsize=10)
        axes[row, 1].set_title("zoom on the last third", fontsize=10)
        axes[row, 0].set_ylabel("||c - r*|| (m)")
        axes[row, 0].legend(fontsize=8)
    ymax = max(float((runs[key].mean(axis=1) + runs[key].std(axis=1))[zoom].max()) for key in runs)
    for ax in axes[:, 1]:
        ax.set_ylim(0.0, 1.05 * ymax)
    for ax in axes[-1]:
        ax.set_xlabel("iteration k")
    _save(fig, Path(path), note)


def fig5_cvt(path, generators) -> None:
    """Fig. 5: constrained CVT on the unit sphere: generators and exact Voronoi cell edges."""
    p = np.asarray(generators, dtype=float)
    p = p / np.linalg.norm(p, axis=1, keepdims=True)
    sv = SphericalVoronoi(p, radius=1.0)
    sv.sort_vertices_of_regions()
    elev_deg, azim_deg = 25.0, -60.0
    view = np.array([np.cos(np.radians(elev_deg)) * np.cos(np.radians(azim_deg)),
                     np.cos(np.radians(elev_deg)) * np.sin(np.radians(azim_deg)),
                     np.sin(np.radians(elev_deg))])
    front, back = [], []
    for region in sv.regions:
        verts = sv.vertices[region]
        for a, b in zip(verts, np.roll(verts, -1, axis=0)):
            t = np.linspace(0.0, 1.0, 12)[:, None]
            arc = (1 - t) * a + t * b
            arc = arc / np.linalg.norm(arc, axis=1, keepdims=True)
            for u, w in zip(arc[:-1], arc[1:]):
                (front if (u + w) @ view >= 0 else back).append((u, w))
    fig = plt.figure(figsize=(6, 6))
    ax = fig.add_subplot(projection="3d")
    ax.view_init(elev=elev_deg, azim=azim_deg)
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 40), np.linspace(0, np.pi, 20))
    ax.plot_surface(np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v), color="lightgrey",
                    alpha=0.2, linewidth=0)
    ax.add_collection3d(Line3DCollection(back, colors="tab:blue", linewidths=0.5, alpha=0.15))
    ax.add_collection3d(Line3DCollection(front, colors="tab:blue", linewidths=1.0))
    visible = p @ view >= 0
    ax.scatter(*p[~visible].T, color="red", s=15, alpha=0.2, depthshade=False)
    ax.scatter(*p[visible].T, color="red", s=30, depthshade=False, label="generators")
    ax.set_box_aspect((1, 1, 1))
    for setter in (ax.set_xlim, ax.set_ylim, ax.set_zlim):
        setter(-1, 1)
    ax.set_title(f"Constrained CVT on the sphere, {len(p)} generators")
    _save(fig, Path(path))


def write_csv(path: Path, rows: list[dict]) -> None:
    """CSV with floats at 8 significant digits (JSON files keep full precision)."""
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0].keys()))
        writer.writeheader()
        writer.writerows({k: f"{v:.8g}" if isinstance(v, float) else v for k, v in row.items()}
                         for row in rows)


def write_json(path: Path, obj) -> None:
    """Indented JSON; numpy arrays and scalars become lists and numbers."""
    path.write_text(json.dumps(obj, indent=2, default=_json_default) + "\n")


def _json_default(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def markdown_table(rows: list[dict], columns: list[str], fmt: str = "{:.3f}") -> str:
    """A markdown table of ``columns`` of ``rows`` (floats formatted with ``fmt``)."""
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    for row in rows:
        cells = [fmt.format(row[c]) if isinstance(row[c], float) else str(row[c]) for c in columns]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def rows_from_series(columns: dict) -> list[dict]:
    """Rows from equal-length columns (``"k"`` is kept as an int, the rest as floats)."""
    keys = list(columns)
    length = len(columns[keys[0]])
    return [{k: float(columns[k][i]) if k != "k" else int(columns[k][i]) for k in keys}
            for i in range(length)]
