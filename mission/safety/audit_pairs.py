"""The audit's separation checks, pair by pair (:mod:`mission.safety.audit`, "Separation").

:func:`track_pair` is the exact check of one pair of tracks (runs of setpoints of two vehicles):
"latest vs latest" at every setpoint instant of either (read ``burst_s`` after it) and the
closest approach along the straight paths between consecutive instants. Every pair of a
mission costs one such check: ``N (N - 1) / 2`` pairs times the mission's length, the audit's
largest cost for a large swarm (4950 pairs at N = 100).

:func:`check_pairs_fast` gives the same report with fewer exact checks: a *lower bound* on the
distance of each pair of tracks (the gap between the two vehicles' bounding boxes, per window of
``window_s``, of every setpoint a track can hold or pass through in that window) orders the
pairs; they are checked exactly from the closest bound up, until the next bound is at least
both the smallest distance found so far and the separation limit: every pair left cannot hold a
violation nor the smallest distance. Their instant and segment counts, which the report gives,
are counted from bit sets of the setpoint instants (all the skipped pairs at once). Same report
as checking every pair:
``tests/mission/safety/test_audit_fast_path.py``.
"""
from __future__ import annotations

import numpy as np

from mission.safety.audit_read import AuditViolation
from mission.safety.geometry import synchronous_distance

__all__ = ["track_pair", "apply_track_pair", "check_pairs_fast"]

#: a bound must clear the threshold by this much to skip a pair (float rounding of the exact check)
_BOUND_MARGIN_M = 1e-6


def _state_at(t_query, t_s, p):
    """Zero-order hold (latest setpoint at or before) and linear interpolation at ``t_query``."""
    return _hold_at(t_query, t_s, p), _interp_at(t_query, t_s, p)


def _hold_at(t_query, t_s, p):
    """The latest setpoint at or before each of ``t_query`` (the first before the first)."""
    return p[np.clip(np.searchsorted(t_s, t_query, side="right") - 1, 0, len(t_s) - 1)]


def _interp_at(t_query, t_s, p):
    """The setpoints linearly interpolated at ``t_query`` (held beyond the ends)."""
    lin = np.empty((len(t_query), 3))
    for c in range(3):
        lin[:, c] = np.interp(t_query, t_s, p[:, c])
    return lin


def pair_span(a, b, ra, rb, stale_after_s) -> tuple[float, float]:
    """``(lo, hi)``: when track ``ra`` of ``a`` and ``rb`` of ``b`` are both commanded (hi < lo: never)."""
    (a_first, a_until), (b_first, b_until) = track_span(a, ra, stale_after_s), track_span(b, rb, stale_after_s)
    return max(a_first, b_first), min(a_until, b_until)


def track_span(sp, r, stale_after_s) -> tuple[float, float]:
    """A track's first stamp and the end of its commanding (see ``VehicleSetpoints.commanded_until``)."""
    return sp.t_s[r[0]], sp.commanded_until(sp.t_s[r[1] - 1], stale_after_s)


def track_pair(a, b, ra, rb, min_sep_m, tol_m, stale_after_s, burst_s=0.0):
    """The exact separation check of track ``ra`` of ``a`` against ``rb`` of ``b``.

    Returns
    -------
    tuple or None
        None when the two are never commanded together; else ``(instants, min_m, violations)``:
        the instants checked (segments: one fewer), the smallest distance, the violations in the
        order the report lists them.
    """
    lo, hi = pair_span(a, b, ra, rb, stale_after_s)
    if hi < lo:
        return None
    ta, pa = a.t_s[ra[0]:ra[1]], a.enu_m[ra[0]:ra[1]]
    tb, pb = b.t_s[rb[0]:rb[1]], b.enu_m[rb[0]:rb[1]]
    tq = np.concatenate([ta, tb, [lo, hi]])
    tq = np.unique(tq[(tq >= lo) & (tq <= hi)])
    za, la = _state_at(tq, ta, pa)
    zb, lb = _state_at(tq, tb, pb)
    if burst_s > 0:
        za, zb = _state_at(tq + burst_s, ta, pa)[0], _state_at(tq + burst_s, tb, pb)[0]
    d_zoh = np.linalg.norm(za - zb, axis=1)
    d_path = synchronous_distance(la[:-1], la[1:], lb[:-1], lb[1:]) if len(tq) > 1 else d_zoh
    min_m = min(float(d_zoh.min()), float(np.min(d_path)))
    every = np.arange(len(tq))
    segments = every[:-1] if len(tq) > 1 else every[:0]
    found = _found(a, b, tq, (every, d_zoh), (segments, d_path if len(tq) > 1 else d_path[:0]), min_sep_m - tol_m,
                   min_sep_m)
    return len(tq), min_m, found


