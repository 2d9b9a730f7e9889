"""``swarmseek paper --quick`` writes every output, and its numbers come from the geometry."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest

import formation
from mission.cli import main as cli_main
from experiments.paper_setup import SIGMA1_START_ENU, SIGMA2_START_ENU, TABLE_NS

_FILES = [
    "table1.csv", "table1.json", "table1.md", "footnote.csv", "footnote.json",
    "fig1_trajectory.png", "fig1_trajectory.csv", "fig1_trajectory.json",
    "fig2_gradient.png", "fig2_gradient.csv", "fig3_error_radius.png", "fig3_error_radius.csv",
    "fig4_noise.png", "fig4_noise.csv", "fig4_robustness.csv", "fig4_robustness.json",
    "fig4_robustness.md", "fig5_cvt30.png", "fig5_cvt30.json", "physics.json", "summary.json",
]


@pytest.fixture(scope="module")
def paper_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper") / "figures"  # not existing yet: must be created
    assert cli_main(["paper", "--quick", "--out", str(out)]) == 0
    return out


@pytest.mark.parametrize("name", _FILES)
def test_every_output_is_written(paper_dir, name):
    path = paper_dir / name
    assert path.is_file() and path.stat().st_size > 0
    if name.endswith(".png"):
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    if name.endswith(".json"):
        assert json.loads(path.read_text())


def test_table1_equals_the_formation_metrics(paper_dir):
    rows = json.loads((paper_dir / "table1.json").read_text())
    assert [r["n"] for r in rows] == list(TABLE_NS)
    for row in rows:
        n = row["n"]
        assert row["symmetric_d_min"] == formation.metrics(formation.symmetric_cylinder(n, 1.0)).d_min
        assert row["cvt_d_min"] == formation.metrics(formation.cvt_sphere(n, 1.0, seed=0, n_starts=10)).d_min
    with (paper_dir / "table1.csv").open() as fh:
        csv_rows = list(csv.DictReader(fh))
    assert [float(r["cvt_d_min"]) for r in csv_rows] == pytest.approx([r["cvt_d_min"] for r in rows])
    md = (paper_dir / "table1.md").read_text()
    assert all(f"| {n} |" in md for n in TABLE_NS)


def test_footnote_rows_match_metrics(paper_dir):
    rows = json.loads((paper_dir / "footnote.json").read_text())
    assert {r["n"] for r in rows} >= {4, 5, 6, 7, 8}
    assert {r["formation"] for r in rows if r["n"] % 2} == {"cvt"}
    row = next(r for r in rows if r["n"] == 7)
    m = formation.metrics(formation.cvt_sphere(7, 1.0, seed=0))
    assert row["norm_scaled_Minv"] == pytest.approx(m.norm_scaled_Minv)
    assert row["norm_M_alpha"] == pytest.approx(m.norm_M_alpha)
    sym = [r for r in rows if r["formation"] == "symmetric"]
    assert all(r["r_bar_norm"] < 1e-12 and r["norm_scaled_Minv"] == pytest.approx(1.0) for r in sym)


def test_outputs_state_the_starting_points_and_data_is_consistent(paper_dir):
    summary = json.loads((paper_dir / "summary.json").read_text())
    assert summary["quick"] is True
    assert summary["sigma1_start_enu"] == list(SIGMA1_START_ENU)
    assert summary["sigma2_start_enu"] == list(SIGMA2_START_ENU)
    fig1 = json.loads((paper_dir / "fig1_trajectory.json").read_text())
    with (paper_dir / "fig1_trajectory.csv").open() as fh:
        traj = list(csv.DictReader(fh))
    first = [float(traj[0][k]) for k in ("east_m", "north_m", "up_m")]
    assert first == list(SIGMA1_START_ENU) == fig1["start_enu"]
    assert float(traj[-1]["dist_m"]) < float(traj[0]["dist_m"])  # it seeks
    np.testing.assert_allclose(np.linalg.norm(fig1["offsets"], axis=1), 4.0)
    with (paper_dir / "fig4_noise.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert float(rows[0]["equal_cvt_mean_m"]) == pytest.approx(np.linalg.norm(SIGMA2_START_ENU))
    assert float(rows[-1]["faulty_symmetric_mean_m"]) < float(rows[0]["faulty_symmetric_mean_m"])


def test_quick_outputs_say_they_stopped_before_convergence(paper_dir):
    """--quick's final errors (20-23 m on Fig. 4) are not the paper's result: its outputs say so."""
    summary = json.loads((paper_dir / "summary.json").read_text())
    assert "QUICK RUN (--quick, 600/400 iterations, not 3000/5000)" in summary["note"]
    assert "stopped before convergence, not the paper's result" in summary["note"]
    assert (paper_dir / "fig4_robustness.md").read_text().startswith("**QUICK RUN (--quick")
    from experiments.paper_setup import PaperConfig

    assert PaperConfig().quick_note() is None  # the full run has no label


def test_quick_printed_fig4_lines_say_so(paper_dir, tmp_path, monkeypatch, capsys):
    import experiments.paper as paper

    summary = json.loads((paper_dir / "summary.json").read_text())
    monkeypatch.setattr(paper, "generate", lambda out, quick=False: summary)
    assert cli_main(["paper", "--quick", "--out", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1].startswith("QUICK RUN (--quick, 600/400 iterations, not 3000/5000): stopped before convergence")
    fig4 = [line for line in lines if line.startswith("  fig4 ")]
    assert len(fig4) == 4 and all(line.endswith("m (quick run: stopped before convergence)") for line in fig4)


@pytest.mark.parametrize("note", [None, "QUICK RUN (--quick):\nstopped before convergence"])
def test_a_quick_figures_label_is_on_top_of_the_figure(tmp_path, monkeypatch, note):
    """The label is a figure text above every axes, inside the figure; a full run's figure has none."""
    from experiments import paper_figures as figs

    closed = []
    monkeypatch.setattr(figs.plt, "close", closed.append)
    k = np.arange(50)
    figs.fig3_error(tmp_path / "fig3.png", k, {"D1": np.linspace(1.0, 0.1, 50)}, note=note)
    (fig,) = closed
    texts = [t for t in fig.texts if t.get_text()]
    if note is None:
        assert texts == []
        return
    (label,) = texts
    assert label.get_text() == note and label.get_color() == "tab:red"
    renderer = fig.canvas.get_renderer()
    box = label.get_window_extent(renderer)
    assert box.y1 <= fig.bbox.y1 + 0.5 and box.x0 >= 0 and box.x1 <= fig.bbox.x1
    assert all(box.y0 >= ax.get_tightbbox(renderer).y1 - 0.5 for ax in fig.axes)  # above the axes and their titles


@pytest.mark.parametrize("n, radius_m", [(7, 1.0), (7, 4.0), (8, 0.5)])
def test_the_papers_cvt_is_solved_once_and_is_cvt_sphere_bit_for_bit(n, radius_m):
    from experiments.paper_setup import CVT_SEED, CVT_STARTS, _unit_cvt, cvt_formation

    first = cvt_formation(n, radius_m)
    assert np.array_equal(first, formation.cvt_sphere(n, radius_m, seed=CVT_SEED, n_starts=CVT_STARTS))
    hits = _unit_cvt.cache_info().hits
    again = cvt_formation(n, radius_m)
    assert _unit_cvt.cache_info().hits == hits + 1 and np.array_equal(again, first)
    again[0, 0] = 99.0                                  # a caller's copy: the shared unit CVT is untouched
    assert np.array_equal(cvt_formation(n, radius_m), first)
    with pytest.raises(ValueError, match="radius_m must be positive"):
        cvt_formation(n, 0.0)
