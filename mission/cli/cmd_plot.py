"""``swarmseek plot LOG --out DIR``: figures of a flown mission from its mission log.

Writes four PNGs (matplotlib, Agg backend), each titled with the run (log directory, fleet,
seed of an embedded run, outcome, error to the true source when known, the estimate's latitude,
longitude and altitude AMSL):

``trajectory_3d.png``   the formation centre during the seek and every vehicle (telemetry, whole
                        mission) in the mission ENU frame, the estimated (and, for embedded
                        runs, the true) source; equal scales on the three axes;
``trajectory_top.png``  the same seen from above (east, north), equal scales, with the estimate's 95 %
                        region (a circle of its radius) and, for a seeker with a posterior
                        (``ste``), the last plan-view posterior as a heat map;
``distance.png``        distance of the centre to the estimated source (and to the true one)
                        per iteration, on a log scale whose floor is 1 cm (a centre on the estimate,
                        0 m, is drawn there with a triangle);
``gradient.png``        the gradient estimate's components (∂c/∂east, ...) and norm per iteration.

The trajectories' legends sit outside the axes; above eight vehicles they have one entry for all.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from wire.cli_args import path_arg, usage_error

__all__ = ["configure", "main", "plot_mission", "mission_tracks", "run_title", "plan_view_figure"]

#: Up to this many vehicles the legend names each one; above, one entry stands for them all.
LEGEND_VEHICLES_MAX = 8
#: distance.png's floor on its log scale: a centre closer than this to a source (the last
#: iteration's centre is often the estimate itself, 0 m) is drawn at the floor and marked.
DISTANCE_FLOOR_M = 0.01


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``plot`` options."""
    parser.add_argument("log", type=path_arg, help="mission log (mission.jsonl)")
    parser.add_argument("--out", type=path_arg, default=None, help="output directory (default: next to the log)")


def mission_tracks(records: list[dict]) -> dict:
    """Arrays extracted from the log's iteration records.

    Returns
    -------
    dict
        ``k`` (T,), ``centre`` (T+1, 3), ``gradient`` (T, 3), ``estimate`` (3,) or None,
        ``region95_m`` (float or None) and ``basis`` (str or None) of that estimate, ``posterior``
        (the last iteration's ``estimate_map`` or None), ``vehicles`` {sysid: (T, 3)},
        ``true_source`` (3,) or None.
    """
    its = [r for r in records if r.get("type") == "iteration"]
    if not its:
        raise ValueError("the mission log has no seeking iteration (did the mission reach the seek phase?)")
    k = np.array([r["k"] for r in its])
    centre = np.array([r["centre_enu"] for r in its] + [its[-1]["new_centre_enu"]], dtype=float)
    grad = np.array([r["gradient"] for r in its], dtype=float)
    samples: list[tuple[float, str, list]] = []
    for r in records:
        if r.get("type") == "iteration":
            samples.extend((r.get("t_s", 0.0), str(s), p) for s, p in (r.get("positions_enu") or {}).items())
        elif r.get("type") == "status":
            samples.extend((r.get("t_s", 0.0), str(v.get("sysid")), v.get("position_enu"))
                           for v in r.get("vehicles", []))
    vehicles: dict[str, list] = {}
    for _, sysid, p in sorted(samples, key=lambda x: x[0]):
        if p is not None and len(p) == 3:
            vehicles.setdefault(sysid, []).append(p)
    summary = next((r for r in reversed(records) if r.get("type") == "summary"), None)
    source = summary if summary and summary.get("estimate_enu") is not None else its[-1]
    estimate = source.get("estimate_enu")
    posterior = next((r["estimate_map"] for r in reversed(its) if r.get("estimate_map")), None)
    truth = next((r for r in reversed(records) if r.get("type") == "truth"), None)
    true_source = truth.get("source_enu") if truth else None
    if true_source is None and summary:
        true_source = summary.get("true_source_enu")
    return {"k": k, "centre": centre, "gradient": grad,
            "estimate": None if estimate is None else np.asarray(estimate, dtype=float),
            "region95_m": source.get("estimate_region95_m"), "basis": source.get("estimate_basis"),
            "posterior": posterior,
            "vehicles": {s: np.asarray(v, dtype=float) for s, v in vehicles.items()},
            "true_source": None if true_source is None else np.asarray(true_source, dtype=float)}


