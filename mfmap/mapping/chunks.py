"""Parallel mapping: the runs of visits between elevator rides, each in its own process.

After an elevator ride the odometry restarts: the local map is cleared and the new visit starts
at the held pose, levelled by gravity, at the floor's elevation. That start is a rigid motion
(yaw and x, y) of the start computed from an identity held pose, and nothing else of the mapper
carries over but counters. So each run of visits between rides ("chunk") is mapped in its own
process from an identity held pose; the merge then chains the chunks in time order (each
chunk's held pose at its end places the next one), renumbers keyframes and runs the loop search
over all keyframes in their order, exactly as the sequential pass would. Each chunk starts with
a fresh adaptive threshold and scan stride phase, so the result differs slightly from one
process, but not between runs: chunks are merged in a fixed order.

Off a stair walk the local map is cleared too, and the visit starts from the pose reached on
the stairs, levelled by gravity (`Mapper._start_visit`): a yaw and x, y of the start computed
from any other pose, as after a ride. So with `split_at_stairs` a chunk also starts at each
stair walk's end (off by default: see the README's Limitations on what it moves): it primes its
motion state on the walk's last scans (`STAIRS_PRIME_NS`), so the visit's first scan is
predicted, deskewed and levelled as in one pass, and the chunk before it maps on to that same
scan, its first keyframe of the new visit carrying the walk's edge. The merge places the new
chunk so its first keyframe lands on that one's pose, keeps the later chunk's keyframe and hands
it the walk's edge. What differs from one pass is what after a ride differs (the threshold, the
stride phase) and the wheels' scale, calibrated afresh.

A worker cannot be handed the open log: each job carries a `LogOpener` that opens it again.
"""

from __future__ import annotations

import contextlib
from concurrent.futures import Executor
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from mfmap.mapping.config import MappingConfig
from mfmap.mapping.geometry import inverse, yaw_pose, yaw_rad
from mfmap.mapping.loops import LoopCloser
from mfmap.mapping.mapper import Mapper
from mfmap.mapping.mapstats import MAX_COUNTERS, loop_counters, stats
from mfmap.mapping.motion import MotionModel
from mfmap.mapping.source import LogOpener, LogSourceLike, read_scans
from mfmap.mapping.timeline import Timeline
from mfmap.mapping.workers import worker_pool
from mfmap.types import (
    F64,
    Extrinsics,
    FloorSegmentation,
    ImuSeries,
    Keyframe,
    MappingResult,
    OdomSeries,
    PoseEdge,
    ScanPose,
    Transition,
    TransitionKind,
)

# The stairs chunk's motion is primed on the walk's scans of this last stretch.
STAIRS_PRIME_NS = 500_000_000


@dataclass(frozen=True)
class Chunk:
    first_visit: int
    start_ns: int | None  # None: from the log's start
    end_ns: int | None  # inclusive; None: to the log's end
    after_stairs: bool = False  # starts at a stair walk's end (primed on the walk's last scans)
    # Maps on to the first scan of this visit (the next chunk's, after a stair walk), then stops.
    stop_in_visit: int | None = None


