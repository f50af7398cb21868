"""The mapping stage: one pass over the lidar scans, floor visit by floor visit.

Per scan: sensor -> base frame, range filter, deskew, cabin filter, scan-to-local-map ICP from the
motion prior, keyframe decision, loop search on the same floor (`mapper.Mapper`). Elevator rides
hold x, y, yaw (scans not registered); stairs keep the odometry running with z free, and the
floor reached starts a new, levelled local map. With `workers` > 1 the runs of visits between
elevator rides (and with `split_at_stairs` stair walks) are mapped in parallel processes and
chained afterwards (`chunks`).
"""

from __future__ import annotations

import logging
import time
from concurrent.futures import Executor

from mfmap.errors import MissingDataError
from mfmap.mapping.chunks import map_parallel, plan_chunks
from mfmap.mapping.config import MappingConfig
from mfmap.mapping.mapper import Mapper
from mfmap.mapping.motion import MotionModel
from mfmap.mapping.source import LogSourceLike, read_scans, reopener
from mfmap.mapping.timeline import Timeline, widen_walks
from mfmap.progress import NullProgress, Progress
from mfmap.types import Extrinsics, FloorSegmentation, MappingResult, Role

logger = logging.getLogger(__name__)


def map_floors(
    source: LogSourceLike,
    seg: FloorSegmentation,
    cfg: MappingConfig,
    extrinsics: Extrinsics,
    progress: Progress | None = None,
    pool: Executor | None = None,
) -> MappingResult:
    """Per-floor lidar odometry, keyframes and verified same-floor loop closures.

    Keyframe poses are initial guesses in the world frame (the first visit starts at identity);
    every lidar scan gets a ScanPose. Uses 3D clouds, or LaserScans when the log has no 3D lidar.
    With `cfg.workers` > 1 and a log that can be opened again (`source.reopener`), the runs of
    visits between elevator rides are mapped in parallel processes (see `chunks.map_parallel`):
    in `pool` when given (its processes must have been started by `workers.worker_pool`), else
    in a pool of their own.
    """
    progress = progress or NullProgress()
    roles = source.roles
    planar = Role.LIDAR not in roles
    if planar and Role.SCAN2D not in roles:
        raise MissingDataError("the log has no lidar (neither PointCloud2 nor LaserScan)")
    total = source.count(Role.SCAN2D if planar else Role.LIDAR)
    started = time.perf_counter()
    seg = widen_walks(seg, round(cfg.stairs.walk_margin_s * 1e9))
    chunks = plan_chunks(Timeline(seg), cfg.split_at_stairs)
    reopen = reopener(source)
    with progress.stage("mapping", total=total) as bar:
        if cfg.workers > 1 and len(chunks) > 1 and reopen is not None:
            result = map_parallel(source, seg, cfg, extrinsics, planar, chunks, reopen, bar, pool)
        else:
            mapper = Mapper(cfg, seg, extrinsics, MotionModel(
                cfg.motion.prior, source.odometry(), source.imu(), extrinsics), planar)
            for stamp_ns, frame_id, xyz, t_offset_ns in read_scans(source, planar):
                mapper.add_scan(stamp_ns, frame_id, xyz, t_offset_ns)
                bar.advance()
            result = mapper.result()
    elapsed = time.perf_counter() - started
    result.stats["elapsed_s"] = elapsed
    result.stats["scans_per_s"] = len(result.scan_poses) / elapsed if elapsed > 0 else 0.0
    return result
