"""A stair walk's climb registered more than once, from the same start; the median is taken.

A walk's climb is the sum of a few thousand registrations on the steps and landings, each
settling some tenths of a millimetre off, and which way is chaotic: on a generated stairwell
(gen-stairs seed 5) the same 8.51 m walk climbed 8.549 m on one CPU and 8.473 m on another, and
8.490-8.515 m with the scan's voxel or the local map's 4-7 % off, while the 3.55 m walk down
stayed within 1.4 cm. So besides the odometry, `extra` copies of its tracking (local map,
motion state, stand-still) follow the walk's scans from where it starts, each downsampling the
scans at another voxel; at the floor reached the odometry takes the members' median climb. Not
their mean: the registrations go wrong one at a time, and one that does is far off (traced on
gen-stairs seeds 3 and 5, one of three climbs 8 and 11 cm from the other two, which agreed
within 2 cm), so the mean carries a third of it and the median none. The copies' x, y and
heading are not taken: they come from the same steps and walls, and the inter-floor
registration holds them.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from mfmap.mapping.config import MappingConfig
from mfmap.mapping.geometry import inverse, rotation_angle_rad
from mfmap.mapping.motion import TrackState
from mfmap.mapping.odometry import ScanMatcher
from mfmap.mapping.posebook import PoseBook
from mfmap.mapping.scanstep import ScanStep
from mfmap.mapping.transitions import walk_scans
from mfmap.types import F32, F64, I64, Keyframe, ScanPose


def needs_keyframe(cfg: MappingConfig, last: F64 | None, map_size: int, pose: F64) -> bool:
    """Whether `pose` is far enough from the last local-map update `last` to update the map."""
    if last is None or map_size == 0:
        return True
    rel = inverse(last) @ pose
    return bool(np.linalg.norm(rel[:3, 3]) >= cfg.keyframes.distance_m
                or np.degrees(rotation_angle_rad(rel)) >= cfg.keyframes.angle_deg)


def member_voxel(voxel_m: float, spread: float, index: int) -> float:
    """The scan voxel of member `index` (1, 2, ...): alternately above and below the odometry's,
    `spread` of it further out every second member."""
    step = (index + 1) // 2
    return voxel_m * (1.0 + (spread * step if index % 2 else -spread * step))


@dataclass
class _Member:
    state: TrackState
    step: ScanStep
    matcher: ScanMatcher


def _fork(step: ScanStep, state: TrackState, voxel_m: float) -> _Member:
    """A copy of the odometry's tracking that shares nothing it changes: the local map's
    keyframes (its k-d tree target is replaced on every update, never changed), the adaptive
    threshold, the stand-still registrations, the counters."""
    assert isinstance(step.matcher, ScanMatcher)
    twin = step.matcher.fork(voxel_m)
    return _Member(replace(state), step.fork(twin), twin)


class ClimbEnsemble:
    """The walk's extra registrations, forked from the odometry at the walk's first scan."""

    def __init__(self, cfg: MappingConfig, step: ScanStep, state: TrackState) -> None:
        self.cfg = cfg
        voxel, spread = cfg.voxel_size_m, cfg.stairs.climb_voxel_spread
        self.members = [_fork(step, state, member_voxel(voxel, spread, i + 1))
                        for i in range(cfg.stairs.climb_registrations - 1)]
        self.start_z = float(state.pose[2, 3])
        self.start_ns = state.stamp_ns if state.stamp_ns is not None else 0

    def add_scan(self, stamp_ns: int, frame_id: str, xyz: F32, t_offset_ns: I64 | None,
                 has_times: bool) -> None:
        """Track the scan in every member, as the odometry does on stairs (every scan
        registered, the pose held while the robot stands still)."""
        for member in self.members:
            state, step = member.state, member.step
            if (state.stamp_ns is not None and state.map_pose is not None
                    and step.still.standing_still(stamp_ns)):
                delta = step.predict(state, stamp_ns)
                _advance(state, stamp_ns, state.pose @ delta, delta, (stamp_ns - state.stamp_ns) / 1e9)
                continue
            result = step.register(state, stamp_ns, frame_id, xyz, t_offset_ns, has_times, True)
            if result.points is not None and result.match is not None and needs_keyframe(
                    self.cfg, state.map_pose, member.matcher.map.size, result.pose):
                assert result.sensor is not None
                member.matcher.add_keyframe(result.points, result.pose, result.sensor)
                state.map_pose = result.pose
            delta = inverse(state.pose) @ result.pose if state.stamp_ns is not None else result.delta
            _advance(state, result.ref_ns, result.pose, delta, result.dt)

    def climbs(self, odometry_z: float) -> list[float]:
        """Each registration's climb since the fork, the odometry's (ending at `odometry_z`)
        first."""
        return [odometry_z - self.start_z,
                *(float(m.state.pose[2, 3]) - self.start_z for m in self.members)]


class ClimbFollower:
    """The odometry's side of the ensemble: forks it at each stair walk's first scan (before
    the odometry registers that scan), hands it the walk's scans, and at the floor reached moves
    the odometry to the median climb."""

    def __init__(self, cfg: MappingConfig, planar: bool) -> None:
        self.cfg = cfg
        self.planar = planar  # a 2D lidar measures no climb
        self.ensemble: ClimbEnsemble | None = None
        self._forkable = True  # off the stairs since the last fork
        self.climbs: list[list[float]] = []  # per walk, each registration's climb

    def drop(self) -> None:
        """An elevator ride: no walk ends on the floor reached."""
        self.ensemble = None

    def follow(self, on_stairs: bool, step: ScanStep, state: TrackState, stamp_ns: int,
               frame_id: str, xyz: F32, t_offset_ns: I64 | None, has_times: bool) -> None:
        if not on_stairs:
            self.ensemble, self._forkable = None, True
            return
        matcher = step.matcher
        if (self.ensemble is None and self._forkable and self.cfg.stairs.climb_registrations > 1
                and not self.planar and isinstance(matcher, ScanMatcher)
                and matcher.map.target is not None):
            self.ensemble = ClimbEnsemble(self.cfg, step, state)
            self._forkable = False
        if self.ensemble is not None:
            self.ensemble.add_scan(stamp_ns, frame_id, xyz, t_offset_ns, has_times)

    def end(self, state: TrackState, book: PoseBook) -> None:
        """Off a stair walk: the pose reached takes the registrations' median climb, and the
        walk's scans (hanging on the keyframe before it) their share of the change, so the
        stairs' cloud meets the floor reached."""
        ensemble, self.ensemble = self.ensemble, None
        if ensemble is None:
            return
        climbs = ensemble.climbs(float(state.pose[2, 3]))
        self.climbs.append(climbs)
        dz = median_change(climbs)
        state.pose = state.pose.copy()
        state.pose[2, 3] += dz
        if state.keyframe is not None:
            ramp_climb(book.scan_poses, state.keyframe, ensemble.start_ns, ensemble.start_z,
                       climbs[0], dz)


