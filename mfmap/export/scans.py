"""The second pass over the log: every scan the maps use, at its optimised pose, into each
floor's cloud and grid (and the depth cameras' images beside them).

Which scans are used is decided from the optimised trajectory alone, before reading, so the pass
decodes only those; with several floors the floors are shared out over worker processes.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from mfmap.config import MfmapConfig
from mfmap.mapping.cabin import (
    CabinBox,
    cabin_boxes,
    distinct_cabins,
    drop_cabins,
    in_cabin,
    outside_cabins,
)
from mfmap.mapping.geometry import deskew, inverse, rotation_angle_rad, twist
from mfmap.mapping.source import read_scans
from mfmap.progress import NullProgress, Progress, StageProgress
from mfmap.types import F64, Extrinsics, FloorSegmentation, MappingResult, Role, TransitionKind

if TYPE_CHECKING:
    from mfmap.export.mapdata import MapAccumulator
    from mfmap.export.write import FloorTrajectory
    from mfmap.graph.optimize import GraphResult
    from mfmap.ingest.colour import ColourCamera
    from mfmap.ingest.depth import Camera
    from mfmap.ingest.source import LogSource


def accumulate(
    src: LogSource,
    seg: FloorSegmentation,
    mapping: MappingResult,
    graph: GraphResult,
    extrinsics: Extrinsics,
    cfg: MfmapConfig,
    progress: Progress,
    pool: Executor | None = None,
) -> tuple[FloorTrajectory, MapAccumulator]:
    """Each floor's cloud and grid from every scan at its optimised pose (or the keyframes).

    With `cfg.export.workers` > 1 the floors are shared out over processes: those of `pool` when
    given (started by `mapping.workers.worker_pool`), else a pool of their own.
    """
    from mfmap.export.config import CloudSource
    from mfmap.export.mapdata import MapAccumulator
    from mfmap.export.write import optimised_trajectory

    rides = [(tr.start_ns, tr.end_ns) for tr in seg.transitions
             if tr.kind == TransitionKind.ELEVATOR]
    walks = [(tr.start_ns, tr.end_ns) for tr in seg.transitions
             if tr.kind != TransitionKind.ELEVATOR]
    trajectory = optimised_trajectory(mapping, graph.poses, rides, walks)
    maps = MapAccumulator(cfg.export, dict(graph.floor_z_m))
    if cfg.export.cloud.source == CloudSource.KEYFRAMES or trajectory.stamps_ns.shape[0] == 0:
        maps.min_hits = 1  # a keyframe cloud already merges several scans
        for kf in sorted(mapping.keyframes, key=lambda k: k.stamp_ns):
            maps.add(kf.floor_id, graph.poses[kf.id], kf.cloud, force_view=True)
        return trajectory, maps
    cabins = cabin_boxes(seg.transitions, trajectory.stamps_ns, trajectory.poses, cfg.mapping)
    used = _used_scans(seg, trajectory, cabins, cfg)
    job = _MapsJob(src.path, cfg, Role.LIDAR not in src.roles, trajectory, used,
                   distinct_cabins(cabins), extrinsics, dict(graph.floor_z_m))
    groups = _floor_groups(used, trajectory, cfg.export.workers)
    with progress.stage("maps", total=len(used)) as bar, contextlib.ExitStack() as stack:
        if len(groups) < 2:
            return trajectory, _accumulate_scans(src, job, bar)
        # One floor group per process (a floor's cloud and grid never depend on another floor,
        # so the maps are those of one pass).
        if pool is None:
            from mfmap.mapping.workers import worker_pool

            pool = stack.enter_context(worker_pool(len(groups), warm=False))
        futures = [pool.submit(_maps_worker, job.for_floors(g)) for g in groups]
        maps = futures[0].result()
        bar.advance(maps.scans)
        for future in futures[1:]:
            part = future.result()
            bar.advance(part.scans)
            maps.merge(part)
    return trajectory, maps


def add_depth_cameras(src: LogSource, cameras: list[Camera], seg: FloorSegmentation,
                      trajectory: FloorTrajectory, maps: MapAccumulator, cfg: MfmapConfig,
                      colour: Sequence[ColourCamera] = ()) -> dict[str, int]:
    """The depth cameras' images into the floor maps (images used per depth topic), then the
    colour cameras' paint on the clouds, left out where the lidar scans are: rides, stair walks
    and elevator cabins."""
    if not cameras and not colour:
        return {}
    from mfmap.export.camera import add_cameras

    margin = int(cfg.export.transition_margin_s * 1e9)
    spans = [(tr.start_ns - margin, tr.end_ns + margin) for tr in seg.transitions]
    shafts = distinct_cabins(cabin_boxes(seg.transitions, trajectory.stamps_ns, trajectory.poses,
                                          cfg.mapping))

    def usable(stamp_ns: int, pose: F64) -> bool:
        return (seg.floor_at(stamp_ns) >= 0 and not _near_transition(stamp_ns, spans)
                and not in_cabin(pose, stamp_ns, shafts))

    def outside(points_base: np.ndarray, pose: F64, stamp_ns: int) -> np.ndarray:
        # A camera by an open landing door sees the cabin (and the shaft) as the lidar does.
        if not shafts or points_base.shape[0] == 0:
            return np.ones(points_base.shape[0], dtype=bool)
        return outside_cabins(points_base, pose, stamp_ns, shafts)

    used = add_cameras(src, cameras, trajectory, maps, cfg.camera, cfg.export.grid.band_m, usable,
                       outside)
    from mfmap.export.lidar_colour import paint_clouds

    paint_clouds(src, list(colour), trajectory, maps, cfg.camera, usable)
    return used


@dataclass(frozen=True)
class _MapsJob:
    """What the second pass over the log needs (sent to a worker process for a floor group)."""

    path: Path  # the log, re-opened by a worker
    cfg: MfmapConfig
    planar: bool
    trajectory: FloorTrajectory
    used: dict[int, int]  # stamp -> trajectory index of the scans to use
    shafts: list[CabinBox]
    extrinsics: Extrinsics
    floor_z_m: dict[int, float]

    def for_floors(self, floors: set[int]) -> _MapsJob:
        floor = self.trajectory.floor
        used = {s: i for s, i in self.used.items() if int(floor[i]) in floors}
        return _MapsJob(self.path, self.cfg, self.planar, self.trajectory, used, self.shafts,
                        self.extrinsics, self.floor_z_m)


def _accumulate_scans(src: LogSource, job: _MapsJob, bar: StageProgress) -> MapAccumulator:
    """Deskew, clean and add the planned scans to a fresh accumulator."""
    from mfmap.export.mapdata import MapAccumulator

    maps = MapAccumulator(job.cfg.export, job.floor_z_m)
    trajectory, todo, deskew = job.trajectory, dict(job.used), job.cfg.export.deskew
    for stamp_ns, frame_id, xyz, t_offset_ns in _scans_of(src, job.planar, trajectory, job.used):
        i = todo.pop(stamp_ns, None)
        if i is None:
            continue  # a scan the plan leaves out (or a second copy of one)
        bar.advance()
        pose = trajectory.poses[i]
        to_base = job.extrinsics.get(frame_id)
        pts = xyz.astype(np.float64)
        if to_base is not None:
            pts = pts @ to_base[:3, :3].T + to_base[:3, 3]
        if deskew and t_offset_ns is not None and len(t_offset_ns) == len(pts):
            pts = _deskew(pts, t_offset_ns, trajectory, i)
        pts = drop_cabins(pts, pose, stamp_ns, job.shafts)
        maps.add(int(trajectory.floor[i]), pose, pts)
    return maps


def _maps_worker(job: _MapsJob) -> MapAccumulator:
    from mfmap.ingest import open_log

    with open_log(job.path, job.cfg.ingest) as src, NullProgress().stage("maps") as bar:
        return _accumulate_scans(src, job, bar)


def _floor_groups(used: dict[int, int], trajectory: FloorTrajectory, workers: int) -> list[set[int]]:
    """Floors in at most `workers` groups of about equal scan counts (largest first, greedy)."""
    counts: dict[int, int] = {}
    for i in used.values():
        counts[int(trajectory.floor[i])] = counts.get(int(trajectory.floor[i]), 0) + 1
    groups: list[tuple[int, set[int]]] = [(0, set()) for _ in range(min(workers, len(counts)))]
    for floor_id, n in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])):
        k = min(range(len(groups)), key=lambda j: (groups[j][0], j))
        groups[k] = (groups[k][0] + n, groups[k][1] | {floor_id})
    return [g for _, g in sorted(groups, key=lambda ng: (-ng[0], min(ng[1], default=0))) if g]


def _used_scans(seg: FloorSegmentation, trajectory: FloorTrajectory, cabins: list[CabinBox],
                cfg: MfmapConfig) -> dict[int, int]:
    """Stamp -> trajectory index of the scans the maps use, decided from the poses alone.

    Left out: scans in (or at the ends of) a ride or stair walk, scans before the robot moved
    or turned enough since the last one used on its floor (standing still adds nothing), and
    scans from inside an elevator cabin (its walls, and mirror ghosts behind them). Deciding
    before reading lets the second pass decode only the scans it uses.
    """
    margin = int(cfg.export.transition_margin_s * 1e9)
    rides = [(tr.start_ns - margin, tr.end_ns + margin) for tr in seg.transitions]
    last_used: dict[int, F64] = {}
    used: dict[int, int] = {}
    for i, stamp in enumerate(trajectory.stamps_ns.tolist()):
        if stamp in used or seg.floor_at(stamp) < 0 or _near_transition(stamp, rides):
            continue
        pose = trajectory.poses[i]
        floor_id = int(trajectory.floor[i])
        if not _moved(last_used.get(floor_id), pose, cfg) or in_cabin(pose, stamp, cabins):
            continue
        used[stamp] = i
        last_used[floor_id] = pose
    return used


def _scans_of(src: LogSource, planar: bool, trajectory: FloorTrajectory, used: dict[int, int],
              max_skip: int = 20) -> Iterator[tuple[int, str, np.ndarray, np.ndarray | None]]:
    """The log's scans in windows around the used ones (runs of skipped scans are not decoded)."""
    idx = sorted(used.values())
    stamps = trajectory.stamps_ns
    start = 0
    for k in range(1, len(idx) + 1):
        if k == len(idx) or idx[k] - idx[k - 1] > max_skip:
            yield from read_scans(src, planar, int(stamps[idx[start]]), int(stamps[idx[k - 1]]))
            start = k


