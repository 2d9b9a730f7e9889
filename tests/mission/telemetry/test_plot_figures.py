"""``swarmseek plot``'s figures, read through matplotlib's objects: legends outside the
trajectories (one entry for a large swarm), the distance curve on its log scale when the centre
reaches the estimate (0 m), headline titles, the gradient's labels."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mission.cli.cmd_plot import DISTANCE_FLOOR_M, LEGEND_VEHICLES_MAX, plot_mission
from mission.telemetry.mission_log import MissionLog


class _Clock:
    speedup = 1.0

    def time(self):
        return 1000.0


def _log(path: Path, n_vehicles: int, posterior: bool = False) -> Path:
    """A mission log whose last centre is the estimate itself (distance 0 m), as a plume run's is;
    ``posterior``: the last iteration carries a plan-view posterior (the ``ste`` seeker's)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    log = MissionLog(path, _Clock())
    log.write("plan", plan={"fleet": "alpha"})
    source = np.array([5.0, 5.0, 12.0])
    c = np.array([-30.0, 0.0, 10.0])
    angles = np.linspace(0.0, 2.0 * np.pi, n_vehicles, endpoint=False)
    ring = np.stack([4.0 * np.cos(angles), 4.0 * np.sin(angles), np.zeros(n_vehicles)], axis=1)
    prob = np.zeros((10, 10), dtype=int)
    prob[4:6, 4:6] = 2500
    for k in range(1, 15):
        new = c + 0.3 * (source - c)
        extra = {"estimate_map": {"prob_e4": prob.tolist(), "cell_m": 0.5, "east0_m": new[0] - 2.5,
                                  "north0_m": new[1] - 2.5}} if posterior and k == 14 else {}
        log.write("iteration", k=k, centre_enu=c, new_centre_enu=new, gradient=(source - c) * 0.01,
                  estimate_enu=new, positions_enu={i + 1: c + ring[i] for i in range(n_vehicles)}, **extra)
        c = new
    log.write("summary", outcome="converged", estimate_enu=c)
    log.write("truth", source_enu=source, error_m=float(np.linalg.norm(c - source)))
    log.close()
    return path


@pytest.fixture(scope="module")
def figures(tmp_path_factory):
    """plot_mission's four figures by name, kept open (plt.close recorded instead) and drawn;
    one plot per (vehicles, posterior) for the whole module."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    made: dict = {}
    tmp_path = tmp_path_factory.mktemp("plots")

    def plot(n_vehicles: int, posterior: bool = False) -> dict:
        name = f"{n_vehicles}{'-posterior' if posterior else ''}"
        if name not in made:
            closed: list = []
            with pytest.MonkeyPatch.context() as mp:
                mp.setattr(plt, "close", lambda fig=None: closed.append(fig))
                log = _log(tmp_path / name / f"run-{n_vehicles}" / "mission.jsonl", n_vehicles, posterior)
                paths = plot_mission(log, tmp_path / f"fig-{name}")
            for fig in closed:
                fig.canvas.draw()
            made[name] = {p.name: fig for p, fig in zip(paths, closed)}
        return made[name]

    yield plot
    plt.close("all")


def _legend_and_axes_boxes(fig):
    ax = fig.axes[0]
    legend = ax.get_legend()
    assert legend is not None
    return legend, legend.get_window_extent(), ax.get_window_extent()


@pytest.mark.parametrize("name", ["trajectory_3d.png", "trajectory_top.png"])
def test_a_twenty_vehicle_swarm_has_one_legend_entry_outside_the_axes(figures, name):
    legend, box, axes_box = _legend_and_axes_boxes(figures(20)[name])
    labels = [t.get_text() for t in legend.get_texts()]
    assert "20 vehicles (one line each)" in labels
    assert not any(lbl.startswith("vehicle ") for lbl in labels)
    assert len(labels) <= 7  # vehicles, centre, start, estimate, truth (and the 95 % region)
    assert box.x0 >= axes_box.x1 - 1.0  # right of the axes: it covers no track


@pytest.mark.parametrize("name", ["trajectory_3d.png", "trajectory_top.png"])
def test_a_legend_outside_the_axes_stays_inside_the_figure(figures, name):
    fig = figures(20)[name]
    _, box, _ = _legend_and_axes_boxes(fig)
    assert fig.bbox.x0 <= box.x0 and box.x1 <= fig.bbox.x1 + 0.5
    assert fig.bbox.y0 <= box.y0 and box.y1 <= fig.bbox.y1 + 0.5


def test_the_posterior_colour_bar_leaves_the_legend_alone(figures):
    fig = figures(8, posterior=True)["trajectory_top.png"]
    legend, box, axes_box = _legend_and_axes_boxes(fig)
    (cbar,) = [a for a in fig.axes if a.get_label() == "<colorbar>"]
    cbar_box = cbar.get_window_extent()
    assert cbar.get_xlabel() == "posterior probability per cell"  # horizontal, below the plan view
    assert not box.overlaps(cbar_box) and cbar_box.y1 <= axes_box.y0
    assert box.x0 >= axes_box.x1 - 1.0


def test_a_small_swarm_names_each_vehicle(figures):
    legend, box, axes_box = _legend_and_axes_boxes(figures(LEGEND_VEHICLES_MAX)["trajectory_top.png"])
    labels = [t.get_text() for t in legend.get_texts()]
    assert [lbl for lbl in labels if lbl.startswith("vehicle ")] == [
        f"vehicle {i}" for i in range(1, LEGEND_VEHICLES_MAX + 1)]
    assert box.x0 >= axes_box.x1 - 1.0


def test_the_distance_to_a_reached_estimate_stays_on_the_log_scale(figures):
    ax = figures(4)["distance.png"].axes[0]
    assert ax.get_yscale() == "log"
    lines = {ln.get_label(): ln for ln in ax.get_lines()}
    est = np.asarray(lines["to the estimated source"].get_ydata(), dtype=float)
    assert len(est) == 15 and np.all(np.isfinite(est)) and np.all(est > 0.0)
    assert est[-1] == pytest.approx(DISTANCE_FLOOR_M)  # the last centre is the estimate: 0 m, drawn at the floor
    low, _ = ax.get_ylim()
    assert low <= DISTANCE_FLOOR_M  # the floored point is inside the view
    marker = lines["to the estimated source: under 1 cm (drawn at 1 cm)"]
    assert list(marker.get_xdata()) == [14] and marker.get_marker() == "v"
    true = np.asarray(lines["to the true source"].get_ydata(), dtype=float)
    assert np.all(true > DISTANCE_FLOOR_M)  # the true source is 0.27 m off: not floored, no marker
    assert "to the true source: under 1 cm (drawn at 1 cm)" not in lines


def test_distance_and_gradient_have_headline_titles_and_readable_labels(figures):
    figs = figures(4)
    dist_title = figs["distance.png"].axes[0].get_title()
    grad_ax = figs["gradient.png"].axes[0]
    assert dist_title.startswith("Distance of the formation centre to the source\nrun-4 | fleet alpha")
    assert grad_ax.get_title().startswith("Gradient estimate of the signal c at the formation centre\nrun-4")
    labels = [t.get_text() for t in grad_ax.get_legend().get_texts()]
    assert labels == ["∂c/∂east", "∂c/∂north", "∂c/∂up", "norm |∇c|"]
    assert all(float(t).is_integer() for t in grad_ax.get_xticks())