def run_title(records: list[dict], log_path: Path) -> str:
    """The figures' title: which run (log directory, fleet, seed), how it ended, where the estimate is.

    Parameters
    ----------
    records : list of dict
        The mission log's records.
    log_path : Path
        The log file (its directory names the run).
    """
    plan = next((r.get("plan") or {} for r in records if r.get("type") == "plan"), {})
    embedded = next((r for r in records if r.get("type") == "event"
                     and r.get("message") == "embedded mock fleet"), None)
    summary = next((r for r in reversed(records) if r.get("type") == "summary"), None) or {}
    truth = next((r for r in reversed(records) if r.get("type") == "truth"), None) or {}
    parts = [Path(log_path).resolve().parent.name, f"fleet {plan.get('fleet', '?')}"]
    if embedded is not None and embedded.get("seed") is not None:
        parts.append(f"seed {embedded['seed']}")
    parts.append(summary.get("outcome", "no summary (interrupted?)"))
    error_m = truth.get("error_m", summary.get("error_m"))
    if error_m is not None:
        parts.append(f"error {float(error_m):.2f} m")
    line = " | ".join(parts)
    geo = summary.get("estimate_geodetic")
    if geo:
        r = summary.get("estimate_region95_m")
        line += (f"\nestimated source {geo['lat_deg']:.7f}, {geo['lon_deg']:.7f}, "
                 f"{geo['alt_m']:.1f} m AMSL, " + ("no 95 % region" if r is None else f"95 % region {float(r):.2f} m"))
    return line


def _equal_3d(ax, points: np.ndarray) -> None:
    """Equal scales on the three axes of a 3D plot (a sphere looks like a sphere)."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    half = max(float(np.max(hi - lo)) / 2.0, 1.0)
    mid = (lo + hi) / 2.0
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)
    ax.set_zlim(mid[2] - half, mid[2] + half)
    ax.set_box_aspect((1.0, 1.0, 1.0))


def _all_points(tr: dict) -> np.ndarray:
    pts = [tr["centre"]] + [p for p in tr["vehicles"].values() if p.ndim == 2 and len(p)]
    pts += [x[None, :] for x in (tr["estimate"], tr["true_source"]) if x is not None]
    return np.concatenate(pts, axis=0)


def _draw_uncertainty(plt, ax, tr: dict, colorbar: bool = True) -> None:
    """The plan-view posterior as a heat map (probability per cell) and the 95 % region's circle."""
    post = tr.get("posterior")
    if post:
        prob = np.asarray(post["prob_e4"], dtype=float) / 1e4
        n, cell = prob.shape[0], float(post["cell_m"])
        e0, n0 = float(post["east0_m"]), float(post["north0_m"])
        img = ax.imshow(np.ma.masked_equal(prob, 0.0), origin="lower", cmap="viridis", alpha=0.8,
                        extent=(e0, e0 + n * cell, n0, n0 + n * cell), interpolation="nearest", zorder=0)
        img.set_label("posterior (plan view)")
        if colorbar:
            # below the axes: the legend is on their right (:func:`_legend_outside`)
            plt.colorbar(img, ax=ax, location="bottom", fraction=0.046, pad=0.1,
                         label="posterior probability per cell")
    if tr["estimate"] is not None and tr.get("region95_m") is not None:
        ax.add_patch(plt.Circle(tr["estimate"][:2], float(tr["region95_m"]), fill=False, color="tab:red",
                                ls="--", lw=1.2, label=f"95 % region ({float(tr['region95_m']):.2f} m)"))


