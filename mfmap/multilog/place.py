"""Every log placed in the building: its frame in the building frame and its floors on the
building's floors, log by log against the floors placed so far (`mfmap.multilog.match`).

The first log is the building frame: its floors are the building's first floors. Each further
log is matched against every floor placed before it; a log that matches none yet is tried again
once the others are placed (it may share a floor only with a later log). Logs that never match
are refused, by name, before anything is written.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mfmap.errors import MfmapError
from mfmap.graph.floorlinks import floor_points
from mfmap.multilog.logs import LogRun
from mfmap.multilog.match import FloorCloud, LogMatch, MatchConfig, match_log
from mfmap.types import F64

logger = logging.getLogger(__name__)


class UnplacedLogsError(MfmapError):
    """Logs that share no floor with the others clearly enough to be merged."""


@dataclass
class Placement:
    """Where each log lies in the building (by log index) and the building's floors."""

    transforms: dict[int, F64] = field(default_factory=dict)  # log frame -> building frame
    floors: dict[int, dict[int, int]] = field(default_factory=dict)  # log floor -> building
    matches: dict[int, LogMatch] = field(default_factory=dict)  # every log but the first
    order: list[int] = field(default_factory=list)  # the order the logs were placed in
    clouds: dict[int, FloorCloud] = field(default_factory=dict)  # building floor, building frame
    levels: dict[int, float] = field(default_factory=dict)  # building floor -> its z

    def add(self, run: LogRun, transform: F64, floors: dict[int, int],
            own: dict[int, FloorCloud]) -> None:
        """The log's floors' points join the building's (a new floor keeps the log's level)."""
        self.transforms[run.index] = transform
        self.floors[run.index] = floors
        self.order.append(run.index)
        for j, k in floors.items():
            self.levels.setdefault(k, run.graph.floor_z_m[j] + float(transform[2, 3]))
        rot, shift = transform[:2, :2], transform[:2, 3]
        for j, cloud in own.items():
            moved = cloud.points.copy()
            moved[:, :2] = cloud.points[:, :2] @ rot.T + shift
            k = floors[j]
            if k in self.clouds:
                old = self.clouds[k]
                self.clouds[k] = FloorCloud(np.concatenate([old.points, moved]), old.level_m)
            else:
                self.clouds[k] = FloorCloud(moved, self.levels[k])

    def renumbered(self) -> dict[int, int]:
        """Building floor ids by height, 0 the lowest: provisional id -> final id."""
        return {k: i for i, k in enumerate(sorted(self.levels, key=lambda k: self.levels[k]))}

    def to_json(self, runs: list[LogRun], final: dict[int, int]) -> list[dict[str, Any]]:
        """report.json's `logs`: each log's floors on the building's, and its registration."""
        out = []
        for run in runs:
            t = self.transforms[run.index]
            item: dict[str, Any] = {
                "log": str(run.path), "index": run.index,
                "floors": {str(j): final[k] for j, k in sorted(self.floors[run.index].items())},
                "frame": {"x_m": round(float(t[0, 3]), 4), "y_m": round(float(t[1, 3]), 4),
                          "z_m": round(float(t[2, 3]), 4),
                          "yaw_deg": round(float(np.degrees(np.arctan2(t[1, 0], t[0, 0]))), 4)},
            }
            match = self.matches.get(run.index)
            if match is None:
                item["registration"] = "the building frame (its first scan)"
            else:
                item["registration"] = [{**p.to_json(), "building_floor": final[p.building_floor]}
                                        for p in match.pairs]
                item["alternatives"] = match.alternatives
            out.append(item)
        return out


def log_floor_clouds(run: LogRun, band_m: tuple[float, float], voxel_m: float
                     ) -> dict[int, FloorCloud]:
    """Each floor of the log: its band points (z floor-relative) and level, in the log frame."""
    from mfmap.mapping.registration import downsample

    out: dict[int, FloorCloud] = {}
    graph = run.graph
    for floor_id, level in sorted(graph.floor_z_m.items()):
        points = floor_points(graph.keyframes, graph.poses, floor_id, band_m, level)
        if len(points) >= 200:
            out[floor_id] = FloorCloud(downsample(points, voxel_m), level)
    return out


def place_logs(runs: list[LogRun], cfg: MatchConfig) -> Placement:
    """Place every log; refuse those that cannot be (UnplacedLogsError names them)."""
    placement = Placement()
    clouds = {run.index: log_floor_clouds(run, cfg.band_m, cfg.voxel_m) for run in runs}
    first = runs[0]
    placement.add(first, np.eye(4), {j: j for j in first.graph.floor_z_m}, clouds[first.index])
    waiting = list(runs[1:])
    last: dict[int, LogMatch] = {}
    while waiting:
        placed_any = False
        for run in list(waiting):
            match = match_log(clouds[run.index], placement.clouds, cfg)
            last[run.index] = match
            logger.debug("%s: %s", run.name, match.reason)
            if match.accepted:
                placement.matches[run.index] = match
                floors = _assign(run, match, placement, cfg.level_tolerance_m)
                placement.add(run, match.transform, floors, clouds[run.index])
                waiting.remove(run)
                placed_any = True
        if not placed_any:
            break
    if waiting:
        raise UnplacedLogsError(_refusal(waiting, last))
    return placement


def _assign(run: LogRun, match: LogMatch, placement: Placement, tolerance_m: float
            ) -> dict[int, int]:
    """Log floor -> building floor: the match's, else the building floor at the log floor's
    height (a floor too small to register), else a new building floor."""
    dz = float(match.transform[2, 3])
    out: dict[int, int] = {}
    next_id = max(placement.levels, default=-1) + 1
    for j, level in sorted(run.graph.floor_z_m.items()):
        k = match.floors.get(j, -1)
        if k < 0:
            near = [b for b, z in placement.levels.items() if abs(z - level - dz) <= tolerance_m]
            k = min(near, key=lambda b: abs(placement.levels[b] - level - dz), default=-1)
        if k < 0 or k in out.values():
            k, next_id = next_id, next_id + 1
        out[j] = k
    return out


def _refusal(waiting: list[LogRun], last: dict[int, LogMatch]) -> str:
    """One line: which logs, and why each."""
    parts = [f"{run.path} ({last[run.index].reason})" if run.index in last else str(run.path)
             for run in waiting]
    return ("cannot merge " + "; ".join(parts) + ": no floor of it matches a floor of the other "
            "logs clearly (another building, or no floor in common); build it on its own")


__all__ = ["Placement", "UnplacedLogsError", "log_floor_clouds", "place_logs"]
