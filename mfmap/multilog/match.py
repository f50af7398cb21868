"""Which of a log's floors are which of the building's, and where the log's frame lies in the
building's: global registration of floors that look alike, then ICP.

Each floor is its walls and furniture in a height band above its own level (floor-relative z),
from the keyframes' clouds at their optimised poses. A log's floor is searched on every floor of
the building with no initial pose: `mfmap.localize.search`'s correlative search in x, y and yaw
(the whole floor is the query), its best distinct places refined by point-to-plane ICP and scored
by their fitness. The log's own floors stage says how its floors stand to each other (relative
barometric heights, never absolute pressures, which differ from day to day), so a hypothesis is
one pair of floors taken as the same: the log's other floors land on the building's floors at the
same relative height, or are floors the building does not have yet. A hypothesis counts only when
the log's shared floors agree on the frame, and the best one is taken only when it is clear:
every other hypothesis, and every distinct place on its floors, leaves `misfit_ratio` times as
many points unfit. Otherwise the log is refused: a confident wrong merge is worse than none.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mfmap.localize.search import SearchField, coarse_places, fitness, pose_xyz_yaw, refine
from mfmap.mapping.geometry import wrap_angle, yaw_rad
from mfmap.mapping.registration import IcpTarget, downsample, icp
from mfmap.types import F64


@dataclass(frozen=True)
class MatchConfig:
    """How floors of two logs are registered and when a match is clear enough to merge."""

    band_m: tuple[float, float] = (0.25, 2.2)  # walls and furniture, not floor and ceiling
    voxel_m: float = 0.1
    resolution_m: float = 0.2  # the coarse search's cell
    yaw_step_deg: float = 2.0
    places: int = 6  # distinct coarse places refined by ICP per pair of floors
    fit_distance_m: float = 0.1
    min_fitness: float = 0.6
    misfit_ratio: float = 1.5
    distinct_m: float = 1.0
    distinct_deg: float = 10.0
    agree_m: float = 0.3  # the shared floors of one hypothesis agree on the frame this closely
    agree_deg: float = 1.5
    level_tolerance_m: float = 1.0  # a log's floor is a building floor within this height


@dataclass(frozen=True)
class FloorCloud:
    """A floor's band points (z floor-relative) in its own frame, and its level in that frame."""

    points: F64
    level_m: float


@dataclass(frozen=True)
class PairFit:
    """A log floor registered on a building floor: log frame -> building frame (x, y, yaw)."""

    log_floor: int
    building_floor: int
    transform: F64  # 4x4, z not included (floor-relative clouds)
    fitness: float  # share of the log floor's points within fit_distance_m of the building's
    runner_up: float  # the best distinct place's fitness on the same floor

    def to_json(self) -> dict[str, Any]:
        return {"log_floor": self.log_floor, "building_floor": self.building_floor,
                "fitness": round(self.fitness, 4), "runner_up_fitness": round(self.runner_up, 4),
                "x_m": round(float(self.transform[0, 3]), 4),
                "y_m": round(float(self.transform[1, 3]), 4),
                "yaw_deg": round(math.degrees(yaw_rad(self.transform)), 4)}


@dataclass(frozen=True)
class LogMatch:
    """The log's floors on the building's and its frame in the building's, or why not."""

    floors: dict[int, int]  # log floor -> building floor (-1: one the building lacks)
    transform: F64  # 4x4 log frame -> building frame: x, y, yaw and z
    pairs: list[PairFit]  # the shared floors' registrations
    accepted: bool
    reason: str
    alternatives: list[dict[str, Any]] = field(default_factory=list)

    @property
    def fitness(self) -> float:
        return float(np.mean([p.fitness for p in self.pairs])) if self.pairs else 0.0


def register_floor(ref: FloorCloud, query: FloorCloud, log_floor: int, building_floor: int,
                   cfg: MatchConfig) -> PairFit:
    """The query floor's place on the reference floor, searched everywhere, refined by ICP."""
    field_ = SearchField.from_points(ref.points[:, :2], cfg.resolution_m)
    centre = np.zeros(3)
    centre[:2] = query.points[:, :2].mean(axis=0)
    local = downsample(query.points - centre, cfg.voxel_m)
    reach = float(np.hypot(local[:, 0], local[:, 1]).max()) + 1.0
    places = coarse_places(field_, local[:, :2], cfg.yaw_step_deg, reach, cfg.places,
                           cfg.distinct_m, cfg.distinct_deg)
    target = IcpTarget.estimate(downsample(ref.points, cfg.voxel_m), 3.0 * cfg.voxel_m)
    fits: list[tuple[float, F64]] = []
    for x, y, yaw, _score in places:
        pose, fit = refine(local, target, pose_xyz_yaw(x, y, 0.0, yaw), cfg.fit_distance_m)
        fits.append((fit, _level(pose)))
    if not fits:
        return PairFit(log_floor, building_floor, np.eye(4), 0.0, 0.0)
    fits.sort(key=lambda f: -f[0])
    best = _level(icp(local, target, fits[0][1], 2.0 * cfg.voxel_m, cfg.voxel_m, 50).transform)
    best_fit = fitness(local, target, best, cfg.fit_distance_m)
    runner_up = max((f for f, pose in fits[1:] if _distinct(pose, best, cfg)), default=0.0)
    shift = np.eye(4)
    shift[:3, 3] = -centre
    return PairFit(log_floor, building_floor, best @ shift, best_fit, runner_up)


