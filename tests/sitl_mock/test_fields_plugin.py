"""Your own field (docs/fields.md, "Your own field"): a Python plug-in ``pkg.module:factory`` and
gridded ``.npz`` frames reach the simulated sensors of a whole ``swarmseek run`` as the built-in
fields do; the grid is interpolated linearly in space and time; a broken plug-in or file stops
``run``, ``mock``, ``sensor`` and ``simulate`` with one line naming it and exit 2."""
from __future__ import annotations

import importlib
import json
import textwrap
from argparse import Namespace
from pathlib import Path

import numpy as np
import pytest

from mission.cli import main as cli_main
from mission.core.plan_types import PlanError
from mission.core.plan import parse_plan
from mission.sim.lockstep import LOCKSTEP_T0_S
from mission.telemetry.mission_log import read_mission_log
from sitl_mock.cli_args import field_from_args
from sitl_mock.fields_grid import GridField, load_grid
from sitl_mock.fields_plugin import FieldPlugin, FieldPluginError, PluginField, load_plugin, probe_field

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples" / "fields"
SOURCE = (6.0, -4.0, 13.0)

GOOD_PLUGIN = f"""
import numpy as np

CALLS = []  # (t_s, values) of every call: what the world's sensors were given


class Puff:
    def __init__(self, source):
        self.source = np.asarray(source, dtype=float)

    def value(self, points_enu_m, t_s):
        assert points_enu_m.ndim == 2 and points_enu_m.shape[1] == 3 and isinstance(t_s, float)
        out = np.exp(-np.sum((points_enu_m - self.source) ** 2, axis=-1) / (2.0 * 15.0 ** 2))
        CALLS.append((t_s, out.copy()))
        return out

    def source_enu(self):
        return self.source


def make(table):
    return Puff(table.get("source_enu_m", {list(SOURCE)!r}))
"""


def _write_module(tmp_path: Path, name: str, text: str, monkeypatch) -> str:
    (tmp_path / f"{name}.py").write_text(textwrap.dedent(text))
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.invalidate_caches()
    return name


def _mission(log_dir: Path):
    records = read_mission_log(log_dir / "mission.jsonl")
    setup = next(r for r in records if r["type"] == "event" and r["message"] == "embedded mock fleet")
    return records, setup


def test_a_plugin_field_reaches_the_sensors_of_a_lockstep_run_and_its_source(tmp_path, monkeypatch, capsys):
    mod = _write_module(tmp_path, "tp_good_field", GOOD_PLUGIN, monkeypatch)
    log_dir = tmp_path / "log"
    code = cli_main(["run", "--field-python", f"{mod}:make", "--noise", "0", "--json", "--no-tlog",
                     "--log-dir", str(log_dir)])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and out["outcome"] == "converged", out["message"]
    assert out["true_source_enu"] == pytest.approx(SOURCE) and out["error_m"] < 1.0
    records, setup = _mission(log_dir)
    assert setup["field"] == f"python:{mod}:make" and "PluginField" in setup["field_model"]
    assert setup["source_enu"] == pytest.approx(SOURCE)
    calls = importlib.import_module(mod).CALLS
    given = {}  # time -> every value the plug-in returned then
    for t_s, values in calls:
        given.setdefault(t_s, []).extend(values.tolist())
    readings = [x for r in records if r["type"] == "iteration" for x in r["readings"]]
    assert len(readings) >= 8 * out["iterations"]
    for x in readings:  # noise 0, no lag: each reading is the plug-in's value at its time (log: 6 decimals)
        assert x["time_s"] >= LOCKSTEP_T0_S
        assert min(abs(v - x["value"]) for v in given[x["time_s"]]) <= 5e-7


def test_a_sensor_reads_a_plugin_field_as_a_builtin_one(tmp_path, monkeypatch):
    from sitl_mock.faults import FaultSet
    from sitl_mock.sensor import SignalSensor

    mod = _write_module(tmp_path, "tp_sensor_field", GOOD_PLUGIN, monkeypatch)
    field = load_plugin(f"{mod}:make", {"source_enu_m": [1.0, 2.0, 3.0]})
    sensor = SignalSensor(field, 0.0, np.random.default_rng(0), FaultSet(), "f", 1)
    pos, t_s = np.array([4.0, -2.0, 9.0]), LOCKSTEP_T0_S + 12.5
    reading = sensor.sample(t_s, pos, 45.0, 5.0, 200.0)
    assert reading["value"] == float(np.exp(-np.sum((pos - (1.0, 2.0, 3.0)) ** 2) / (2.0 * 15.0 ** 2)))
    calls = importlib.import_module(mod).CALLS
    assert calls[-1][0] == t_s and calls[-1][1].shape == (1,)  # one point (M = 1), the reading's time