def _moved(last: F64 | None, pose: F64, cfg: MfmapConfig) -> bool:
    if last is None:
        return True
    delta = inverse(last) @ pose
    turn_deg = math.degrees(rotation_angle_rad(delta))
    return bool(
        np.linalg.norm(delta[:3, 3]) >= cfg.export.scan_min_motion_m
        or turn_deg >= cfg.export.scan_min_turn_deg
    )


def _near_transition(stamp_ns: int, spans: list[tuple[int, int]]) -> bool:
    return any(lo <= stamp_ns <= hi for lo, hi in spans)


def _deskew(points_base: F64, t_offset_ns: np.ndarray, trajectory: FloorTrajectory, i: int,
            max_gap_ns: int = 250_000_000) -> F64:
    """Points measured at stamp + t_offset, expressed in the base frame at the scan's stamp.

    A spinning lidar fires each column at its own time, while the scan's pose is the base at the
    stamp (mapping deskews at mid-sweep and moves the pose back to the stamp). The motion over
    the sweep comes from the optimised trajectory: the relative pose to the next scan (or from
    the previous one, at a gap), interpolated per point with a slerp of the rotation (Rodrigues,
    vectorised) and a linear translation.
    """
    stamps, poses, floor = trajectory.stamps_ns, trajectory.poses, trajectory.floor
    n = stamps.shape[0]
    if n < 2 or points_base.shape[0] == 0 or not np.any(t_offset_ns):
        return points_base
    if i + 1 < n and stamps[i + 1] - stamps[i] <= max_gap_ns and floor[i + 1] == floor[i]:
        a, b = i, i + 1
    elif i > 0 and stamps[i] - stamps[i - 1] <= max_gap_ns and floor[i - 1] == floor[i]:
        a, b = i - 1, i
    else:
        return points_base  # an isolated scan: no motion to interpolate
    # The motion to the next scan (or from the previous one, at a gap) as a constant twist.
    span_s = (stamps[b] - stamps[a]) / 1e9
    angular, linear = twist(inverse(poses[a]) @ poses[b], span_s)
    return deskew(points_base, t_offset_ns.astype(np.float64) / 1e9, angular, linear)


__all__ = ["accumulate", "add_depth_cameras"]
