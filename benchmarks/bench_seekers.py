"""Seekers compared offline: success, time to the source, distance, readings (no assertions).

Vectorised over trials (:func:`experiments.offline_seek.simulate_seeker`): the default
mission's formation (8-vehicle CVT, radius 4 m), each trial with a uniformly random formation
orientation and a start 10-50 m from the source (``--start-m``; uniform distance, uniform heading, elevation
within +-15 degrees: the fence's altitude band), perfect tracking, Gaussian reading noise. The
gradient seeker uses the mission's ``eps = 1 / (2 A lambda_max(S))`` and ``gamma = 1 m`` (the
default ``swarmseek run``); newton and model a trust region capped at ``gamma = 20 m``.

Per seeker, field and noise:

* success: the centre gets within 1 m of the source and stays there until the end of the
  budget (``--iterations``), with a Wilson 95 % interval;
* time to get and stay within 1 m (mission time from :class:`~experiments.offline_seek.StopAndGo`:
  fly at the ramp's speed limits, settle, read), median and 90th percentile over successes;
* the ratio of that time to the straight-line limit ``distance / max_speed_m_s`` (3 m/s);
* distance flown by the centre until then (each vehicle flies the same path: rigid formation,
  perfect tracking) and the number of readings (N per iteration);
* the final distance to the source (median over successes, and median over all trials: where
  nothing succeeds, which seeker gets closer);
* success within 4x and 10x the straight line: the fraction of all trials that succeed within that
  time (the issue's speed target, counted over every trial, so that a policy whose few successes
  are fast does not look better than one whose many are).

Noise levels: 0 and "realistic" = 1 % of the field's peak (0.01 for sigma_2, the default
``swarmseek run --noise``; 1.0 for sigma_1; 0.01 for the plumes, whose peak is about 1). Fields
(``--fields``): any name :func:`sitl_mock.fields_config.make_field` knows, with its default parameters:
the paper's sigma_1 and sigma_2, ``plume`` (steady Gaussian plume, wind 2 m/s) and
``intermittent`` (puffs: a reading is patchy in time; read at the mission time the time model
gives). On a plume the starts are downwind (within 10 degrees of the wind axis), as in
``swarmseek run``; the gradient seeker's ``eps`` is the field's ``default_eps``
(:func:`mission.sim.embedded.default_eps`). Seekers (``--seekers``): ``gradient``, ``newton``,
``model``, ``plume`` (the plume's axis estimated from the readings) and ``plume-wind`` (the
plume seeker given the field's wind direction; on a field without wind it is ``plume``),
``plume-patchy`` and ``plume-patchy-wind`` (the intermittent-plume variant,
:class:`estimator.seek_hits.HitEdgeSeeker`, without / with the wind); ``ste``, ``ste-wind``,
``ste-patchy``, ``ste-patchy-wind`` (:class:`estimator.ste.SteSeeker` with the steady or the
intermittent likelihood, without / with the wind; ``--ste-args key=value,...`` sets its other
keywords). A seeker that reports a posterior (``estimate_enu`` and ``region95_m``: ``ste``) adds
columns: its estimate within 1 m at the end, the estimate's median error and region radius, the
calibration (the source inside the reported 95 % region, Wilson interval), the fraction converged
(region within ``region_m``), the fraction reporting convergence (its ``arrival``: the region, no
recent collapse and the model check passed), the fraction flagged ``misfit`` with the median
``fit_z``, and the posterior collapses. A seeker that sizes the formation (``formation_radius_m``:
``ste``) gets it in the simulation, and the time model counts the vehicles' flights to their new
slots (:meth:`experiments.offline_seek.SeekRun.iteration_s`). ``--cpu 8,50`` prints each seeker's
CPU time per ``propose`` (one trial) instead of the table. ``--search-box SIDE_M`` (stop and go):
the ``ste`` seekers' prior is bounded by a search box per trial (``prior_box_enu``), what a plan's
fence gives a mission: a square of that side placed at random among the placements holding the
release and the start 5 m inside (:func:`search_boxes`; never centred on the release), up the
embedded plan's altitude band (2-80 m); the starts are the same as without it.

Usage::

    python benchmarks/bench_seekers.py                         # 400 trials per cell
    python benchmarks/bench_seekers.py --trials 100 --fields sigma2 --json out.json
    python benchmarks/bench_seekers.py --trials 50 --iterations 120 --fields plume,intermittent \
        --noise realistic --seekers ste,ste-wind,ste-patchy,ste-patchy-wind
    python benchmarks/bench_seekers.py --cpu 8,50 --fields plume --seekers ste-wind
    python benchmarks/bench_seekers.py --trials 100 --iterations 120 --fields intermittent --noise realistic \
        --seekers ste-patchy-wind --ste-args prior_upwind_deg=30 --search-box 60   # the prior inside a 60 m fence
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

__all__ = ["main", "wilson", "measure", "search_boxes"]

_MAX_SPEED_M_S = 3.0


def wilson(successes: int, trials: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion."""
    if trials == 0:
        return 0.0, 1.0
    p = successes / trials
    den = 1 + z * z / trials
    mid = (p + z * z / (2 * trials)) / den
    half = z * np.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / den
    return float(max(0.0, mid - half)), float(min(1.0, mid + half))


