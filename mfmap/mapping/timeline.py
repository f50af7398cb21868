"""Where a stamp falls in the floors stage's segmentation: a floor visit, a ride or a walk."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np

from mfmap.types import FloorSegmentation, Transition, TransitionKind


class SegmentKind(str, Enum):
    VISIT = "visit"
    RIDE = "ride"  # in an elevator
    WALK = "walk"  # on stairs (or a transition of unknown kind)


@dataclass(frozen=True)
class Segment:
    """Where a scan falls: a floor visit, an elevator ride or a walk (stairs) between visits."""

    kind: SegmentKind
    visit: int  # the visit (for a transition: the visit before it)
    floor_id: int
    transition: Transition | None = None


class Timeline:
    """Maps a stamp to its Segment using the floors stage's visits and transitions."""

    def __init__(self, seg: FloorSegmentation) -> None:
        self.visits = seg.visits() or [(0, -(2**62), 2**62)]
        self.transitions = sorted(seg.transitions, key=lambda tr: tr.start_ns)
        self._starts = np.array([v[1] for v in self.visits], dtype=np.int64)

    def at(self, stamp_ns: int) -> Segment:
        v = max(int(np.searchsorted(self._starts, stamp_ns, side="right")) - 1, 0)
        for tr in self.transitions:
            if tr.start_ns <= stamp_ns <= tr.end_ns:
                kind = SegmentKind.RIDE if tr.kind == TransitionKind.ELEVATOR else SegmentKind.WALK
                return Segment(kind, v, self.visits[v][0], tr)
        return Segment(SegmentKind.VISIT, v, self.visits[v][0])