def test_the_plan_field_table_reaches_the_factory_and_plan_checks_the_form(tmp_path, monkeypatch):
    mod = _write_module(tmp_path, "tp_table_field", GOOD_PLUGIN, monkeypatch)
    plan = tmp_path / "plan.toml"
    plan.write_text(f'[field]\npython = "{mod}:make"\nsource_enu_m = [1.0, 2.0, 3.0]\nsensor_detection_floor = 0.01\n')
    args = _field_args(field_config=plan)
    name, field, response = field_from_args(args, None)
    assert name == f"python:{mod}:make" and isinstance(field, PluginField)
    assert field.source_enu().tolist() == [1.0, 2.0, 3.0] and response == {"detection_floor": 0.01}
    doc = {"field": {"python": f"{mod}:make", "width_m": 3.0, "sensor_time_constant_s": 0.5}}
    got = parse_plan(_minimal_plan(doc)).field
    assert got.type == "python" and got.to_table() == doc["field"]
    with pytest.raises(PlanError, match=r"field\.python: expected 'pkg\.module:factory', got 'not a spec'"):
        parse_plan(_minimal_plan({"field": {"python": "not a spec"}}))
    with pytest.raises(PlanError, match=r"field\.npz: a grid field needs npz"):
        parse_plan(_minimal_plan({"field": {"type": "grid"}}))


def _minimal_plan(extra: dict) -> dict:
    import tomllib

    doc = tomllib.loads((ROOT / "mission" / "examples" / "sitl_plan.toml").read_text())
    doc.pop("field", None)
    doc.update(extra)
    return doc


def _field_args(**kw) -> Namespace:
    base = dict(field=None, field_config=None, field_python=None, field_npz=None, field_default="sigma2",
                extra_source=[], no_ground_reflection=False, sensor_tau=None, detection_floor=None,
                wind_from=None, wind_speed=None, stability=None, source_radius=None, emission_rate=None,
                background=None, field_seed=None, release_rate=None, meander_time=None)
    base.update(kw)
    return Namespace(**base)


# ----------------------------------------------------------------------------- the npz loader
def _grid(tmp_path, frames, loop=False, **extra) -> GridField:
    d = frames.ndim - 1
    path = tmp_path / "g.npz"
    np.savez(path, frames=frames, origin_enu_m=np.array([-3.0, 5.0, 1.0][:d]), spacing_m=np.array([2.0, 0.5, 4.0][:d]),
             frame_period_s=np.float64(3.0), t0_s=np.float64(100.0), loop=loop, **extra)
    return load_grid(path)


def _nodes(g: GridField) -> np.ndarray:
    mesh = np.stack(np.meshgrid(*g.axes, indexing="ij"), axis=-1)
    if g.dims == 2:
        mesh = np.concatenate([mesh, np.full(mesh.shape[:-1] + (1,), 7.5)], axis=-1)  # any altitude
    return mesh


