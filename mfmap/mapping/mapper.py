"""One pass of lidar odometry over a log's scans (or a chunk's), floor visit by floor visit.

Per scan: sensor -> base frame, range filter, deskew, cabin filter, scan-to-local-map ICP from the
motion prior (`scanstep`), keyframe decision, loop search on the same floor. Elevator rides hold
x, y, yaw (scans not registered); stairs keep the odometry running with z free, and the floor
reached starts a new, levelled local map.
"""

from __future__ import annotations

import numpy as np

from mfmap.mapping.cabin import CabinFilter
from mfmap.mapping.climb import ClimbFollower, needs_keyframe
from mfmap.mapping.config import MappingConfig
from mfmap.mapping.geometry import inverse
from mfmap.mapping.loops import LoopCloser
from mfmap.mapping.mapstats import ScanCounts, mapper_counters, stats
from mfmap.mapping.motion import MotionModel, TrackState
from mfmap.mapping.odometry import AdaptiveThreshold, LocalMap, ScanMatcher
from mfmap.mapping.posebook import PoseBook, odometry_information, odometry_sigma_m
from mfmap.mapping.registration import downsample
from mfmap.mapping.scan2d import Scan2DMatcher
from mfmap.mapping.scanstep import ScanStep
from mfmap.mapping.timeline import Segment, SegmentKind, Timeline
from mfmap.mapping.transitions import Transitions, walk_heading, walk_path_m
from mfmap.mapping.wheelscale import Run, RunScale
from mfmap.types import (
    F32,
    F64,
    I64,
    EdgeKind,
    Extrinsics,
    FloorSegmentation,
    Keyframe,
    MappingResult,
    PoseEdge,
    TransitionKind,
)

# The height sigma of a 2D lidar's edge across a stair walk (m): it measures no climb.
FREE_Z_SIGMA_M = 1000.0