def plan_chunks(timeline: Timeline, stairs: bool = False) -> list[Chunk]:
    """Runs of visits whose odometry restarts after an elevator ride (see
    `Mapper._start_visit`) and, with `stairs`, after a stair walk."""
    starts: list[tuple[int, Transition | None]] = [(0, None)]
    for v in range(1, len(timeline.visits)):
        previous_start, start = timeline.visits[v - 1][1], timeline.visits[v][1]
        between = [tr for tr in timeline.transitions if previous_start <= tr.start_ns < start]
        if any(tr.kind == TransitionKind.ELEVATOR for tr in between):
            starts.append((v, None))
        elif stairs and between and between[-1].kind == TransitionKind.STAIRS:
            starts.append((v, between[-1]))
    # A ride ends where the next visit starts, and a scan stamped exactly there is still the
    # ride's (`Timeline.at`): it stays in the chunk the ride hangs off. Started with the next
    # chunk, it was posed from that chunk's held pose as if the whole ride lay ahead of it, 7.4 m
    # below the floor on three-floor-revisit seed 1's 8 m ride down, and the trajectory's export
    # then scaled the ride's height profile to that scan (the ride came out half as deep).
    out = []
    for k, (v, walk) in enumerate(starts):
        start_ns: int | None = None
        if k > 0:
            start_ns = timeline.visits[v][1] + 1
            if walk is not None:
                start_ns = max(walk.end_ns - STAIRS_PRIME_NS, walk.start_ns)
        end_ns: int | None = None
        stop: int | None = None
        if k + 1 < len(starts):
            following, following_walk = starts[k + 1]
            end_ns = timeline.visits[following][1]
            if following_walk is not None:
                # On to the next visit's first scan (read up to a few seconds into it).
                stop, end_ns = following, end_ns + 5_000_000_000
        out.append(Chunk(v, start_ns, end_ns, walk is not None, stop))
    return out


@dataclass(frozen=True)
class ChunkJob:
    reopen: LogOpener  # the log, opened again by the worker
    seg: FloorSegmentation
    cfg: MappingConfig
    extrinsics: Extrinsics
    odom: OdomSeries | None
    imu: ImuSeries | None
    planar: bool
    chunk: Chunk


@dataclass(frozen=True)
class ChunkResult:
    keyframes: list[Keyframe]  # poses in the chunk's frame, ids from 0
    edges: list[PoseEdge]  # odometry only
    scan_poses: list[ScanPose]
    pending: list[tuple[int, F64]]  # scans left without a keyframe of their visit
    first_visit: int
    held: F64  # the pose at the chunk's end, held through the following ride
    scans: int
    counters: dict[str, float]
    warnings: list[str]
    held_ns: int | None = None  # the reference time of `held`
    # After a stair walk: the visit's first scan's stamp, and its pose and reference time.
    first_scan_ns: int | None = None
    anchor: F64 | None = None
    anchor_ns: int | None = None


def map_chunk(job: ChunkJob) -> ChunkResult:
    """Worker: map one chunk's scans from an identity held pose."""
    motion = MotionModel(job.cfg.motion.prior, job.odom, job.imu, job.extrinsics)
    mapper = Mapper(job.cfg, job.seg, job.extrinsics, motion, job.planar)
    chunk = job.chunk
    if chunk.first_visit > 0:
        mapper.state.visit = chunk.first_visit - 1  # so its first scan restarts after the ride (walk)
    scans = 0
    first_scan_ns: int | None = None
    anchor: F64 | None = None
    anchor_ns: int | None = None
    with job.reopen() as src:
        for stamp_ns, frame_id, xyz, t_offset_ns in read_scans(src, job.planar, chunk.start_ns,
                                                               chunk.end_ns):
            mapper.add_scan(stamp_ns, frame_id, xyz, t_offset_ns)
            visit = mapper.state.visit
            if chunk.after_stairs and first_scan_ns is None and visit >= chunk.first_visit:
                first_scan_ns, anchor, anchor_ns = stamp_ns, mapper.state.pose.copy(), mapper.state.stamp_ns
            if chunk.stop_in_visit is not None and visit >= chunk.stop_in_visit:
                break  # the next chunk's first scan: counted there
            scans += visit >= chunk.first_visit or not chunk.after_stairs  # not the priming scans
        # What this process's reading dropped (scans with broken stamps) is the build's to say.
        warnings = mapper.warnings
        warnings += [w for w in src.stream_warnings() if w not in warnings]
    mapper.finish_run()
    book = mapper.book
    return ChunkResult(book.keyframes, book.edges, book.scan_poses, book.pending,
                       chunk.first_visit, mapper.state.pose, scans, mapper.counters(),
                       warnings, mapper.state.stamp_ns, first_scan_ns, anchor, anchor_ns)