def median_change(climbs: list[float]) -> float:
    """What the odometry's climb (`climbs[0]`) moves by to the registrations' median climb."""
    return float(np.median(climbs)) - climbs[0]


def ramp_climb(scan_poses: list[ScanPose], before: Keyframe, start_ns: int, start_z: float,
               climb_m: float, dz: float) -> None:
    """Raise the walk's scans since `start_ns` (hanging on `before`, the keyframe before the
    walk) by `dz` in proportion to how far they climbed of the odometry's `climb_m` from
    `start_z` (by time where the walk hardly climbs)."""
    scans = [n for n in walk_scans(before, scan_poses) if scan_poses[n].stamp_ns >= start_ns]
    if not scans:
        return
    end_ns = scan_poses[scans[-1]].stamp_ns
    for n in scans:
        sp = scan_poses[n]
        pose = before.pose @ sp.relative
        if abs(climb_m) > 0.1:
            share = (pose[2, 3] - start_z) / climb_m
        else:
            share = (sp.stamp_ns - start_ns) / max(end_ns - start_ns, 1)
        pose[2, 3] += dz * min(max(share, 0.0), 1.0)
        scan_poses[n] = ScanPose(sp.stamp_ns, sp.keyframe, inverse(before.pose) @ pose)


def _advance(state: TrackState, ref_ns: int, pose: F64, delta: F64, dt: float) -> None:
    if dt > 0:
        state.delta, state.delta_dt_s = delta, dt
    state.pose, state.stamp_ns = pose, ref_ns