@pytest.mark.parametrize("shape", [(3, 4, 5, 3), (3, 4, 5)])
def test_grid_is_exact_at_nodes_and_linear_between_nodes_and_frames(tmp_path, shape):
    frames = np.random.default_rng(1).uniform(0.0, 10.0, shape)
    g = _grid(tmp_path, frames)
    nodes = _nodes(g)
    for k in range(3):
        assert np.array_equal(g.value(nodes, 100.0 + 3.0 * k), frames[k])  # bit-exact at the nodes
    mid = nodes[:-1] + np.array([1.0, 0.0, 0.0])  # half-way along east (spacing 2 m)
    assert np.allclose(g.value(mid, 103.0), 0.5 * (frames[1][:-1] + frames[1][1:]), rtol=0, atol=1e-12)
    mid_n = nodes[:, :-1] + np.array([0.0, 0.125, 0.0])  # a quarter of the way along north (spacing 0.5 m)
    assert np.allclose(g.value(mid_n, 103.0), 0.75 * frames[1][:, :-1] + 0.25 * frames[1][:, 1:], atol=1e-12)
    assert np.allclose(g.value(nodes, 100.0 + 3.0 * 0.25), 0.75 * frames[0] + 0.25 * frames[1], atol=1e-12)
    times = np.array([99.0, 103.0, 200.0])[:, None]  # array times: before the first frame, a frame, after the last
    got = g.value(np.broadcast_to(nodes.reshape(-1, 3), (3,) + nodes.reshape(-1, 3).shape), times)
    assert np.array_equal(got, np.stack([frames[0], frames[1], frames[2]]).reshape(3, -1))
    assert g.value(np.array([1e3, 0.0, 0.0]), 103.0) == 0.0  # outside the grid
    if len(shape) == 3:  # a 2D grid does not depend on the altitude
        assert np.array_equal(g.value(nodes + np.array([0.0, 0.0, 40.0]), 103.0), frames[1])


def test_grid_loops_from_the_last_frame_back_to_the_first(tmp_path):
    frames = np.random.default_rng(2).uniform(0.0, 1.0, (3, 2, 2, 2))
    g = _grid(tmp_path, frames, loop=True)
    nodes = _nodes(g)
    assert np.allclose(g.value(nodes, 100.0 + 2.5 * 3.0), 0.5 * (frames[2] + frames[0]), atol=1e-12)
    assert np.array_equal(g.value(nodes, 100.0 + 3 * 3.0 * 7 + 3.0), frames[1])  # 7 loops later
    assert g.time_dependent and g.source_enu().shape == (3,)


def test_the_example_npz_is_what_its_script_writes_and_serves_both_ways(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLES))
    script = importlib.import_module("make_grid_example")
    fresh = np.load(script.write(tmp_path / "fresh.npz"))
    committed = np.load(EXAMPLES / "grid_example.npz")
    assert sorted(fresh.files) == sorted(committed.files)
    for key in fresh.files:
        assert np.array_equal(fresh[key], committed[key]), key
    assert (EXAMPLES / "grid_example.npz").stat().st_size < 200_000
    plan = tmp_path / "plan.toml"  # npz relative to the file that names it
    (tmp_path / "fresh_copy.npz").write_bytes((tmp_path / "fresh.npz").read_bytes())
    for table in ('type = "grid"\nnpz = "fresh_copy.npz"',
                  'python = "sitl_mock.fields_grid:from_table"\nnpz = "fresh_copy.npz"'):
        plan.write_text(f"[field]\n{table}\n")
        name, field, _ = field_from_args(_field_args(field_config=plan), None)
        assert field.source_enu().tolist() == [10.0, -5.0, 12.0], name
        at_node = float(field.value(np.array([10.0, -5.0, 12.0]), 0.0))  # frame 0: the cloud 0.5 m east
        assert at_node == float(np.float32(np.exp(-0.25 / (2.0 * 15.0 ** 2))))


# ----------------------------------------------------------------------------- the docs' example
def test_the_docs_example_plugin_is_the_file_and_serves(monkeypatch):
    text = (EXAMPLES / "my_field.py").read_text()
    docs = (ROOT / "docs" / "fields.md").read_text()
    assert text.split('"""', 2)[2].strip() in docs  # the code the docs show is the file's
    monkeypatch.syspath_prepend(str(EXAMPLES))
    field = load_plugin("my_field:make", {"width_m": 15.0})
    assert isinstance(field.model, FieldPlugin) and field.time_dependent
    probe_field(field, np.array([[0.0, 0.0, 0.0], [10.0, -5.0, 12.0]]), LOCKSTEP_T0_S)
    t = LOCKSTEP_T0_S + 15.0  # a quarter of the 60 s period: the peak, 1.05
    assert float(field.value(np.array([10.0, -5.0, 12.0]), t)) == pytest.approx(1.05)
    g = field.gradient(np.array([14.0, -5.0, 12.0]), t)  # central differences: the Gaussian's slope
    assert g[0] == pytest.approx(-4.0 / 15.0 ** 2 * float(field.value(np.array([14.0, -5.0, 12.0]), t)), rel=1e-5)