def _zoom(plt, ax, tr: dict) -> None:
    """An inset about the estimate (its region and posterior, the true source): they are metres
    across in a view of tens of metres."""
    est = tr["estimate"]
    if est is None or (tr.get("region95_m") is None and not tr.get("posterior")):
        return
    half = 3.0 * float(tr.get("region95_m") or 0.0)
    if tr.get("posterior"):
        half = max(half, 0.5 * len(tr["posterior"]["prob_e4"]) * float(tr["posterior"]["cell_m"]))
    if tr["true_source"] is not None:
        half = max(half, 1.2 * float(np.linalg.norm(tr["true_source"][:2] - est[:2])))
    half = max(half, 0.25)
    inset = ax.inset_axes([0.02, 0.02, 0.34, 0.34])
    _draw_uncertainty(plt, inset, tr, colorbar=False)
    inset.plot(est[0], est[1], "*", color="tab:red", ms=10)
    if tr["true_source"] is not None:
        inset.plot(tr["true_source"][0], tr["true_source"][1], "x", color="tab:green", ms=8)
    inset.set_xlim(est[0] - half, est[0] + half)
    inset.set_ylim(est[1] - half, est[1] + half)
    inset.set_aspect("equal")
    inset.tick_params(labelsize=6)
    inset.set_title(f"about the estimate ({2 * half:.1f} m across)", fontsize=6)


def _draw_vehicles(ax, tr: dict, dims: int) -> None:
    """Every vehicle's track on ``ax`` (``dims`` 2: east, north; 3: east, north, up).

    Up to :data:`LEGEND_VEHICLES_MAX` vehicles, each has its colour and legend entry; above, all
    are drawn in grey with one legend entry, so that the legend of a 20-vehicle swarm stays short.
    """
    tracks = sorted(tr["vehicles"].items(), key=lambda kv: int(kv[0]))
    grouped = len(tracks) > LEGEND_VEHICLES_MAX
    for i, (sysid, p) in enumerate(tracks):
        cols = [p[:, j] for j in range(dims)]
        if grouped:
            label = f"{len(tracks)} vehicles (one line each)" if i == 0 else "_nolegend_"
            ax.plot(*cols, lw=0.6, alpha=0.45, color="tab:gray", label=label)
        else:
            ax.plot(*cols, lw=0.8, alpha=0.6, label=f"vehicle {sysid}")


def _legend_outside(ax, fontsize: int = 7):
    """The legend to the right of the axes, outside them, so that it covers no track."""
    return ax.legend(fontsize=fontsize, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)


def plan_view_figure(plt, tr: dict, title: str):
    """The plan view (east, north), equal scales, with the estimate's uncertainty (and an inset
    about the estimate); returns the figure."""
    fig, ax = plt.subplots(figsize=(9.5, 7))
    _draw_uncertainty(plt, ax, tr)
    _zoom(plt, ax, tr)
    _draw_vehicles(ax, tr, 2)
    c = tr["centre"]
    ax.plot(c[:, 0], c[:, 1], "k-", lw=2.0, label="formation centre")
    ax.plot(c[0, 0], c[0, 1], "ko", ms=5, label="start")
    if tr["estimate"] is not None:
        ax.plot(tr["estimate"][0], tr["estimate"][1], "*", color="tab:red", ms=14, label="estimated source")
    if tr["true_source"] is not None:
        ax.plot(tr["true_source"][0], tr["true_source"][1], "x", color="tab:green", ms=10, label="true source")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.grid(True, alpha=0.3)
    ax.set_title(title, fontsize=9)
    _legend_outside(ax)
    fig.tight_layout()
    return fig


def _plot_top(plt, tr: dict, title: str, path: Path) -> None:
    """Plan view (east, north), equal scales (:func:`plan_view_figure`), saved to ``path``."""
    fig = plan_view_figure(plt, tr, title)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _plot_3d(plt, tr: dict, title: str, path: Path) -> None:
    """3D trajectory in the mission ENU frame, equal scales on the three axes."""
    fig = plt.figure(figsize=(10, 7))
    ax = fig.add_axes((0.0, 0.02, 0.72, 0.86), projection="3d")
    _draw_vehicles(ax, tr, 3)
    c = tr["centre"]
    ax.plot(c[:, 0], c[:, 1], c[:, 2], "k-", lw=2.0, label="formation centre")
    ax.scatter(*c[0], color="k", marker="o", s=30, label="start")
    if tr["estimate"] is not None:
        ax.scatter(*tr["estimate"], color="tab:red", marker="*", s=150, label="estimated source")
    if tr["true_source"] is not None:
        ax.scatter(*tr["true_source"], color="tab:green", marker="x", s=100, label="true source")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_zlabel("up (m)")
    _equal_3d(ax, _all_points(tr))
    ax.set_title(f"Trajectory (mission ENU frame, equal scales)\n{title}", fontsize=9)
    _legend_outside(ax)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _distance_line(ax, iters: np.ndarray, d_m: np.ndarray, style: str, label: str) -> None:
    """One distance curve on the log axis, its points below :data:`DISTANCE_FLOOR_M` (0 m when the
    centre reached that point) drawn at the floor and marked with a triangle, so that the curve
    does not vanish off the log scale."""
    below = d_m < DISTANCE_FLOOR_M
    (line,) = ax.plot(iters, np.maximum(d_m, DISTANCE_FLOOR_M), style, label=label)
    if below.any():
        ax.plot(iters[below], np.full(int(below.sum()), DISTANCE_FLOOR_M), "v", color=line.get_color(), ms=7,
                label=f"{label}: under {100 * DISTANCE_FLOOR_M:.0f} cm (drawn at {100 * DISTANCE_FLOOR_M:.0f} cm)")