def _found(a, b, tq, zoh, path, limit, min_sep_m) -> list:
    """The violations of a pair, in the report's order: ``zoh`` and ``path`` are ``(indices, distances)``
    of the instants and segments evaluated (a segment starting at an instant found too close, or
    ending at one, is not listed again)."""
    (z_idx, d_zoh), (p_idx, d_path) = zoh, path
    bad = np.flatnonzero(d_zoh < limit)
    found = [AuditViolation("separation", float(tq[i]), (a.sysid, b.sysid), float(d), min_sep_m,
                            f"latest setpoints {d:.3f} m apart (minimum {min_sep_m:g} m)")
             for i, d in zip(z_idx[bad], d_zoh[bad])]
    bad_z = set(z_idx[bad].tolist())
    for pos in np.flatnonzero(d_path < limit):
        i, d = int(p_idx[pos]), d_path[pos]
        if i in bad_z or (i + 1) in bad_z:
            continue
        found.append(AuditViolation("separation", float(tq[i]), (a.sysid, b.sysid), float(d), min_sep_m,
                                    f"paths {tq[i]:.3f}..{tq[i + 1]:.3f} s come {d:.3f} m close "
                                    f"(minimum {min_sep_m:g} m)"))
    return found


def apply_track_pair(report, result) -> None:
    """Add one :func:`track_pair` result (not None) to ``report``."""
    instants, min_m, found = result
    report.separation_instants_checked += instants
    report.separation_segments_checked += max(instants - 1, 0)
    report.min_separation_seen_m = min(report.min_separation_seen_m, min_m)
    for violation in found:
        report.add(violation)


def _grid(vehicles, stale_after_s: float, burst_s: float, window_s: float) -> np.ndarray:
    """Window edges covering every setpoint, ``stale_after_s + burst_s`` after the last, and more."""
    firsts = [sp.t_s[0] for sp, _ in vehicles if len(sp.t_s)]
    lasts = [sp.t_s[-1] for sp, _ in vehicles if len(sp.t_s)]
    t0 = min(firsts) - window_s
    count = int(np.ceil((max(lasts) + stale_after_s + burst_s - t0) / window_s)) + 2
    return t0 + window_s * np.arange(count + 1)


def _track_boxes(t, p, edges) -> np.ndarray:
    """``(W, 2, 3)``: per window, the low and high corner of the box holding every setpoint of a
    track (``t``, ``p``) that the track's latest setpoint or interpolated position can be during
    that window: those inside it, the latest at or before its start and the first at or after its
    end (clamped to the track's first and last, as the exact check clamps)."""
    k = len(t)
    starts, ends = edges[:-1], edges[1:]
    prev = np.clip(np.searchsorted(t, starts, side="right") - 1, 0, k - 1)
    nxt = np.clip(np.searchsorted(t, ends, side="left"), 0, k - 1)
    lo, hi = np.minimum(p[prev], p[nxt]), np.maximum(p[prev], p[nxt])
    first = np.searchsorted(t, starts, side="left")
    last = np.searchsorted(t, ends, side="left")
    busy = np.flatnonzero(last > first)
    if len(busy):
        lo[busy] = np.minimum(lo[busy], _reduce_ranges(np.minimum, p, first[busy], last[busy]))
        hi[busy] = np.maximum(hi[busy], _reduce_ranges(np.maximum, p, first[busy], last[busy]))
    return np.stack([lo, hi], axis=1)