def map_parallel(source: LogSourceLike, seg: FloorSegmentation, cfg: MappingConfig,
                 extrinsics: Extrinsics, planar: bool, chunks: list[Chunk], reopen: LogOpener,
                 bar: Any, pool: Executor | None) -> MappingResult:
    """Map the chunks in `pool` (or a pool of their own) and merge them."""
    odom, imu = source.odometry(), source.imu()
    jobs = [ChunkJob(reopen, seg, cfg, extrinsics, odom, imu, planar, chunk) for chunk in chunks]
    parts: list[ChunkResult] = []
    with contextlib.ExitStack() as stack:
        if pool is None:
            pool = stack.enter_context(worker_pool(min(cfg.workers, len(chunks)), warm=False))
        for part in pool.map(map_chunk, jobs):
            parts.append(part)
            bar.advance(part.scans)
    return merge(parts, cfg, seg, planar)


class _Merge:
    """The chunks chained in time order into the first one's frame (see `merge`)."""

    def __init__(self, seg: FloorSegmentation) -> None:
        self.timeline = Timeline(seg)
        self.elevation = {f.id: f.elevation_m for f in seg.floors}
        self.keyframes: list[Keyframe] = []
        self.chunk_edges: dict[int, list[PoseEdge]] = {}  # odometry and loops within a chunk, by j
        self.chunk_of_visit: dict[int, int] = {}
        self.scan_poses: list[ScanPose] = []
        self.counters: dict[str, float] = {}
        self.warnings: list[str] = []
        self.held = np.eye(4)
        self.held_ns: int | None = None
        # Edges onto the next chunk's first keyframe, and the end pose they were made to.
        self.walk: list[tuple[PoseEdge, F64]] = []

    def _frame(self, part: ChunkResult) -> F64:
        """Where the chunk's frame lies in the first chunk's."""
        held = self.held
        frame = np.eye(4)
        if part.anchor is not None:
            # Off a stair walk: the chunk's first scan of its visit is the chunk before's last.
            if self.held_ns != part.anchor_ns:
                self.warnings.append("a stair walk's two chunks did not end and start at one scan")
            frame = held @ inverse(part.anchor)
        elif part.first_visit > 0:
            # `Mapper._start_visit` levels the held pose by gravity keeping its yaw, and sets z
            # to the floor's elevation: from the held pose that is the chunk's start (made from
            # an identity held pose) turned by the held yaw and moved by its x, y.
            known = self.timeline.visits[part.first_visit][0] in self.elevation
            frame = yaw_pose(yaw_rad(held), np.array([held[0, 3], held[1, 3],
                                                      0.0 if known else held[2, 3]]))
        return frame

    def add(self, index: int, part: ChunkResult, end: Keyframe | None,
            walk_edges: list[PoseEdge]) -> None:
        if part.scans == 0:
            self.walk = []
            return  # nothing mapped: the held pose carries on to the next chunk
        frame = self._frame(part)
        keyframes, chunk_edges = self.keyframes, self.chunk_edges
        offset = len(keyframes)
        for kf in part.keyframes:
            keyframes.append(replace(kf, id=kf.id + offset, pose=frame @ kf.pose))
            self.chunk_of_visit[kf.visit] = index
        if part.anchor is not None and part.keyframes:
            # The walk's edge, made by the chunk before onto its own first keyframe of this
            # visit, which lands on this chunk's first (the same scan, the same pose).
            first = keyframes[offset]
            for e, end_pose in self.walk:
                chunk_edges.setdefault(first.id, []).append(
                    replace(e, j=first.id, measured=e.measured @ inverse(end_pose) @ first.pose))
        self.walk = [] if end is None else [(replace(e, i=e.i + offset), frame @ end.pose)
                                            for e in walk_edges]
        for e in part.edges:
            chunk_edges.setdefault(e.j + offset, []).append(replace(e, i=e.i + offset, j=e.j + offset))
        self.scan_poses.extend(replace(sp, keyframe=sp.keyframe + offset) for sp in part.scan_poses)
        if part.pending and keyframes:
            # Scans of a visit that ended before its first keyframe hang on the last keyframe
            # (the chunk's own, or the one before it when the chunk has none).
            last = keyframes[-1]
            self.scan_poses.extend(ScanPose(ns, last.id, inverse(last.pose) @ frame @ pose)
                                   for ns, pose in part.pending)
        self.held, self.held_ns = frame @ part.held, part.held_ns
        for name, value in part.counters.items():
            combine = max if name in MAX_COUNTERS else (lambda a, b: a + b)
            self.counters[name] = combine(self.counters.get(name, 0.0), value)
        self.warnings += [w for w in part.warnings if w not in self.warnings]


