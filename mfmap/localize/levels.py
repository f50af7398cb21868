"""The log's floors on the map's floors, from the barometer alone.

Within one log the barometer measures heights relative to the start well (the floors stage's
levels, from the height change across each ride or stair walk); across days it does not: the
weather moves the pressure of every floor by hundreds of pascals, tens of metres. So the log's
levels are the map's floor elevations shifted by one unknown offset. Each offset that puts a
level of the log on a floor of the map is a hypothesis; the better ones put more of the log's
time on floors the map has. Registration picks among the hypotheses that remain (and checks the
one that is left).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass


@dataclass(frozen=True)
class FloorHypothesis:
    """One offset between the log's levels and the map's elevations, and what it implies."""

    offset_m: float  # map elevation - log level
    assignment: tuple[tuple[int, int | None], ...]  # (log floor, map floor or None), by log floor
    time_on_map_s: float  # the log's visit time on floors the map has
    residual_m: float  # worst distance of an assigned level from its map floor

    def floor_of(self, log_floor: int) -> int | None:
        return dict(self.assignment).get(log_floor)

    @property
    def assigned(self) -> int:
        return sum(1 for _, m in self.assignment if m is not None)

    def key(self) -> tuple[int, float, float]:
        """Sort key, best first: more log floors assigned, more time on them, closer."""
        return (-self.assigned, -round(self.time_on_map_s, 3), round(self.residual_m, 6))


def floor_hypotheses(log_levels_m: Mapping[int, float], log_time_s: Mapping[int, float],
                     map_elevations_m: Mapping[int, float], tolerance_m: float
                     ) -> list[FloorHypothesis]:
    """Every distinct assignment of the log's floors to the map's, best first.

    An offset is tried for each pair of a log level and a map floor (the level on the floor);
    each log level then goes to the nearest map floor within `tolerance_m`, or to none. Offsets
    giving the same assignment are one hypothesis (the first pair's offset, refined to the mean
    over the assigned levels).
    """
    seen: dict[tuple[tuple[int, int | None], ...], FloorHypothesis] = {}
    log_ids = sorted(log_levels_m)
    for anchor in log_ids:
        for _floor_id, elevation in sorted(map_elevations_m.items()):
            offset = elevation - log_levels_m[anchor]
            pairs: list[tuple[int, int | None]] = []
            for lid in log_ids:
                level = log_levels_m[lid] + offset
                best = min(map_elevations_m.items(), key=lambda kv: (abs(kv[1] - level), kv[0]))
                pairs.append((lid, best[0] if abs(best[1] - level) <= tolerance_m else None))
            assignment = tuple(pairs)
            if assignment in seen:
                continue
            used = [(lid, m) for lid, m in assignment if m is not None]
            if used:
                offset = sum(map_elevations_m[m] - log_levels_m[lid] for lid, m in used) / len(used)
            residual = max((abs(log_levels_m[lid] + offset - map_elevations_m[m]) for lid, m in used),
                           default=0.0)
            time_on = sum(log_time_s.get(lid, 0.0) for lid, _ in used)
            seen[assignment] = FloorHypothesis(offset, assignment, time_on, residual)
    return sorted(seen.values(), key=FloorHypothesis.key)


def best_hypotheses(hypotheses: list[FloorHypothesis]) -> list[FloorHypothesis]:
    """The hypotheses that assign as many of the log's floors as the best one."""
    if not hypotheses:
        return []
    most = hypotheses[0].assigned
    return [h for h in hypotheses if h.assigned == most]