def _starts(source: np.ndarray, trials: int, rng, downwind=None, start_m=(10.0, 50.0)) -> tuple[np.ndarray, np.ndarray]:
    dist = rng.uniform(float(start_m[0]), float(start_m[1]), trials)
    heading = rng.uniform(0, 2 * np.pi, trials)
    if downwind is not None:  # plumes: downwind of the source (within 10 degrees), as swarmseek run
        heading = np.arctan2(downwind[1], downwind[0]) + np.deg2rad(rng.uniform(-10.0, 10.0, trials))
    elev = np.deg2rad(rng.uniform(-15.0, 15.0, trials))
    u = np.stack([np.cos(elev) * np.cos(heading), np.cos(elev) * np.sin(heading), np.sin(elev)], axis=1)
    return source + dist[:, None] * u, dist


def measure(run, start_dist_m: np.ndarray, n: int, time_model, tol_m: float = 1.0) -> dict:
    """The measures of one batch (module docstring) from a :class:`SeekRun`."""
    d = run.distance_m()  # (T + 1, K)
    t_count, k = d.shape
    out_ = d > tol_m
    ever_out = out_.any(axis=0)
    last_out = np.where(ever_out, t_count - 1 - np.argmax(out_[::-1], axis=0), -1)
    ok = ~out_[-1]
    entered = np.minimum(last_out + 1, t_count - 1)
    moves = run.moves()
    times = np.concatenate([np.zeros((1, k)), np.cumsum(run.iteration_s(time_model), axis=0)])
    path = np.concatenate([np.zeros((1, k)), np.cumsum(np.linalg.norm(moves, axis=-1), axis=0)])
    cols = np.arange(k)
    t_in, flown = times[entered, cols], path[entered, cols]
    ratio = t_in / (start_dist_m / _MAX_SPEED_M_S)
    lo, hi = wilson(int(ok.sum()), k)

    def q(x, p):
        return float(np.percentile(x[ok], p)) if ok.any() else float("nan")

    return {"trials": k, "success": float(ok.mean()), "success_ci95": [lo, hi],
            "time_s_median": q(t_in, 50), "time_s_p90": q(t_in, 90),
            "ratio_median": q(ratio, 50), "ratio_p90": q(ratio, 90),
            "flown_m_median": q(flown, 50), "straight_m_median": q(start_dist_m, 50),
            "readings_median": q(entered * n, 50), "final_error_m_median": q(d[-1], 50),
            "final_distance_m_median_all": float(np.median(d[-1])),
            "within_4x": float(np.mean(ok & (ratio <= 4.0))), "within_10x": float(np.mean(ok & (ratio <= 10.0)))}


def _wind_from_deg(field):
    """The field's wind direction (a plume's, or an intermittent plume's steady mean's); None without wind."""
    for f in (field, getattr(field, "steady", None), *(getattr(field, "parts", None) or ())[:1]):
        if f is not None and getattr(f, "wind_from_deg", None) is not None:
            return float(f.wind_from_deg)
        if f is not None and getattr(getattr(f, "steady", None), "wind_from_deg", None) is not None:
            return float(f.steady.wind_from_deg)
    return None


