"""The mapping's view of a stair walk: wider than the floors stage's (mfmap.mapping.timeline)."""

from __future__ import annotations

import numpy as np

from mfmap.mapping.timeline import SegmentKind, Timeline, widen_walks
from mfmap.types import Floor, FloorSegmentation, Transition, TransitionKind

S = 1_000_000_000


def _seg(kinds: list[TransitionKind]) -> FloorSegmentation:
    """Visits of 60 s and transitions of 20 s, alternating floors 0 and 1."""
    transitions = tuple(Transition(kind, k % 2, (k + 1) % 2, (60 + 80 * k) * S, (80 + 80 * k) * S, 3.0)
                        for k, kind in enumerate(kinds))
    edges = [0] + [t for tr in transitions for t in (tr.start_ns, tr.end_ns)] + [(80 * len(kinds) + 60) * S]
    visits = [(edges[2 * k], edges[2 * k + 1]) for k in range(len(kinds) + 1)]
    floors = tuple(Floor(f, 3.0 * f, 0.0, tuple(v for k, v in enumerate(visits) if k % 2 == f)) for f in (0, 1))
    zeros = np.zeros(2)
    return FloorSegmentation(floors, transitions, np.array([0, 1], dtype=np.int64), zeros, zeros,
                             np.zeros(2, dtype=np.int32))


def test_a_walk_is_widened_and_its_visits_shortened_alike() -> None:
    seg = _seg([TransitionKind.STAIRS, TransitionKind.ELEVATOR])
    wide = widen_walks(seg, 2 * S)
    walk, ride = wide.transitions
    assert (walk.start_ns, walk.end_ns) == (58 * S, 82 * S)
    assert (ride.start_ns, ride.end_ns) == (140 * S, 160 * S)  # rides are timed by the IMU: kept
    assert [v[1:] for v in wide.visits()] == [(0, 58 * S), (82 * S, 140 * S), (160 * S, 220 * S)]
    timeline = Timeline(wide)
    assert timeline.at(59 * S).kind is SegmentKind.WALK and timeline.at(83 * S).kind is SegmentKind.VISIT


def test_a_short_visit_between_walks_keeps_half_its_length() -> None:
    seg = _seg([TransitionKind.STAIRS, TransitionKind.STAIRS])
    wide = widen_walks(seg, 40 * S)
    first, second = wide.transitions
    # The 60 s visit between them: each walk takes at most a quarter of it.
    assert (first.end_ns, second.start_ns) == (95 * S, 125 * S)
    assert (first.start_ns, second.end_ns) == (45 * S, 175 * S)
    seg = _seg([TransitionKind.STAIRS])
    assert widen_walks(seg, 0) is seg