class Mapper:
    """Tracks the robot scan by scan, hands out keyframes and their edges (`book`)."""

    def __init__(self, cfg: MappingConfig, seg: FloorSegmentation, extrinsics: Extrinsics,
                 motion: MotionModel, planar: bool) -> None:
        self.cfg = cfg
        self.motion = motion
        self.planar = planar
        self.timeline = Timeline(seg)
        self.elevation = {f.id: f.elevation_m for f in seg.floors}
        threshold = AdaptiveThreshold.from_config(cfg)
        self.matcher: ScanMatcher | Scan2DMatcher
        if planar:
            self.matcher = Scan2DMatcher.from_config(cfg, threshold)
        else:
            self.matcher = ScanMatcher.from_config(cfg, LocalMap.from_config(cfg), threshold)
        self.cabin = CabinFilter(cfg, self.timeline.transitions, motion) if cfg.cabin.filter else None
        self.transitions = Transitions(seg, self.timeline)
        self.loops = LoopCloser(cfg, planar=planar)
        self.state = TrackState()
        self.book = PoseBook()
        self._opening: list[str] = []  # the warnings known before the first scan
        self.counts = ScanCounts()
        self.step = ScanStep(cfg, extrinsics, motion, planar, self.matcher, self.cabin, self.counts)
        # The wheels' scale since the last elevator ride, and that run (see `finish_run`).
        self.wheels = RunScale(cfg.motion.odom_scale_min_m)
        # A stair walk's climb registered again, the median taken (`climb`).
        self.climb = ClimbFollower(cfg, planar)
        if motion.source != "odometry" and cfg.cabin.filter and any(
            tr.kind == TransitionKind.ELEVATOR for tr in self.timeline.transitions
        ):
            self._opening.append(
                "no wheel odometry: cabin returns are only filtered when leaving an elevator")

    @property
    def warnings(self) -> list[str]:
        """The warnings so far, in the order things happened."""
        return [*self._opening, *self.step.warnings]

    def add_scan(self, stamp_ns: int, frame_id: str, xyz: F32, t_offset_ns: I64 | None) -> None:
        segment = self.timeline.at(stamp_ns)
        state = self.state
        if segment.kind == SegmentKind.RIDE:
            self.climb.drop()
            self._ride_scan(stamp_ns, segment)
            return
        if segment.kind == SegmentKind.VISIT and segment.visit != state.visit:
            self._start_visit(segment, stamp_ns)
        state.scan_index += 1
        has_times = t_offset_ns is not None and len(t_offset_ns) == len(xyz) and len(xyz) > 0
        stride = self.cfg.scan_stride_2d if self.planar else self.cfg.scan_stride
        on_stairs = self.transitions.on_stairs_at(stamp_ns)
        self.climb.follow(on_stairs, self.step, state, stamp_ns, frame_id, xyz, t_offset_ns,
                          has_times)
        if on_stairs:
            # On stairs every scan: the motion prior (planar wheel odometry) does not climb, and
            # a scan posed by it would start the next registration a step too low (with every
            # third scan the climb came out 7 % short; with every scan within 1-3 cm).
            stride = 1
        # Never the first scan of a fresh map (a visit's): it starts the map, and the chunk
        # mapped from a stair walk's end must start it as one pass does (`chunks.chunks`).
        held = (state.scan_index % stride == 0 and state.map_pose is not None
                and self.step.still.standing_still(stamp_ns))
        self.counts.held_scans += held
        if state.stamp_ns is not None and (state.scan_index % stride != 0 or held):
            delta = self.step.predict(state, stamp_ns)
            dt = (stamp_ns - state.stamp_ns) / 1e9
            predicted = state.pose @ delta
            self._record(stamp_ns, predicted, stamp_ns, predicted, delta, dt)
            return
        step = self.step.register(state, stamp_ns, frame_id, xyz, t_offset_ns, has_times,
                                  on_stairs)
        if step.points is None or step.match is None:  # inside the cabin, or tipping
            self._record(stamp_ns, step.scan_pose(), step.ref_ns, step.pose, step.delta, step.dt)
            return
        if self._needs_keyframe(step.pose):
            assert step.sensor is not None
            self._keyframe(step.ref_ns, step.points, step.sensor, step.pose, step.match.fitness,
                           step.match.rmse_m, emit=segment.kind == SegmentKind.VISIT)
        self._record(stamp_ns, step.scan_pose(), step.ref_ns, step.pose,
                     inverse(state.pose) @ step.pose if state.stamp_ns is not None else step.delta,
                     step.dt)

    def _record(self, stamp_ns: int, scan_pose: F64, ref_ns: int, ref_pose: F64, delta: F64,
                dt: float) -> None:
        """Keep the tracking state (at the reference time) and the scan's pose (at its stamp)."""
        state = self.state
        if dt > 0:
            state.delta, state.delta_dt_s = delta, dt
        state.pose, state.stamp_ns = ref_pose, ref_ns
        if state.keyframe is None or state.keyframe.visit != state.visit:
            # Held until the visit's first keyframe, so the scan moves with that visit's graph.
            self.book.pending.append((stamp_ns, scan_pose))
        else:
            self.book.hang(state.keyframe, stamp_ns, scan_pose)

    def _needs_keyframe(self, pose: F64) -> bool:
        return needs_keyframe(self.cfg, self.state.map_pose, self.matcher.map.size, pose)

    def _keyframe(self, stamp_ns: int, points: F64, sensor: F64, pose: F64, fitness: float,
                  rmse_m: float, emit: bool) -> None:
        """Update the local map (`sensor`: the lidar in the base frame); during a visit also
        hand out a keyframe (not on stairs)."""
        state = self.state
        self.matcher.add_keyframe(points, pose, sensor)
        self.counts.max_map_points = max(self.counts.max_map_points, self.matcher.map.size)
        state.map_pose = pose
        if not emit:
            return
        kf = Keyframe(
            id=len(self.book.keyframes),
            stamp_ns=stamp_ns,
            floor_id=self.timeline.visits[state.visit][0],
            visit=state.visit,
            pose=pose.copy(),
            cloud=downsample(points, self.cfg.keyframes.voxel_size_m).astype(np.float32),
            fitness=fitness,
            rmse_m=rmse_m,
        )
        previous = state.keyframe
        if previous is not None and (previous.visit == kf.visit or state.link_previous):
            self._odometry_edge(previous, kf, fitness)
        self.book.keyframes.append(kf)
        state.keyframe = kf
        self.book.hang_pending(kf)
        self.book.edges.extend(self.loops.add(kf))

    def _odometry_edge(self, previous: Keyframe, kf: Keyframe, fitness: float) -> None:
        """The edge from the previous keyframe; within a visit it also calibrates the wheels."""
        measured = inverse(previous.pose) @ kf.pose
        information = odometry_information(self.cfg, measured)
        if previous.visit != kf.visit:  # across a stair walk
            # A 2D lidar's odometry does not climb: its z across the walk measures nothing.
            information[5, 5] = (FREE_Z_SIGMA_M**-2 if self.planar
                                 else min(information[5, 5], self.cfg.stairs.sigma_z_m**-2))
            # x, y drift with the way walked, not the way from end to end: weighed by the
            # straight line, a switch-back walk's 17 cm of drift over 20 m of flights held
            # the floors 7 cm apart against their inter-floor registration.
            sigma_xy = odometry_sigma_m(self.cfg, walk_path_m(previous, kf, self.book.scan_poses))
            information[3, 3] = min(information[3, 3], sigma_xy**-2)
            information[4, 4] = min(information[4, 4], sigma_xy**-2)
            measured = walk_heading(self.cfg, self.motion.gyro, previous, kf, measured,
                                    self.book.scan_poses)
        self.book.edges.append(PoseEdge(previous.id, kf.id, measured, information, EdgeKind.ODOMETRY,
                                        fitness))
        if previous.visit == kf.visit and not self.transitions.on_stairs(previous.stamp_ns,
                                                                         kf.stamp_ns):
            wheels = self.motion.wheels(previous.stamp_ns, kf.stamp_ns)
            if wheels is not None:
                self.wheels.current.add(measured, wheels)
                self.motion.odom_scale = self.wheels.current.value or 1.0

    def _start_visit(self, segment: Segment, stamp_ns: int) -> None:
        """A new floor visit: after a ride the map restarts at the held pose, z from the floor."""
        state = self.state
        previous_start = self.timeline.visits[state.visit][1] if state.visit >= 0 else None
        state.visit = segment.visit
        state.map_pose = None  # the first scan of a visit is always a keyframe
        self.step.still.clear()
        if previous_start is None:
            return
        rides = self.transitions.rides(previous_start, stamp_ns)
        state.link_previous = not rides
        if rides:
            self._after_ride(segment, stamp_ns, rides[-1].start_ns, rides[-1].end_ns)
        elif self.transitions.walked(previous_start, stamp_ns):
            # Off the stairs: the local map holds the floor below and the steps, seen from poses
            # whose pitch and height drifted on the climb; registering the new floor against it
            # tilts and turns the start of the visit, and nothing on the floor corrects that
            # later. The odometry continues from the pose reached on the stairs, levelled by
            # gravity (the climb leaves tenths of a degree of tilt, and a tilted new map makes
            # the flat floor climb: on `long` this halves the visit's drift before loops).
            self.climb.end(state, self.book)
            self.matcher.map.clear()
            if not self.planar and self.cfg.stairs.level_window_s > 0:
                state.pose = self.motion.level(state.pose, stamp_ns,
                                               stamp_ns + int(self.cfg.stairs.level_window_s * 1e9))
        # else: a gap: the odometry and its local map simply continue.

    def _after_ride(self, segment: Segment, stamp_ns: int, ride_start_ns: int,
                    ride_end_ns: int) -> None:
        """The odometry restarts at the pose held through the ride, levelled, z from the floor."""
        state = self.state
        self.finish_run()
        # The pose before the ride is still state.pose (ride scans do not move it).
        pose = state.pose if self.planar else self.motion.level(
            state.pose, ride_start_ns, ride_end_ns)
        pose = pose.copy()
        pose[2, 3] = self.elevation.get(segment.floor_id, pose[2, 3])
        state.pose = pose
        state.stamp_ns = stamp_ns
        state.delta = np.eye(4)
        self.matcher.map.clear()
        if self.cabin is not None:
            self.cabin.visit_started(pose)
        # The motion prior alone carries the robot out of the cabin: its scale is calibrated
        # again on this run's keyframes, and the way out rescaled by `finish_run`.
        self.wheels.run = Run(pose.copy(), len(self.book.keyframes), len(self.book.scan_poses))

    def _ride_scan(self, stamp_ns: int, segment: Segment) -> None:
        """Inside the elevator: x, y, yaw held; z follows the filtered barometric height."""
        state = self.state
        tr = segment.transition
        assert tr is not None
        pose = state.pose.copy()  # the pose before the ride, not updated during it
        pose[2, 3] += self.transitions.height(stamp_ns) - self.transitions.height(tr.start_ns)
        if state.keyframe is None:
            self.book.pending.append((stamp_ns, pose))
        else:
            self.book.hang(state.keyframe, stamp_ns, pose)

    def finish_run(self) -> None:
        """End of a run of visits between elevator rides: rescale the way out of the cabin.

        From the held pose to the run's first keyframe (the first scan outside the cabin) the
        wheels alone moved the robot, before this run had calibrated their scale. With the scale
        known now, the first keyframe moves to where the calibrated wheels put it; the rest of
        the run, registered against it, moves rigidly with it; and the scans in the cabin are
        rescaled along the way out.
        """
        scale, run = self.wheels.finish()
        self.motion.odom_scale = 1.0
        if scale is None or run is None:
            return
        rigid = self.book.rescale_run(run, scale)
        if rigid is None:
            return
        state = self.state
        state.pose = rigid @ state.pose
        if state.map_pose is not None:
            state.map_pose = rigid @ state.map_pose
        self.book.pending = [(ns, rigid @ pose) for ns, pose in self.book.pending]

    def counters(self) -> dict[str, float]:
        return mapper_counters(self.matcher, self.cabin, self.loops, self.counts, self.wheels,
                               self.climb.climbs)

    def result(self) -> MappingResult:
        self.finish_run()
        book = self.book
        warnings = self.warnings
        if book.pending and not book.keyframes:
            warnings.append("no keyframe could be made: no usable lidar scans")
        elif book.pending:
            book.hang_pending_on_last()
        figures = stats(self.counters(), len(book.scan_poses), book.keyframes, book.edges)
        if self.matcher.failures:
            warnings.append(f"{self.matcher.failures} scans could not be registered (motion prior used)")
        return MappingResult(book.keyframes, book.edges, book.scan_poses, warnings, figures)
