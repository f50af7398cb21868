"""One log of a multi-log build: its floors, its mapping and its own factor graph, each exactly
as a single-log build of it runs them (`mfmap.pipeline`), in the log's own frame.

The graph is solved here as `mfmap.graph.optimize.optimize_building` solves it, but on a
`Builder` this module keeps: its factors go on into the building's one graph
(`mfmap.multilog.joint`), the solution is where that graph starts from.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mfmap.config import MfmapConfig
from mfmap.graph.factors import Builder, X
from mfmap.graph.floorlinks import median_floor_z
from mfmap.graph.interfloor import FloorMatch
from mfmap.graph.optimize import _Sensors, _solve
from mfmap.logs import WarningCollector
from mfmap.pipeline import _Floors, _Stages, graph_floors
from mfmap.progress import Progress
from mfmap.types import F64, Keyframe, MappingResult

if TYPE_CHECKING:
    from mfmap.graph.heights import Calibration
    from mfmap.ingest.source import LogSource


@dataclass
class LogGraph:
    """A log's own factor graph and its solution, in the log's frame."""

    builder: Builder
    result: Any  # gtsam.Values
    keyframes: list[Keyframe]  # by time
    poses: dict[int, F64]  # keyframe id -> optimised base-in-log-frame pose
    floor_z_m: dict[int, float]  # the log's floor -> median keyframe z, log frame
    matches: list[FloorMatch]
    rides: list[dict[str, Any]]
    calibration: Calibration
    iterations: int


@dataclass
class LogRun:
    """One log's stages: what the building's graph and exports take from it."""

    index: int  # the log's place in the build (0: the building's frame)
    path: Path
    stages: _Stages
    floors: _Floors
    mapping: MappingResult
    graph: LogGraph

    @property
    def src(self) -> LogSource:
        return self.stages.src

    @property
    def name(self) -> str:
        return self.path.name


def run_log(index: int, log: Path, src: LogSource, cfg: MfmapConfig, progress: Progress,
            collected: WarningCollector) -> LogRun:
    """The floors, the mapping and the log's own graph, as a single-log build runs them."""
    with contextlib.ExitStack() as workers:
        stages = _Stages.start(log, src, cfg, progress, collected, workers)
        floors, mapping = stages.mapping(stages.floors())
        t0 = time.perf_counter()
        graph = solve_log(stages, floors, mapping, progress)
        stages.timings["graph"] = time.perf_counter() - t0
    # The worker pool is closed with the log's mapping; the maps start their own when needed.
    stages.pool = None
    return LogRun(index, log, stages, floors, mapping, graph)


def solve_log(stages: _Stages, floors: _Floors, mapping: MappingResult,
              progress: Progress) -> LogGraph:
    """The log's graph, as `optimize_building` builds and solves it, keeping the factors."""
    import gtsam

    from mfmap.graph.gravity import gravity_at_keyframes

    cfg = floors.cfg
    imu, odom = stages.src.imu(), stages.src.odometry()
    gravity = gravity_at_keyframes(imu, mapping.keyframes, stages.extrinsics,
                                   odom=odom if cfg.graph.gravity.minus_odometry else None)
    kfs = sorted(mapping.keyframes, key=lambda k: (k.stamp_ns, k.id))
    initial = {k.id: np.asarray(k.pose, dtype=np.float64).copy() for k in kfs}
    builder = Builder(cfg.graph)
    values = gtsam.Values()
    for kf in kfs:
        values.insert(X(kf.id), gtsam.Pose3(initial[kf.id]))
    sensors = _Sensors(floors.pressure, cfg.floors.temperature_k, gravity, imu, floors.scale_sigma)
    seg, graph_cfg = graph_floors(floors.seg, floors.pressure, cfg.graph)
    result, iterations, matches, rides, calibration = _solve(
        builder, values, kfs, mapping.edges, initial, seg, graph_cfg, sensors, stages.pool,
        progress)
    poses = {k.id: np.asarray(result.atPose3(X(k.id)).matrix(), dtype=np.float64) for k in kfs}
    return LogGraph(builder, result, kfs, poses, median_floor_z(kfs, poses), matches, rides,
                    calibration, iterations)


__all__ = ["LogGraph", "LogRun", "run_log", "solve_log"]