def _reduce_ranges(ufunc, p, first, last) -> np.ndarray:
    """``ufunc.reduce(p[first[i]:last[i]])`` for disjoint, increasing, non-empty ranges."""
    idx = np.empty(2 * len(first), dtype=np.int64)
    idx[0::2], idx[1::2] = first, last
    if idx[-1] >= len(p):
        idx = idx[:-1]                         # the last range runs to the end
    return ufunc.reduceat(p, idx, axis=0)[0::2]


def _instant_bits(vehicles) -> tuple[np.ndarray, list]:
    """The distinct setpoint stamps of all vehicles, and per vehicle a bit set (uint64 words) of
    the ones it has."""
    stamps = np.unique(np.concatenate([sp.t_s for sp, _ in vehicles]))
    words = (len(stamps) + 63) // 64
    bits = []
    for sp, _ in vehicles:
        present = np.zeros(words * 64, dtype=bool)
        present[np.searchsorted(stamps, sp.t_s)] = True
        bits.append(np.packbits(present, bitorder="little").view("<u8"))
    return stamps, bits


def _span_bits(stamps, bits_a, bits_b, lo: float, hi: float):
    """The stamps of either vehicle in ``[lo, hi]`` as bit words: ``(first stamp index of the first
    word, words, whether hi is one of them)``."""
    g_lo = int(np.searchsorted(stamps, lo, side="left"))
    g_hi = int(np.searchsorted(stamps, hi, side="right")) - 1
    w0, w1 = g_lo >> 6, g_hi >> 6
    both = bits_a[w0:w1 + 1] | bits_b[w0:w1 + 1]
    both[0] &= ~np.uint64((1 << (g_lo & 63)) - 1)
    both[-1] &= np.uint64((1 << ((g_hi & 63) + 1)) - 1) if (g_hi & 63) < 63 else np.uint64(2 ** 64 - 1)
    hi_there = stamps[g_hi] == hi and bool((both[-1] >> np.uint64(g_hi & 63)) & np.uint64(1))
    return w0 * 64, both, hi_there


def _instants(stamps, bits_a, bits_b, lo: float, hi: float) -> np.ndarray:
    """``tq`` of :func:`track_pair` (the same values, sorted) from the bit sets."""
    base, both, hi_there = _span_bits(stamps, bits_a, bits_b, lo, hi)
    tq = stamps[base + np.flatnonzero(np.unpackbits(both.view(np.uint8), bitorder="little"))]
    return tq if hi_there else np.append(tq, hi)


def _hot_indices(tq, edges, hot_w, burst_s):
    """The instants (read ``burst_s`` later) and the segments that overlap a window where the bound
    is below the threshold: the only ones that can hold a violation or the smallest distance."""
    last = len(edges) - 2
    wz = np.clip(np.searchsorted(edges, tq + burst_s, side="right") - 1, 0, last)
    wt = np.clip(np.searchsorted(edges, tq, side="right") - 1, 0, last)
    hot_sum = np.concatenate([[0], np.cumsum(hot_w)])
    return np.flatnonzero(hot_w[wz]), np.flatnonzero(hot_sum[wt[1:] + 1] - hot_sum[wt[:-1]] > 0)


