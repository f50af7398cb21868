"""Where a stamp falls in the floors stage's segmentation: a floor visit, a ride or a walk."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from enum import Enum

import numpy as np

from mfmap.types import Floor, FloorSegmentation, Transition, TransitionKind


def widen_walks(seg: FloorSegmentation, margin_ns: int) -> FloorSegmentation:
    """The segmentation with every stair walk widened by `margin_ns` on each side, within the
    visits either side (a walk takes at most a quarter of each, so each keeps half its length).

    The floors stage times a walk by its flights, for floors.json; the mapping needs the span
    that encloses it (`mapping.stairs.walk_margin_s`): a scan on the steps mapped as the floor's
    puts the steps in its map and pulls its height."""
    visits = seg.visits()
    if margin_ns <= 0 or not any(tr.kind == TransitionKind.STAIRS for tr in seg.transitions):
        return seg
    transitions = sorted(seg.transitions, key=lambda tr: tr.start_ns)
    bounds = {v[1:]: list(v[1:]) for v in visits}
    keys = [v[1:] for v in visits]
    widened = []
    for k, tr in enumerate(transitions):
        if tr.kind != TransitionKind.STAIRS or k + 1 >= len(keys):
            widened.append(tr)
            continue
        before, after = keys[k], keys[k + 1]
        start = max(tr.start_ns - margin_ns, before[1] - (before[1] - before[0]) // 4)
        end = min(tr.end_ns + margin_ns, after[0] + (after[1] - after[0]) // 4)
        bounds[before][1], bounds[after][0] = start, end
        widened.append(dataclasses.replace(tr, start_ns=start, end_ns=end))
    floors = tuple(
        Floor(f.id, f.elevation_m, f.pressure_pa, tuple((bounds[v][0], bounds[v][1]) for v in f.visits))
        for f in seg.floors
    )
    return dataclasses.replace(seg, floors=floors, transitions=tuple(widened))


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