def name_values(text: str | None, option: str, number=float) -> dict:
    """``"a=1,b=x"`` -> ``{"a": number("1"), "b": "x"}``: a value ``number`` cannot read stays a string.

    ValueError (one line, naming ``option``) for an item that is not ``NAME=VALUE``.
    """
    out = {}
    for item in filter(None, (p.strip() for p in (text or "").split(","))):
        key, eq, value = item.partition("=")
        if not eq or not key.strip() or not value.strip():
            raise ValueError(f"{option}: {item!r} is not NAME=VALUE")
        try:
            out[key.strip()] = number(value)
        except ValueError:
            out[key.strip()] = value.strip()
    return out


def _int_or_float(value: str):
    return float(value) if "." in value or "e" in value else int(value)


def _ste_kwargs(text: str | None) -> dict:
    """``"exploit_m=1,temper=0.5"`` -> keyword arguments of the ``ste`` seeker (integers stay integers)."""
    return name_values(text, "--ste-args", _int_or_float)


def search_boxes(source: np.ndarray, starts: np.ndarray, side_m: float, rng, margin_m: float = 5.0,
                 band_m: tuple = (2.0, 80.0)) -> np.ndarray:
    """Per trial, the search box a plan's fence would give ``(K, 2, 3)``: a horizontal square of side
    ``side_m`` placed uniformly at random among the placements holding the release and the start each
    at least ``margin_m`` inside (along an axis where no placement can, the side grows to the least
    that does: ``|d| + 2 margin``), up the altitude band ``band_m`` (the embedded plan's fence's).
    Not centred on the release: where the release sits in its box is as random as the box."""
    src = np.broadcast_to(source[:2], starts[:, :2].shape)
    lo_pt, hi_pt = np.minimum(src, starts[:, :2]), np.maximum(src, starts[:, :2])
    side = np.maximum(float(side_m), hi_pt - lo_pt + 2.0 * margin_m)
    first, last = hi_pt + margin_m - side, lo_pt - margin_m  # the box's low corner may be anywhere in between
    low = first + rng.uniform(0.0, 1.0, first.shape) * (last - first)
    box = np.empty((len(starts), 2, 3))
    box[:, 0, :2], box[:, 1, :2] = low, low + side
    box[:, 0, 2], box[:, 1, 2] = band_m
    return box


def _seeker(name: str, field, ste_args: str | None = None, box=None, stability: str | None = None):
    """A seeker by benchmark name; ``stability``: the class a plan would give the ``ste`` seeker."""
    from estimator.seekers import make_seeker
    from mission.sim.embedded import default_eps

    if name == "gradient":
        return make_seeker("gradient", eps=default_eps(field)), 1.0
    if name == "plume-wind":  # the plume seeker given the wind direction (an anemometer)
        return make_seeker("plume", wind_from_deg=_wind_from_deg(field)), 20.0
    if name in ("plume-patchy", "plume-patchy-wind"):  # intermittent plumes: the hit cloud's upwind edge
        wind = _wind_from_deg(field) if name.endswith("wind") else None
        return make_seeker("plume", patchy=True, wind_from_deg=wind), 20.0
    if name.startswith("ste"):  # source-term estimation: ste, ste-wind, ste-patchy, ste-patchy-wind
        wind = _wind_from_deg(field) if name.endswith("wind") else None
        box_kw = {} if box is None else {"prior_box_enu": box}
        if stability is not None:
            box_kw["stability"] = stability
        return make_seeker("ste", patchy="patchy" in name, wind_from_deg=wind, **_ste_kwargs(ste_args), **box_kw), 20.0
    return make_seeker(name), 20.0


def _posterior_row(seeker, source: np.ndarray, tol_m: float = 1.0) -> dict:
    """A seeker's own estimate at the end (``ste``: posterior mean and 95 % region); {} without one."""
    est, region = getattr(seeker, "estimate_enu", None), getattr(seeker, "region95_m", None)
    if est is None or region is None:
        return {}
    err = np.linalg.norm(est - source, axis=1)
    inside = err <= region
    lo, hi = wilson(int(inside.sum()), len(err))
    ok = err <= tol_m
    return {"estimate_success": float(ok.mean()), "estimate_success_ci95": list(wilson(int(ok.sum()), len(err))),
            "estimate_error_m_median": float(np.median(err)), "region95_m_median": float(np.median(region)),
            "calibration": float(inside.mean()), "calibration_ci95": [lo, hi],
            "converged": float(np.mean(region <= getattr(seeker, "region_m", tol_m))),
            "reported_converged": float(np.mean(getattr(seeker, "arrival", None) if getattr(seeker, "arrival", None)
                                                is not None else region <= tol_m)),
            "misfit": float(np.mean(getattr(seeker, "misfit", None) if getattr(seeker, "misfit", None) is not None
                                    else False)),
            "fit_z_median": float(np.median(getattr(seeker, "fit_z", None))) if getattr(seeker, "fit_z", None)
            is not None else float("nan"),
            "collapses": int(np.sum(getattr(seeker, "collapses", 0)))}