def track_pair_hot(a, b, ra, rb, tq, hot, min_sep_m, tol_m, burst_s):
    """:func:`track_pair` evaluated only at the instants and segments ``hot = (instants, segments)``
    (:func:`_hot_indices`; ``tq`` its instants, at least two): the same violations; the smallest
    distance among those evaluated (inf if none)."""
    ta, pa = a.t_s[ra[0]:ra[1]], a.enu_m[ra[0]:ra[1]]
    tb, pb = b.t_s[rb[0]:rb[1]], b.enu_m[rb[0]:rb[1]]
    hot_z, hot_p = hot
    t_z = tq[hot_z] + burst_s if burst_s > 0 else tq[hot_z]
    d_zoh = np.linalg.norm(_hold_at(t_z, ta, pa) - _hold_at(t_z, tb, pb), axis=1)
    ends = np.concatenate([tq[hot_p], tq[hot_p + 1]])
    la, lb = _interp_at(ends, ta, pa), _interp_at(ends, tb, pb)
    n = len(hot_p)
    d_path = synchronous_distance(la[:n], la[n:], lb[:n], lb[n:])
    min_m = min(float(d_zoh.min()) if len(d_zoh) else np.inf, float(d_path.min()) if n else np.inf)
    return len(tq), min_m, _found(a, b, tq, (hot_z, d_zoh), (hot_p, d_path), min_sep_m - tol_m, min_sep_m)


def _pair_items(vehicles, stale_after_s: float, burst_s: float, edges) -> list:
    """Every pair of tracks in the plain order, ``(i, j, ra, rb, lo, hi, lower_bound_m)``, and each
    vehicle's track boxes (:func:`_track_boxes`)."""
    boxes = [[_track_boxes(sp.t_s[r[0]:r[1]], sp.enu_m[r[0]:r[1]], edges) for r in tracks] for sp, tracks in vehicles]
    spans = [[track_span(sp, r, stale_after_s) for r in tracks] for sp, tracks in vehicles]
    flat = [(v, n) for v, (_, tracks) in enumerate(vehicles) for n in range(len(tracks))]   # tracks, vehicle order
    if not flat:
        return [], boxes
    lows = np.stack([boxes[v][n][:, 0] for v, n in flat])                                 # (T, W, 3)
    highs = np.stack([boxes[v][n][:, 1] for v, n in flat])
    track_spans = np.array([spans[v][n] for v, n in flat], dtype=float).reshape(-1, 2)     # (T, 2)
    first = np.cumsum([0] + [len(tracks) for _, tracks in vehicles])   # vehicle v's tracks: first[v]..first[v+1]
    bound = _track_bounds(lows, highs, track_spans, first, [v for v, _ in flat], edges, burst_s)
    lo = np.maximum(track_spans[:, None, 0], track_spans[None, :, 0])
    hi = np.minimum(track_spans[:, None, 1], track_spans[None, :, 1])
    items = []
    for i, (_, tracks_a) in enumerate(vehicles):
        for j in range(i + 1, len(vehicles)):
            for n, ra in enumerate(tracks_a):
                t = first[i] + n
                items.extend((i, j, ra, rb, float(lo[t, u]), float(hi[t, u]), float(bound[t, u]))
                             for u, rb in enumerate(vehicles[j][1], start=first[j]))
    return items, boxes


#: elements ``(pairs, windows, 3)`` of one block of window bounds (8 MB of float64)
_BLOCK_ELEMENTS = 1 << 20


