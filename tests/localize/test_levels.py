"""The barometer's floor hypotheses: one unknown offset between a log's levels and a map's."""

from __future__ import annotations

import pytest

from mfmap.localize.levels import best_hypotheses, floor_hypotheses


def test_start_upstairs_two_floors() -> None:
    # The log starts on the upper floor (its level 0) and rides 3.5 m down.
    hyps = floor_hypotheses({0: 0.0, 1: -3.48}, {0: 20.0, 1: 60.0}, {0: 0.0, 1: 3.5}, 1.0)
    best = best_hypotheses(hyps)
    assert len(best) == 1
    assert best[0].floor_of(0) == 1 and best[0].floor_of(1) == 0
    assert best[0].offset_m == pytest.approx(3.49, abs=0.02)
    assert best[0].residual_m == pytest.approx(0.01, abs=0.005)


def test_two_levels_on_three_even_floors_are_two_hypotheses() -> None:
    # Two levels a storey apart fit floors 0-1 and floors 1-2 equally: the barometer alone
    # cannot choose, so both remain for registration to decide.
    hyps = floor_hypotheses({0: 0.0, 1: 4.0}, {0: 100.0, 1: 100.0},
                            {0: 0.0, 1: 4.0, 2: 8.0}, 1.2)
    best = best_hypotheses(hyps)
    assert sorted((h.floor_of(0), h.floor_of(1)) for h in best) == [(0, 1), (1, 2)]


def test_a_level_between_floors_is_on_none() -> None:
    # The log's second level is 2 m above its first: no offset puts both on 3.5 m storeys.
    hyps = floor_hypotheses({0: 0.0, 1: 2.0}, {0: 50.0, 1: 10.0}, {0: 0.0, 1: 3.5}, 1.0)
    best = best_hypotheses(hyps)
    assert all(h.assigned == 1 for h in best)
    # The longer visit on a map floor ranks first.
    assert best[0].floor_of(0) is not None and best[0].floor_of(1) is None
