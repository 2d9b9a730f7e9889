"""Measures of one flown mission read back from its mission log: how fast and how straight the
seek went (``benchmarks/bench_seek_mission.py`` and the sweeps of ``swarmseek run --seeds``).

The mission's own summary (:class:`mission.flight.result.MissionResult`, what ``--json``
prints) has the outcome, the error, the seek time and the distance flown; these are the
measures it has not, computed from the ``iteration`` records:

* ``t_1m_s``: seek time (from the start of the seek phase) of the first iteration from which on
  the centroid of the vehicles' actual reading positions stays within ``tol_m`` of the source;
* ``ratio``: ``t_1m_s`` over the straight-line limit ``|start - source| / max_speed_m_s``
  (the *straight-line ratio*: 1 is a formation flying straight to the source at full speed);
* the path length flown by the centre and by each vehicle, the readings used, where the last
  iteration's centroid is.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mission.telemetry.mission_log import read_mission_log

__all__ = ["mission_measures", "centre_moves_enu"]

#: the plan's ``max_speed_m_s`` when the log has no ``plan`` record (the embedded plan's default)
_DEFAULT_MAX_SPEED_M_S = 3.0


def centre_moves_enu(records: list[dict]) -> np.ndarray:
    """The seek's centre moves, shape (K, 3): from each iteration's centre to its new centre.

    Parameters
    ----------
    records : list of dict
        A mission log's records (:func:`mission.telemetry.mission_log.read_mission_log`).
    """
    its = [r for r in records if r["type"] == "iteration"]
    if not its:
        return np.zeros((0, 3))
    centres = np.array([its[0]["centre_enu"]] + [r["new_centre_enu"] for r in its], dtype=float)
    return np.diff(centres, axis=0)


def _vehicle_paths_m(its: list[dict]) -> list[float]:
    """Path length of each vehicle over the iterations' telemetry positions."""
    pos = {s: np.array([r["positions_enu"][s] for r in its if r["positions_enu"].get(s) is not None])
           for s in its[0]["positions_enu"]}
    return [float(np.linalg.norm(np.diff(p, axis=0), axis=-1).sum()) for p in pos.values() if len(p) > 1]


def _empty_measures(truth: dict, summary: dict, straight_s: float | None) -> dict:
    """The measures of a mission that never iterated (stopped before or at the seek's start)."""
    return {"t_1m_s": None, "ratio": None, "straight_s": straight_s, "iterations_1m": None, "iterations": 0,
            "seek_time_s": 0.0, "error_m": truth.get("error_m"), "readings": 0, "centre_flown_m": 0.0,
            "vehicle_flown_m_mean": None, "vehicle_flown_m_max": None, "outcome": summary.get("outcome"),
            "end_centroid_m": None}


def mission_measures(log_path: str | Path, max_speed_m_s: float | None = None, tol_m: float = 1.0) -> dict:
    """The measures of one mission log (module docstring).

    Parameters
    ----------
    log_path : path-like
        A ``swarmseek run`` mission log (it has the ``truth`` record: the true source).
    max_speed_m_s : float, optional
        Speed of the straight-line limit (default: the plan's ``max_speed_m_s``).
    tol_m : float
        Distance to the source that counts as "there", m.

    Returns
    -------
    dict
        ``t_1m_s``, ``ratio``, ``straight_s``, ``iterations_1m`` (None when the centroid never
        stays within ``tol_m``), ``iterations``, ``seek_time_s``, ``error_m``, ``readings``,
        ``centre_flown_m``, ``vehicle_flown_m_mean``, ``vehicle_flown_m_max``, ``outcome``,
        ``end_centroid_m``.

    Raises
    ------
    ValueError
        The log has no ``truth`` record (not a simulated mission: the source is unknown).
    """
    recs = read_mission_log(log_path)
    truth = next((r for r in recs if r["type"] == "truth"), None)
    if truth is None:
        raise ValueError(f"{log_path}: no 'truth' record (only a `swarmseek run` log knows the true source)")
    source = np.asarray(truth["source_enu"], dtype=float)
    plan = next((r["plan"] for r in recs if r["type"] == "plan"), {})
    speed_m_s = max_speed_m_s or plan.get("max_speed_m_s") or _DEFAULT_MAX_SPEED_M_S
    summary = next((r for r in recs if r["type"] == "summary"), {})
    t_seek = next((r["t_s"] for r in recs if r["type"] == "phase" and r.get("phase") == "seek"), None)
    its = [r for r in recs if r["type"] == "iteration"]
    if t_seek is None or not its:
        return _empty_measures(truth, summary, None)
    t = np.array([r["t_s"] - t_seek for r in its])
    dist = np.array([np.linalg.norm(np.asarray(r["centroid_enu"]) - source) for r in its])
    out_ = dist > tol_m
    first_in = int(len(its) - np.argmax(out_[::-1])) if out_.any() else 0
    stays = first_in < len(its)
    straight = float(np.linalg.norm(np.asarray(its[0]["centre_enu"]) - source)) / speed_m_s
    per_vehicle = _vehicle_paths_m(its)
    return {
        "t_1m_s": float(t[first_in]) if stays else None,
        "ratio": float(t[first_in]) / straight if stays and straight > 0 else None,
        "straight_s": straight,
        "iterations_1m": first_in + 1 if stays else None,
        "iterations": len(its),
        "seek_time_s": float(its[-1]["t_s"] - t_seek),
        "error_m": truth.get("error_m"),
        "readings": int(sum(len(r["readings"]) for r in its)),
        "centre_flown_m": float(np.linalg.norm(centre_moves_enu(recs), axis=-1).sum()),
        "vehicle_flown_m_mean": float(np.mean(per_vehicle)) if per_vehicle else None,
        "vehicle_flown_m_max": float(np.max(per_vehicle)) if per_vehicle else None,
        "outcome": summary.get("outcome"),
        "end_centroid_m": float(dist[-1]),
    }