def update_ms(seeker_name: str, field_name: str, n: int, iterations: int = 40, seed: int = 0,
              ste_args: str | None = None) -> float:
    """Median CPU time (ms, ``time.process_time``) of one ``propose`` with one trial (K = 1) of
    ``n`` vehicles (CVT of radius 4 m) on a field, along a run from 25 m downwind."""
    import formation
    from mission.sim.embedded import downwind_en

    source = np.array([0.0, 0.0, 15.0])
    field, noise = _field_and_noise(field_name, source, "realistic")
    seeker, gamma = _seeker(seeker_name, field, ste_args)
    seeker.reset()
    dw = downwind_en(field)
    c = source + (np.array([25.0 * dw[0], 25.0 * dw[1], -2.0]) if dw is not None else np.array([25.0, 0.0, -2.0]))
    off = formation.cvt_sphere(n, 4.0, seed=0)
    rng = np.random.default_rng(seed)
    from estimator.seekers import cap_move

    times, t_s = [], 0.0
    for _ in range(iterations):
        pos = c[None] + off
        vals = field.value(pos, t_s) + noise * rng.standard_normal(n)
        t0 = time.process_time()
        nxt = seeker.propose(c[None], pos[None], vals[None])
        times.append(time.process_time() - t0)
        c, t_s = cap_move(c[None], nxt, gamma)[0], t_s + 1.0
    return 1e3 * float(np.median(times))


def _field_and_noise(name: str, source: np.ndarray, level: str, field_args: dict | None = None):
    from sitl_mock.fields_config import make_field

    field = make_field(name, source, **(field_args or {}))
    steady = getattr(field, "steady", field)  # the intermittent plume's ensemble mean
    peak = float(steady.value(field.source_enu()))
    return field, (0.0 if level == "0" else 0.01 * peak)


def measure_moving(run, start_dist_m: np.ndarray, tol_m: float = 1.0) -> dict:
    """The measures of one batch sampling while moving (:class:`experiments.offline_moving.MovingRun`):
    success = the formation's centre within ``tol_m`` from some estimate to the end."""
    t_in = run.time_within_s(tol_m)
    ok = np.isfinite(t_in)
    lo, hi = wilson(int(ok.sum()), len(ok))
    ratio = t_in / (start_dist_m / _MAX_SPEED_M_S)
    reads = np.concatenate([np.zeros((1, len(ok))), np.cumsum(run.readings, axis=0)])
    entered = np.array([np.searchsorted(run.times_s[:, k], t) if o else 0 for k, (t, o) in enumerate(zip(t_in, ok))])
    d = np.linalg.norm(run.formation_enu[-1] - run.source_enu, axis=-1)
    path = np.concatenate([np.zeros((1, len(ok))), np.cumsum(np.linalg.norm(np.diff(run.formation_enu, axis=0),
                                                                           axis=-1), axis=0)])
    cols = np.arange(len(ok))

    def q(x, p):
        return float(np.percentile(x[ok], p)) if ok.any() else float("nan")

    return {"trials": len(ok), "success": float(ok.mean()), "success_ci95": [lo, hi],
            "time_s_median": q(t_in, 50), "time_s_p90": q(t_in, 90), "ratio_median": q(ratio, 50),
            "ratio_p90": q(ratio, 90), "flown_m_median": q(path[entered, cols], 50),
            "straight_m_median": q(start_dist_m, 50), "readings_median": q(reads[entered, cols], 50),
            "final_error_m_median": q(d, 50), "final_distance_m_median_all": float(np.median(d))}