def _plot_distance(plt, tr: dict, title: str, path: Path) -> None:
    """Distance of the centre to the estimated (and true) source per iteration (log scale, floored)."""
    c = tr["centre"]
    fig, ax = plt.subplots(figsize=(8, 4.3))
    iters = np.arange(len(c))
    if tr["estimate"] is not None:
        _distance_line(ax, iters, np.linalg.norm(c - tr["estimate"], axis=1), "-", "to the estimated source")
    if tr["true_source"] is not None:
        _distance_line(ax, iters, np.linalg.norm(c - tr["true_source"], axis=1), "--", "to the true source")
    ax.set_xlabel("iteration")
    ax.set_ylabel("distance of the centre (m)")
    ax.set_yscale("log")
    ax.xaxis.get_major_locator().set_params(integer=True)  # iterations are whole numbers
    ax.set_title(f"Distance of the formation centre to the source\n{title}", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _plot_gradient(plt, tr: dict, title: str, path: Path) -> None:
    """The gradient estimate's components and norm per iteration."""
    fig, ax = plt.subplots(figsize=(8, 4.3))
    g = tr["gradient"]
    for i, name in enumerate(("east", "north", "up")):
        ax.plot(tr["k"], g[:, i], lw=1.0, label=f"∂c/∂{name}")
    ax.plot(tr["k"], np.linalg.norm(g, axis=1), "k-", lw=1.5, label="norm |∇c|")
    ax.set_xlabel("iteration")
    ax.set_ylabel("gradient estimate (signal / m)")
    ax.xaxis.get_major_locator().set_params(integer=True)  # iterations are whole numbers
    ax.set_title(f"Gradient estimate of the signal c at the formation centre\n{title}", fontsize=9)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_mission(log_path: Path, out_dir: Path) -> list[Path]:
    """Write the four figures; returns their paths.

    Raises
    ------
    FileNotFoundError, ValueError
        No log, not a mission log, or no seeking iteration in it.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mission.telemetry.mission_log import read_mission_log

    records = read_mission_log(log_path)
    tr = mission_tracks(records)
    title = run_title(records, log_path)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [out_dir / name for name in ("trajectory_3d.png", "trajectory_top.png", "distance.png",
                                         "gradient.png")]
    _plot_3d(plt, tr, title, paths[0])
    _plot_top(plt, tr, f"Seen from above (equal scales)\n{title}", paths[1])
    _plot_distance(plt, tr, title, paths[2])
    _plot_gradient(plt, tr, title, paths[3])
    return paths


def main(args) -> int:
    """Plot a mission log; 0 on success, 1 if the log cannot be plotted, 2 if --out cannot be written."""
    from wire.cli_args import output_dir_problem

    out = args.out or args.log.parent
    if not args.log.is_file():
        what = "is a directory, not a mission log" if args.log.is_dir() else "no such file"
        print(f"swarmseek plot: error: {args.log}: {what}", file=sys.stderr)
        return 1
    problem = output_dir_problem(out, "output directory (--out)")
    if problem:
        return usage_error("swarmseek plot", problem)
    try:
        paths = plot_mission(args.log, out)
    except FileNotFoundError:
        print(f"swarmseek plot: no such file: {args.log}", file=sys.stderr)
        return 1
    except (ValueError, KeyError, IsADirectoryError) as exc:
        print(f"swarmseek plot: cannot plot {args.log}: {exc}", file=sys.stderr)
        return 1
    for p in paths:
        print(p)
    return 0