def test_simulate_takes_a_plugin_field(tmp_path, monkeypatch, capsys):
    mod = _write_module(tmp_path, "tp_sim_field", GOOD_PLUGIN, monkeypatch)
    code = cli_main(["simulate", "--field-python", f"{mod}:make", "--seeker", "model", "--gamma", "20",
                     "--iterations", "150", "--window", "12", "--tol", "0.3", "--stop-at-convergence", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and out["field"] == f"python:{mod}:make" and out["source_enu"] == list(SOURCE)
    assert out["converged"] and out["estimate_error_m"] < 0.5


# ----------------------------------------------------------------------------- broken plug-ins
BROKEN = {
    "missing_module": (None, "cannot import module 'tp_missing_zz' (no module named 'tp_missing_zz'; run from the "
                             "directory holding it or put it on PYTHONPATH)"),
    "import_error": ("import tp_nowhere_zz\n", "importing 'tp_b_import_error' failed: ModuleNotFoundError: No module "
                                               "named 'tp_nowhere_zz'"),
    "no_attribute": ("def other(table):\n    return None\n", "module 'tp_b_no_attribute' has no attribute 'make'"),
    "raises": ("def make(table):\n    raise KeyError('width_m')\n", "the factory raised KeyError: 'width_m'"),
    "wrong_type": ("def make(table):\n    return {'value': 1}\n",
                   "the factory returned a dict without value() and source_enu() (docs/fields.md, \"Your own field\")"),
    "bad_source": (GOOD_PLUGIN.replace("return self.source\n", "return [1.0, 2.0]\n"),
                   "source_enu() must return 3 finite numbers (E, N, U m), got [1., 2.]"),
    "wrong_shape": (GOOD_PLUGIN.replace("return out\n", "return out[:, None]\n"),
                    "value() of 11 points returned shape (11, 1), expected (11,)"),
    "nan": (GOOD_PLUGIN.replace("return out\n", "return out * np.nan\n"),
            "value() is nan at (-150, -150, 2) m, t = 1767225600 s"),
    "negative": (GOOD_PLUGIN.replace("return out\n", "return out - (t_s > 1767225630.0)\n"),
                 "value() is negative (-1) at (-150, -150, 2) m, t = 1767225660 s; a concentration is >= 0"),
}


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_a_broken_plugin_stops_run_with_one_line_and_exit_2(case, tmp_path, monkeypatch, capsys):
    text, why = BROKEN[case]
    mod = "tp_missing_zz" if text is None else _write_module(tmp_path, f"tp_b_{case}", text, monkeypatch)
    log_dir = tmp_path / "log"
    assert cli_main(["run", "--field-python", f"{mod}:make", "--log-dir", str(log_dir)]) == 2
    err = capsys.readouterr().err
    assert err == f"swarmseek run: error: field plug-in {mod}:make: {why}\n"
    assert not (log_dir / "mission.jsonl").exists()  # nothing started


def test_a_plugin_failing_where_the_probe_did_not_look_is_told(tmp_path, monkeypatch, capsys):
    # wrong shape on the ground only: the probe looks at the fence's floor (2 m) and above, the
    # sensors first read before take-off (z = 0; the fleet asks for all its vehicles at once, then,
    # as that fails, one point at a time)
    bad = GOOD_PLUGIN.replace("return out\n", "return out[:, None] if (points_enu_m[:, 2] < 1.0).any() else out\n")
    mod = _write_module(tmp_path, "tp_runtime_bad", bad, monkeypatch)
    log_dir = tmp_path / "log"
    assert cli_main(["run", "--field-python", f"{mod}:make", "--json", "--no-tlog", "--log-dir", str(log_dir)]) == 1
    captured = capsys.readouterr()
    out = json.loads(captured.out)
    assert out["outcome"] == "aborted" and "nothing armed" in out["message"]
    assert (f"swarmseek run: warning: the simulated world caught 20 error(s) (at most the first ones are kept); the "
            f"first: sitl_mock.fields_plugin.FieldPluginError: field plug-in {mod}:make: value() of 1 points returned "
            "shape (1, 1), expected (1,)\n") in captured.err


@pytest.mark.parametrize("command", ["mock", "sensor", "simulate"])
def test_a_broken_plugin_stops_mock_sensor_and_simulate(command, tmp_path, monkeypatch, capsys):
    mod = _write_module(tmp_path, f"tp_nan_{command}", BROKEN["nan"][0], monkeypatch)
    extra = {"mock": ["--udp-base-port", "0", "--tcp-base-port", "0"],
             "sensor": ["--connect", "tcp:127.0.0.1:9", "--origin", "45,5,200", "--zenoh-connect", "tcp/127.0.0.1:9"],
             "simulate": []}[command]
    assert cli_main([command, "--field-python", f"{mod}:make", *extra]) == 2
    err = capsys.readouterr().err
    prefix = "swarmseek simulate: " if command == "simulate" else f"swarmseek {command}: error: "
    assert err.startswith(f"{prefix}field plug-in {mod}:make: value() is nan at (") and err.count("\n") == 1
    assert "Traceback" not in err


def _npz(path: Path, **arrays) -> Path:
    base = dict(frames=np.ones((2, 3, 3, 3)), origin_enu_m=np.zeros(3), spacing_m=np.ones(3),
                frame_period_s=np.float64(1.0))
    base.update(arrays)
    np.savez(path, **{k: v for k, v in base.items() if v is not None})
    return path


@pytest.mark.parametrize("arrays, why", [
    ({"frames": None, "spacing_m": None}, "missing keys frames, spacing_m (needs frames, origin_enu_m, spacing_m, "
                                          "frame_period_s)"),
    ({"frames": np.ones((3, 3))}, "frames must have shape (T, nx, ny) or (T, nx, ny, nz) with T >= 1 and at least 2 "
                                  "nodes per axis, got (3, 3)"),
    ({"spacing_m": np.array([1.0, np.inf, 1.0])}, "spacing_m must be 3 finite positive numbers (one per grid axis), "
                                                   "got [ 1., inf,  1.]"),
    ({"origin_enu_m": np.zeros(2)}, "origin_enu_m must be 3 finite numbers (one per grid axis), got [0., 0.]"),
    ({"frames": np.full((2, 3, 3), -1.0)}, "frames hold negative values (min -1); a concentration is >= 0"),
    ({"frames": np.full((2, 3, 3), np.nan)}, "frames hold non-finite values (first in frame 0)"),
    ({"frame_period_s": np.float64(0.0)}, "frame_period_s must be one finite positive number, got 0."),
    ({"speed": np.ones(1)}, "unknown key speed (known: frames, origin_enu_m, spacing_m, frame_period_s, t0_s, loop, "
                            "source_enu_m)"),
])
def test_a_broken_npz_stops_run_with_one_line_and_exit_2(arrays, why, tmp_path, capsys):
    path = _npz(tmp_path / "bad.npz", **arrays)
    assert cli_main(["run", "--field-npz", str(path), "--log-dir", str(tmp_path / "log")]) == 2
    assert capsys.readouterr().err == f"swarmseek run: error: grid field {path}: {why}\n"


def test_a_file_that_is_not_an_npz_is_one_line(tmp_path, capsys):
    path = tmp_path / "frames.npz"
    path.write_text("not a zip")
    assert cli_main(["mock", "--field-npz", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"swarmseek mock: error: grid field {path}: cannot read it as a NumPy .npz (")
    assert err.count("\n") == 1


def test_plugin_field_options_that_do_not_apply_are_refused(tmp_path, monkeypatch, capsys):
    mod = _write_module(tmp_path, "tp_opts_field", GOOD_PLUGIN, monkeypatch)
    for extra, why in ((["--wind-from", "90"], f"--wind-from does not apply to the python:{mod}:make field"),
                       (["--field", "sigma2"], "give one of --field, --field-python, not several"),
                       (["--extra-source", "1,2,3"], f"--extra-source does not apply to the python:{mod}:make field")):
        assert cli_main(["run", "--field-python", f"{mod}:make", *extra, "--log-dir", str(tmp_path / "l")]) == 2
        assert capsys.readouterr().err == f"swarmseek run: error: {why}\n"
    with pytest.raises(FieldPluginError, match="expected a plug-in as 'pkg.module:factory'"):
        load_plugin("no_colon")