class _Stacked:
    """The per-trial seekers' own estimates stacked as one batched seeker's (for :func:`_posterior_row`)."""

    def __init__(self, seekers: list):
        for name in ("estimate_enu", "region95_m", "arrival", "misfit", "fit_z", "collapses"):
            vals = [getattr(s, name, None) for s in seekers]
            setattr(self, name, None if any(v is None for v in vals) else np.concatenate([np.atleast_1d(v) for v in vals]))
        if self.estimate_enu is not None:
            self.estimate_enu = self.estimate_enu.reshape(-1, 3)
        self.region_m = getattr(seekers[0], "region_m", 1.0) if seekers else 1.0


def run_cell(seeker_name: str, field_name: str, noise_level: str, trials: int, iterations: int, seed: int,
             ste_args: str | None = None, sampling: str = "stop", start_m=(10.0, 50.0),
             search_box_m: float | None = None, field_args: dict | None = None) -> dict:
    """One table cell: ``trials`` runs of a seeker on a field at a noise level, stop and go
    (vectorised) or sampling while moving (trial by trial); with ``search_box_m`` the ``ste``
    seekers' prior is bounded by each trial's :func:`search_boxes` (stop and go only);
    ``field_args``: the field's parameters (:func:`field_args`; a ``stability`` is also given
    to the ``ste`` seekers, as a plan's ``[field]`` would)."""
    import formation
    from experiments.offline_moving import simulate_moving
    from experiments.offline_seek import StopAndGo, simulate_seeker

    rng = np.random.default_rng(seed)
    source = np.array([0.0, 0.0, 15.0])
    field, noise = _field_and_noise(field_name, source, noise_level, field_args)
    stability = (field_args or {}).get("stability")
    from mission.sim.embedded import downwind_en

    starts, dist = _starts(field.source_enu(), trials, rng, downwind_en(field), start_m)
    box = None
    if search_box_m is not None and seeker_name.startswith("ste"):
        box = search_boxes(field.source_enu(), starts, search_box_m, np.random.default_rng(seed + 2))
    seeker, gamma = _seeker(seeker_name, field, ste_args, box, stability)
    offsets = formation.cvt_sphere(8, 4.0, seed=0)
    t0 = time.perf_counter()
    if sampling == "moving":
        run = simulate_moving(offsets, field, starts, lambda: _seeker(seeker_name, field, ste_args, None, stability)[0],
                              gamma_m=gamma,
                              iterations=iterations, noise_std=noise, rotate=True, seed=seed + 1)
        row = measure_moving(run, dist)
        seeker = _Stacked(run.seekers)
    else:
        run = simulate_seeker(offsets, field, starts, seeker, gamma_m=gamma, iterations=iterations,
                              noise_std=noise, rotate=True, seed=seed + 1)
        row = measure(run, dist, offsets.shape[0], StopAndGo())
    row.update(_posterior_row(seeker, field.source_enu()))
    row.update(seeker=seeker_name, field=field_name, noise=noise, sampling=sampling, wall_s=time.perf_counter() - t0,
               field_args=dict(field_args or {}))
    return row


def field_args(text: str) -> dict:
    """``"wind_speed_m_s=4,stability=D"`` -> the field's keyword parameters (numbers as floats).

    ValueError (one line) for an item without ``=``; the field checks names and ranges
    (:func:`sitl_mock.fields_config.make_field`).
    """
    return name_values(text, "--field-args")


def _start_range(text: str) -> tuple[float, float]:
    """``"20,40"`` -> (20.0, 40.0); ValueError (one line) unless two numbers ``0 < lo <= hi``."""
    parts = text.split(",")
    try:
        lo, hi = (float(x) for x in parts) if len(parts) == 2 else (np.nan, np.nan)
    except ValueError:
        lo = hi = np.nan
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo <= hi):
        raise ValueError(f"--start-m must be two numbers lo,hi with 0 < lo <= hi, got {text!r}")
    return lo, hi