def _level(pose: F64) -> F64:
    """x, y and yaw of a pose; no roll, pitch or z (the clouds are gravity-aligned, z relative)."""
    return pose_xyz_yaw(float(pose[0, 3]), float(pose[1, 3]), 0.0, yaw_rad(pose))


def _distinct(a: F64, b: F64, cfg: MatchConfig) -> bool:
    dyaw = abs(math.degrees(wrap_angle(yaw_rad(a) - yaw_rad(b))))
    return bool(np.hypot(*(a[:2, 3] - b[:2, 3])) > cfg.distinct_m or dyaw > cfg.distinct_deg)


def _agree(a: F64, b: F64, at_xy: F64, cfg: MatchConfig) -> bool:
    """Do two log-to-building transforms put the point `at_xy` (log frame) in one place?"""
    dyaw = abs(math.degrees(wrap_angle(yaw_rad(a) - yaw_rad(b))))
    p = np.array([at_xy[0], at_xy[1], 0.0, 1.0])
    return bool(np.hypot(*((a @ p)[:2] - (b @ p)[:2])) <= cfg.agree_m and dyaw <= cfg.agree_deg)


def _hypotheses(log: dict[int, FloorCloud], building: dict[int, FloorCloud],
                cfg: MatchConfig) -> list[dict[int, int]]:
    """Each pair of floors taken as one, the log's others placed by relative height: the
    distinct log floor -> building floor assignments (-1: a floor the building lacks)."""
    out: list[dict[int, int]] = []
    for j0, k0 in ((j, k) for j in sorted(log) for k in sorted(building)):
        dz = building[k0].level_m - log[j0].level_m
        assignment: dict[int, int] = {}
        for j in sorted(log):
            near = [k for k in building if abs(building[k].level_m - (log[j].level_m + dz))
                    <= cfg.level_tolerance_m]
            assignment[j] = min(near, key=lambda k: abs(building[k].level_m - log[j].level_m - dz),
                                default=-1)
        used = [k for k in assignment.values() if k >= 0]
        if len(used) == len(set(used)) and assignment not in out:
            out.append(assignment)
    return out


def match_log(log: dict[int, FloorCloud], building: dict[int, FloorCloud],
              cfg: MatchConfig) -> LogMatch:
    """The log's floors on the building's floors and its frame in the building's frame."""
    fits: dict[tuple[int, int], PairFit] = {}
    scored: list[tuple[float, dict[int, int], list[PairFit]]] = []
    for assignment in _hypotheses(log, building, cfg):
        pairs = []
        for j, k in sorted(assignment.items()):
            if k >= 0:
                if (j, k) not in fits:
                    fits[(j, k)] = register_floor(building[k], log[j], j, k, cfg)
                pairs.append(fits[(j, k)])
        best = max(pairs, key=lambda p: p.fitness)
        agree = all(_agree(p.transform, best.transform, log[p.log_floor].points[:, :2].mean(axis=0),
                           cfg) for p in pairs)
        score = float(np.mean([p.fitness for p in pairs])) if agree else 0.0
        scored.append((score, assignment, pairs))
    if not scored:
        return LogMatch({}, np.eye(4), [], False, "no floor to register")
    scored.sort(key=lambda s: -s[0])
    score, assignment, pairs = scored[0]
    alternatives = [{"floors": {str(j): k for j, k in a.items()}, "fitness": round(s, 4)}
                    for s, a, _ in scored[1:]]
    transform = _frame(pairs, log, building)
    reason = _verdict(score, scored[1][0] if len(scored) > 1 else 0.0, pairs, cfg)
    return LogMatch(assignment, transform, pairs, reason == "ok", reason, alternatives)


def _verdict(best: float, second: float, pairs: list[PairFit], cfg: MatchConfig) -> str:
    """"ok", or why the best hypothesis is not a clear match."""
    if best < cfg.min_fitness:
        return (f"no floor fits: the best registration leaves {100 * (1 - best):.0f} % of its "
                f"points unfit (fitness {best:.2f} < {cfg.min_fitness:.2f})")
    if 1.0 - second < cfg.misfit_ratio * (1.0 - best):
        return (f"ambiguous: another assignment of its floors fits nearly as well (fitness "
                f"{second:.2f} against {best:.2f})")
    for p in pairs:
        if 1.0 - p.runner_up < cfg.misfit_ratio * (1.0 - p.fitness):
            return (f"ambiguous: its floor {p.log_floor} fits two places of building floor "
                    f"{p.building_floor} (fitness {p.runner_up:.2f} against {p.fitness:.2f})")
    return "ok"


def _frame(pairs: list[PairFit], log: dict[int, FloorCloud],
           building: dict[int, FloorCloud]) -> F64:
    """The log frame in the building frame: x, y, yaw of the best-fitting shared floor, z from
    the shared floors' levels (the same slab)."""
    best = max(pairs, key=lambda p: p.fitness)
    out = best.transform.copy()
    out[2, 3] = float(np.mean([building[p.building_floor].level_m - log[p.log_floor].level_m
                               for p in pairs]))
    return out


__all__ = ["FloorCloud", "LogMatch", "MatchConfig", "PairFit", "match_log", "register_floor"]