def _track_bounds(lows, highs, track_spans, first, vehicle_of, edges, burst_s) -> np.ndarray:
    """``(T, T)``: for tracks ``t`` and ``u`` of vehicles ``v < w``, at ``[t, u]`` the smallest distance
    between their window boxes over the windows that meet ``[lo, hi + burst_s]`` (both commanded);
    elsewhere inf. The later tracks of a vehicle are a contiguous slice (no copy), a block at a time."""
    count, windows = lows.shape[0], lows.shape[1]
    bound = np.full((count, count), np.inf)
    rows = max(1, _BLOCK_ELEMENTS // max(1, windows * 3))
    for t in range(count):
        for u0 in range(first[vehicle_of[t] + 1], count, rows):
            u1 = min(count, u0 + rows)
            gap = lows[u0:u1] - highs[t]                                   # b_lo - a_hi
            np.maximum(gap, lows[t] - highs[u0:u1], out=gap)               # a_lo - b_hi
            np.maximum(gap, 0.0, out=gap)
            dist2 = np.einsum("mwc,mwc->mw", gap, gap)
            lo = np.maximum(track_spans[u0:u1, 0], track_spans[t, 0])
            hi = np.minimum(track_spans[u0:u1, 1], track_spans[t, 1])
            bound[t, u0:u1] = np.sqrt(_span_bound(dist2, edges, lo, hi + burst_s))   # sqrt of the min: the min of sqrt
    return bound


def _span_bound(dist: np.ndarray, edges, lo, hi) -> np.ndarray:
    """Per row of window distances ``(M, W)``, the smallest over the windows that meet ``[lo, hi]``."""
    w_lo = np.clip(np.searchsorted(edges, lo, side="right") - 1, 0, len(edges) - 2)
    w_hi = np.clip(np.searchsorted(edges, hi, side="right") - 1, 0, len(edges) - 2)
    if np.all(w_lo == 0) and np.all(w_hi == dist.shape[1] - 1):
        return dist.min(axis=1)
    w = np.arange(dist.shape[1])
    return np.where((w >= w_lo[:, None]) & (w <= w_hi[:, None]), dist, np.inf).min(axis=1)


def _box_distance(box_a, box_b) -> np.ndarray:
    """Per window, the distance between two boxes ``(..., W, 2, 3)`` (0 where they overlap)."""
    gap = np.maximum(0.0, np.maximum(box_a[..., 0, :] - box_b[..., 1, :], box_b[..., 0, :] - box_a[..., 1, :]))
    return np.sqrt(np.einsum("...c,...c->...", gap, gap))


def _alone_in_span(sp, r, lo: float, hi: float) -> bool:
    """Whether no setpoint of ``sp`` outside track ``r`` lies in ``[lo, hi]`` (then the vehicle's
    bit set counts that track's instants exactly)."""
    inside = np.searchsorted(sp.t_s, hi, side="right") - np.searchsorted(sp.t_s, lo, side="left")
    in_track = np.searchsorted(sp.t_s[r[0]:r[1]], hi, side="right") - np.searchsorted(sp.t_s[r[0]:r[1]], lo, side="left")
    return inside == in_track


def check_pairs_fast(report, vehicles, min_sep_m: float, tol_m: float, stale_after_s: float, burst_s: float,
                     window_s: float = 1.0) -> int:
    """Every pair's separation, as the exact check of every pair of tracks reports it (module
    docstring); returns how many pairs of tracks were checked exactly.

    Parameters
    ----------
    report : AuditReport
    vehicles : list of (VehicleSetpoints, tracks)
        In the order of the plain pair loop (by system id).
    """
    vehicles = [(sp, tracks) for sp, tracks in vehicles]
    if sum(1 for sp, _ in vehicles if len(sp.t_s)) < 2:
        return 0
    edges = _grid(vehicles, stale_after_s, burst_s, window_s)
    items, boxes = _pair_items(vehicles, stale_after_s, burst_s, edges)
    stamps, bits = _instant_bits(vehicles)
    limit = min_sep_m - tol_m
    results, smallest = {}, np.inf
    one_track_each = all(len(tracks) <= 1 for _, tracks in vehicles)
    for k in np.argsort(np.array([item[6] for item in items]), kind="stable").tolist():   # closest bound first
        i, j, ra, rb, lo, hi, bound = items[k]
        if hi < lo:
            continue
        (a, tracks_a), (b, tracks_b) = vehicles[i], vehicles[j]
        threshold = max(smallest, limit) + _BOUND_MARGIN_M
        alone = ((len(tracks_a) == 1 or _alone_in_span(a, ra, lo, hi))
                 and (len(tracks_b) == 1 or _alone_in_span(b, rb, lo, hi)))
        if alone and bound >= threshold:
            if one_track_each:
                break            # every pair left is alone, its bound at least this one: all skipped
            continue
        tq = _instants(stamps, bits[i], bits[j], lo, hi) if alone else None
        if tq is None or len(tq) < 2:
            results[k] = track_pair(a, b, ra, rb, min_sep_m, tol_m, stale_after_s, burst_s)
        else:
            hot_w = _box_distance(boxes[i][tracks_a.index(ra)], boxes[j][tracks_b.index(rb)]) < threshold
            results[k] = track_pair_hot(a, b, ra, rb, tq, _hot_indices(tq, edges, hot_w, burst_s), min_sep_m, tol_m,
                                        burst_s)
        smallest = min(smallest, results[k][1])
    skipped = []
    for k, (i, j, ra, rb, lo, hi, _) in enumerate(items):
        if hi < lo:
            continue
        if k in results:
            apply_track_pair(report, results[k])
        else:
            skipped.append((i, j, lo, hi))
    counts = _count_instants_many(stamps, np.stack(bits), skipped)
    report.separation_instants_checked += int(counts.sum())
    report.separation_segments_checked += int(np.maximum(counts - 1, 0).sum())
    return len(results)


_ALL_BITS = np.uint64(2 ** 64 - 1)


def _count_instants_many(stamps, bits, spans) -> np.ndarray:
    """``len(tq)`` of :func:`track_pair` for many pairs of vehicles whose tracks are alone in their
    span, from the bit sets: per ``(i, j, lo, hi)`` of ``spans``, the distinct stamps of vehicle
    ``i`` or ``j`` in ``[lo, hi]``, plus one unless ``hi`` is one of them (``lo`` always is).
    ``bits``: the ``(N, words)`` bit sets of :func:`_instant_bits`. Blocks of pairs, bounded memory."""
    if not spans:
        return np.zeros(0, dtype=np.int64)
    i, j = (np.array([s[c] for s in spans], dtype=np.int64) for c in (0, 1))
    lo, hi = (np.array([s[c] for s in spans], dtype=float) for c in (2, 3))
    g_lo = np.searchsorted(stamps, lo, side="left")
    g_hi = np.searchsorted(stamps, hi, side="right") - 1
    w0, w1 = g_lo >> 6, g_hi >> 6
    hi_word = bits[i, w1] | bits[j, w1]
    hi_there = (stamps[g_hi] == hi) & ((hi_word >> (g_hi & 63).astype(np.uint64)) & np.uint64(1)).astype(bool)
    counts = np.where(hi_there, 0, 1).astype(np.int64)
    low_keep = ~((np.uint64(1) << (g_lo & 63).astype(np.uint64)) - np.uint64(1))       # bits >= g_lo in word w0
    top = (g_hi & 63).astype(np.uint64)
    shift = np.minimum(top + np.uint64(1), np.uint64(63))                                  # no shift by 64
    high_keep = np.where(top < 63, (np.uint64(1) << shift) - np.uint64(1), _ALL_BITS)      # bits <= g_hi in word w1
    rows = max(1, _BLOCK_ELEMENTS // max(1, bits.shape[1]))
    for r0 in range(0, len(spans), rows):
        r = slice(r0, r0 + rows)
        c0, c1 = int(w0[r].min()), int(w1[r].max())
        both = bits[i[r], c0:c1 + 1] | bits[j[r], c0:c1 + 1]                           # (rows, words)
        col = np.arange(c0, c1 + 1)
        keep = np.where((col >= w0[r, None]) & (col <= w1[r, None]), _ALL_BITS, np.uint64(0))
        at = np.arange(len(keep))
        keep[at, w0[r] - c0] &= low_keep[r]
        keep[at, w1[r] - c0] &= high_keep[r]
        counts[r] += np.bitwise_count(both & keep).sum(axis=1, dtype=np.int64)
    return counts
