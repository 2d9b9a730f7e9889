"""The separation hold must not freeze a formation (docs/faults.md, "separation-hold deadlock").

Vehicles flown straight to their goals through the safety gate (the ramp) and the envelope, as the
re-formation's settle does: every batch sent keeps every pair at the separation (or at its start
distance for a pair that started closer), inside the fence and the speed limit, and every vehicle
reaches its goal. Before the envelope moved held vehicles aside, a pair that wanted to cross was
held at its previous setpoints tick after tick for good: the swap below, and 32 of 60 random
re-formations of a radius-2 m CVT formation around a lost vehicle with its slots rotated
(``reformed_offsets`` then a rotation, as ``clear_offsets`` does) never arrived.
"""
from __future__ import annotations

import numpy as np
import pytest

from tests.support.separation_flight import CENTRE, fly as _fly, reformation_case


def test_head_on_swap_at_radius_2_completes():
    ticks, gate = _fly([CENTRE + (-2, 0, 0), CENTRE + (2, 0, 0)], [CENTRE + (2, 0, 0), CENTRE + (-2, 0, 0)])
    assert ticks is not None, "the pair was frozen by the separation hold"
    assert gate.separation_interventions > 0          # it did have to intervene


def test_a_pair_already_closer_than_the_separation_crosses_without_closing_in():
    # 1.4 m apart (< 1.5 m: e.g. a transfer's interpolation); each wants the other's side
    ticks, _ = _fly([CENTRE + (-0.7, 0, 0), CENTRE + (0.7, 0, 0)], [CENTRE + (1.0, 0, 0), CENTRE + (-1.0, 0, 0)])
    assert ticks is not None


def test_three_vehicles_rotating_their_slots_complete():
    a, b, c = CENTRE + (-1, 0, 0), CENTRE + (1, 0, 0), CENTRE + (0, 1.8, 0)
    ticks, _ = _fly([a, b, c], [b, a, CENTRE + (0, -1.8, 0)])
    assert ticks is not None


# each seed draws N, the lost vehicle and the rotation; 6 of these 12 (0, 2, 4, 6, 9, 11) froze before the fix
@pytest.mark.parametrize("seed", range(12))
def test_reformation_around_a_lost_vehicle_at_radius_2_settles(seed):
    n, lost, starts, goals = reformation_case(seed)
    ticks, _ = _fly(starts, goals)
    assert ticks is not None, f"N={n}, lost {lost}: the re-formed formation never settled"


def test_moves_aside_stay_inside_a_tight_fence():
    # the formation's box plus 0.3 m: moving aside must not leave it (checked every batch in _fly)
    tight = np.array([(-2.5, -2.5), (2.5, -2.5), (2.5, 2.5), (-2.5, 2.5)])
    ticks, _ = _fly([CENTRE + (-2, 0, 0), CENTRE + (2, 0, 0)], [CENTRE + (2, 0, 0), CENTRE + (-2, 0, 0)],
                    poly=tight)
    assert ticks is not None
