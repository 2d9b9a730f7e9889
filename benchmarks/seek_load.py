"""The coordinator's seek-loop work as a load for benchmarks (no vehicles are moved by it).

Not a benchmark itself: ``python benchmarks/bench_setpoints.py --extra-load seek_load:seek_load``
adds it to the setpoint benchmark's coordinator (``benchmarks/`` is the script's path).

:func:`seek_load` matches the ``extra_load(vehicles, streamer, clock)`` hook of
``benchmarks/bench_setpoints.py``: while the benchmark streams setpoints, it does what the
coordinator does during a seek besides streaming:

* readings: every vehicle's reading at ``reading_rate_hz`` is decoded and validated by a
  :class:`~mission.telemetry.readings.ReadingStore` (JSON decode, geodetic -> ENU, telemetry distance,
  sequence checks). The payloads are made by cheap string formatting of a template (a sensor's
  encoding cost is not the coordinator's; zenoh transport is not included);
* setpoints: a :class:`~mission.safety.gate.SafetyGate` (at the streamer's rate, driving its sends, as in the
  coordinator) moves every vehicle
  towards its slot and passes every batch through the :class:`~mission.safety.envelope.SafetyEnvelope`
  (fence, altitude band, speed, separation along the paths);
* estimation at ``estimate_rate_hz``: time alignment, Theorem 2 on the actual positions about
  their centroid, ``seek_step``, the envelope's ``clamp_centre``, and an ``iteration`` record in a
  mission log (a temporary file).
"""
from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path

import numpy as np

from mission.core.tasks import spawn

__all__ = ["seek_load"]


async def seek_load(vehicles, streamer, clock, *, reading_rate_hz: float = 10.0, estimate_rate_hz: float = 2.0,
                    radius_m: float = 4.0, fleet: str = "bench") -> None:
    """Run the seek-loop work until cancelled (see the module docstring)."""
    from mission.flight.targets import formation_offsets
    from mission.safety.envelope import SafetyEnvelope
    from mission.safety.fence import Geofence
    from mission.safety.gate import SafetyGate
    from mission.telemetry.mission_log import MissionLog
    from mission.telemetry.readings import ReadingStore

    n = len(vehicles)
    origin = vehicles[0].mission_origin if hasattr(vehicles[0], "mission_origin") else None
    if origin is None:
        home = vehicles[0].state.home
        origin = home if home is not None else (45.0, 5.0, 200.0)
    sysids = [v.sysid for v in vehicles]
    by_sysid = {v.sysid: v for v in vehicles}
    store = ReadingStore(fleet, sysids, origin, clock, max_position_error_m=1e6,
                         telemetry_position=lambda s: by_sysid[s].position_enu_m())
    fence = Geofence(np.array([[-5000.0, -5000.0], [5000.0, -5000.0], [5000.0, 5000.0], [-5000.0, 5000.0]]),
                     -1000.0, 5000.0)
    envelope = SafetyEnvelope(fence, max_speed_m_s=3.0, min_separation_m=0.0, formation_radius_m=radius_m)
    ramp = SafetyGate(streamer, clock, 3.0, envelope=envelope)  # it drives the streamer's sends
    offsets = formation_offsets("cvt", n, radius_m * max(1.0, (n / 8) ** 0.5))
    centre = np.array([0.0, 0.0, 20.0])
    for i, v in enumerate(vehicles):
        p = v.position_enu_m()
        ramp.add(v.sysid, p if p is not None else centre + offsets[i])
    ramp.set_goals({s: centre + offsets[i] for i, s in enumerate(sysids)})
    ramp.start()
    templates = _reading_templates(fleet, sysids, origin, centre, offsets)

    async def readings():
        seq = 0
        while True:
            await clock.sleep(1.0 / reading_rate_hz)
            seq += 1
            t = clock.time()
            for s, (key, tpl) in templates.items():
                store.offer(key, (tpl % (seq, t, 0.5 + 1e-3 * math.sin(seq + s))).encode())

    tmp = tempfile.TemporaryDirectory(prefix="swarmseek-seek-load-")
    log = MissionLog(Path(tmp.name) / "mission.jsonl", clock)
    task = spawn(readings(), "the synthetic readings of the seek load")
    try:
        await _estimate_forever(store, envelope, ramp, log, clock, centre, offsets, sysids, by_sysid,
                                estimate_rate_hz)
    finally:
        task.cancel()
        await ramp.stop()
        log.close()
        tmp.cleanup()


def _reading_templates(fleet: str, sysids, origin, centre, offsets) -> dict:
    """Per vehicle: its sensor key and a reading payload with ``%d`` (seq), ``%.4f`` (time), ``%.6f`` (value)."""
    from formation.geodesy import enu_to_geodetic
    from mission.telemetry.reading_format import SCHEMA, sensor_key

    templates = {}
    for i, s in enumerate(sysids):
        lat, lon, alt = enu_to_geodetic(centre + offsets[i], origin)
        templates[s] = (sensor_key(fleet, s), json.dumps(
            {"schema": SCHEMA, "fleet": fleet, "sysid": s, "seq": 0, "time_s": 0.0, "lat_deg": float(lat),
             "lon_deg": float(lon), "alt_m": float(alt), "value": 0.5}).replace('"seq": 0', '"seq": %d')
            .replace('"time_s": 0.0', '"time_s": %.4f').replace('"value": 0.5', '"value": %.6f'))
    return templates


async def _estimate_forever(store, envelope, ramp, log, clock, centre, offsets, sysids, by_sysid,
                            estimate_rate_hz: float) -> None:
    """The coordinator's estimation work at ``estimate_rate_hz`` (see the module docstring), until cancelled."""
    import estimator

    while True:
        await clock.sleep(1.0 / estimate_rate_hz)
        aligned = store.aligned(clock.time(), 0.5)
        if len(aligned) < 4:
            continue
        used = sorted(aligned)
        pos = np.array([aligned[s].position_enu_m for s in used])
        vals = np.array([aligned[s].value for s in used])
        try:
            grad = estimator.gradient(pos, vals, pos.mean(axis=0), method="cvt", max_condition=1e12)
        except ValueError:
            continue
        new_centre = envelope.clamp_centre(centre, estimator.seek_step(centre, grad, 1.0, 0.1)).centre_enu
        log.write("iteration", centre_enu=centre, gradient=grad, new_centre_enu=new_centre,
                  readings=[aligned[s] for s in used],
                  positions_enu={s: by_sysid[s].position_enu_m() for s in used})
        centre = np.asarray(new_centre, dtype=float)
        ramp.set_goals({s: centre + offsets[i] for i, s in enumerate(sysids)})