def merge(parts: list[ChunkResult], cfg: MappingConfig, seg: FloorSegmentation,
          planar: bool) -> MappingResult:
    """Chain the chunks into one frame, renumber keyframes, search loops across chunks.

    Each worker searched the loops within its chunk; what is left are the revisits of a floor
    from another chunk, searched here in keyframe order against the other chunks' keyframes.
    """
    chained = _Merge(seg)
    for index, part in enumerate(parts):
        part, end, walk_edges = meet_at_stairs(part, parts[index + 1] if index + 1 < len(parts)
                                               else None)
        chained.add(index, part, end, walk_edges)
    keyframes, scan_poses, counters = chained.keyframes, chained.scan_poses, chained.counters
    scan_poses.sort(key=lambda sp: sp.stamp_ns)
    loops = LoopCloser(cfg, group_of=lambda kf: chained.chunk_of_visit[kf.visit], planar=planar)
    edges: list[PoseEdge] = []
    for kf in keyframes:
        edges += chained.chunk_edges.get(kf.id, [])
        edges += loops.add(kf)
    for name, value in loop_counters(loops).items():
        counters[name] = counters.get(name, 0.0) + value
    warnings = chained.warnings
    if not keyframes:
        warnings.append("no keyframe could be made: no usable lidar scans")
    failures = counters.get("registration_failures", 0.0)
    figures = stats(counters, len(scan_poses), keyframes, edges)
    figures["chunks"] = float(len(parts))
    warnings = [w for w in warnings if "scans could not be registered" not in w]
    if failures:
        warnings.append(f"{int(failures)} scans could not be registered (motion prior used)")
    return MappingResult(keyframes, edges, scan_poses, warnings, figures)


def meet_at_stairs(part: ChunkResult, following: ChunkResult | None
                   ) -> tuple[ChunkResult, Keyframe | None, list[PoseEdge]]:
    """Where chunks meet at a stair walk's end, each scan is kept once.

    A chunk that starts there drops its priming scans (the walk's, posed by the chunk before).
    A chunk that ends there drops the next visit's first scan and its keyframe, returned with
    the odometry edges onto it (the walk's edge) for the merge to hand to the next chunk's
    first keyframe; its loop edges go (the merge searches them again across chunks).
    """
    if part.first_scan_ns is not None:
        part = replace(part, scan_poses=[sp for sp in part.scan_poses
                                         if sp.stamp_ns >= part.first_scan_ns],
                       pending=[(ns, pose) for ns, pose in part.pending
                                if ns >= part.first_scan_ns])
    if following is None or following.first_scan_ns is None:
        return part, None, []
    cut = following.first_scan_ns
    end = part.keyframes[-1] if part.keyframes else None
    if end is None or end.visit < following.first_visit:
        end = None
    keyframes = part.keyframes if end is None else part.keyframes[:-1]
    kept, pending = [], [(ns, pose) for ns, pose in part.pending if ns < cut]
    for sp in part.scan_poses:
        if sp.stamp_ns >= cut:
            continue
        if end is not None and sp.keyframe == end.id:
            pending.append((sp.stamp_ns, end.pose @ sp.relative))  # hung on the last one kept
        else:
            kept.append(sp)
    onto = [] if end is None else [e for e in part.edges if e.j == end.id and e.kind == "odometry"]
    edges = part.edges if end is None else [e for e in part.edges
                                            if end.id not in (e.i, e.j)]
    return (replace(part, keyframes=keyframes, edges=edges, scan_poses=kept, pending=pending),
            end, onto)