def _fmt(row: dict) -> str:
    lo, hi = row["success_ci95"]
    post = ""
    if "calibration" in row:
        clo, chi = row["calibration_ci95"]
        post = (f" estimate within 1 m {row['estimate_success']:.2f}, error {row['estimate_error_m_median']:.2f} m, "
                f"region95 {row['region95_m_median']:.2f} m, calibration {row['calibration']:.2f} ({clo:.2f}-{chi:.2f}), "
                f"converged {row['converged']:.2f}, reported converged {row['reported_converged']:.2f}, "
                f"misfit {row['misfit']:.2f} (fit z {row['fit_z_median']:.1f}), collapses {row['collapses']}, "
                f"wall {row['wall_s']:.0f} s |")
    if "within_4x" in row:
        post += f" success within 4x / 10x the straight line {row['within_4x']:.2f} / {row['within_10x']:.2f} |"
    args = ",".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.get("field_args", {}).items())
    field = f"{row['field']} ({args})" if args else row["field"]
    return (f"| {row['seeker']} | {field} | {row['noise']:g} | {row['success']:.2f} ({lo:.2f}-{hi:.2f}) "
            f"| {row['time_s_median']:.1f} / {row['time_s_p90']:.1f} | {row['ratio_median']:.2f} / {row['ratio_p90']:.2f} "
            f"| {row['flown_m_median']:.1f} ({row['straight_m_median']:.1f}) | {row['readings_median']:.0f} "
            f"| {row['final_error_m_median']:.3f} | {row['final_distance_m_median_all']:.2f} |" + post)


def main(argv=None) -> int:
    """Run the table; prints markdown rows (and ``--json`` the rows)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=400)
    ap.add_argument("--iterations", type=int, default=150)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--seekers", default="gradient,newton,model,plume,plume-wind",
                    help="seekers (estimator.seekers.SEEKERS) and plume-wind: the plume seeker given the wind")
    ap.add_argument("--fields", default="sigma1,sigma2")
    ap.add_argument("--noise", default="0,realistic", help="noise levels: 0 and/or realistic (1 %% of the peak)")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--ste-args", default=None, help="keyword arguments of the ste seekers, e.g. exploit_m=1,temper=0.5")
    ap.add_argument("--sampling", choices=("stop", "moving"), default="stop",
                    help="stop and go (vectorised), or sampling while moving (experiments.offline_moving, trial by trial)")
    ap.add_argument("--start-m", default="10,50", help="range of the start distances from the source, m (lo,hi); "
                    "the issue's targets are for 20,40")
    ap.add_argument("--search-box", type=float, default=None, metavar="SIDE_M",
                    help="ste seekers: bound the prior by a search box (a plan's fence) of this side, m, placed "
                    "at random about each trial's release and start (search_boxes); stop and go only")
    ap.add_argument("--field-args", action="append", default=None, metavar="NAME=VALUE,...",
                    help="the fields' parameters, e.g. wind_speed_m_s=4,stability=D (a stability class is also "
                    "given to the ste seekers, as a plan would); repeat for more conditions (one table row each)")
    ap.add_argument("--cpu", default=None, help="vehicle counts (e.g. 8,50): print each seeker's CPU per update "
                    "(K = 1, median ms) on each field instead of the table")
    args = ap.parse_args(argv)
    try:
        start_m = _start_range(args.start_m)
    except ValueError as exc:
        ap.error(str(exc))
    try:
        conditions = [field_args(text) for text in (args.field_args or [""])]
        _ste_kwargs(args.ste_args)  # a malformed --ste-args: one line now, not a traceback mid-table
        from sitl_mock.fields_config import make_field

        for name in args.fields.split(","):
            for cond in conditions:
                make_field(name, (0.0, 0.0, 15.0), **cond)
    except ValueError as exc:
        ap.error(str(exc))
    if args.search_box is not None and (not np.isfinite(args.search_box) or args.search_box <= 0
                                        or args.sampling != "stop"):
        ap.error(f"--search-box must be a side > 0 m, with --sampling stop; got {args.search_box!r}, {args.sampling}")
    if args.cpu:
        for field_name in args.fields.split(","):
            for name in args.seekers.split(","):
                for n in (int(x) for x in args.cpu.split(",")):
                    print(f"{name} {field_name} N={n}: {update_ms(name, field_name, n, ste_args=args.ste_args):.1f} ms per update", flush=True)
        return 0
    print("| seeker | field | noise | success (95 % CI) | time to stay within 1 m, s (median / p90) "
          "| ratio to straight line (median / p90) | centre flown, m (straight) | readings | final error, m "
          "| final distance, all trials, m |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for field_name in args.fields.split(","):
        for cond in conditions:
            for level in args.noise.split(","):
                for name in args.seekers.split(","):
                    row = run_cell(name, field_name, level, args.trials, args.iterations, args.seed, args.ste_args,
                                   args.sampling, start_m, args.search_box, cond)
                    rows.append(row)
                    print(_fmt(row), flush=True)
    if args.json is not None:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
