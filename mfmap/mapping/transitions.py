"""Elevator rides and stair walks as the mapper meets them: where they are, the height during a
ride, and the heading across a walk."""

from __future__ import annotations

import math

import numpy as np

from mfmap.mapping.config import MappingConfig
from mfmap.mapping.geometry import GyroIntegrator, inverse, wrap_angle, yaw_pose, yaw_rad
from mfmap.mapping.timeline import Timeline
from mfmap.types import F64, FloorSegmentation, Keyframe, ScanPose, Transition, TransitionKind


class Transitions:
    """The rides and walks between a log's floor visits, and the filtered barometric height."""

    def __init__(self, seg: FloorSegmentation, timeline: Timeline) -> None:
        self.seg = seg
        self.timeline = timeline
        # Stair walks, widened: the floors stage places their ends to within a second or two.
        margin_ns = 3_000_000_000
        self.stair_walks = [(tr.start_ns - margin_ns, tr.end_ns + margin_ns)
                            for tr in timeline.transitions if tr.kind == TransitionKind.STAIRS]

    def on_stairs_at(self, stamp_ns: int) -> bool:
        return any(lo <= stamp_ns <= hi for lo, hi in self.stair_walks)

    def on_stairs(self, from_ns: int, to_ns: int) -> bool:
        return any(lo <= to_ns and from_ns <= hi for lo, hi in self.stair_walks)

    def rides(self, from_ns: int, to_ns: int) -> list[Transition]:
        """The elevator rides starting from from_ns until before to_ns."""
        return [tr for tr in self.timeline.transitions
                if tr.kind == TransitionKind.ELEVATOR and from_ns <= tr.start_ns < to_ns]

    def walked(self, from_ns: int, to_ns: int) -> bool:
        """Whether a stair walk starts from from_ns until before to_ns."""
        return any(tr.kind == TransitionKind.STAIRS and from_ns <= tr.start_ns < to_ns
                   for tr in self.timeline.transitions)

    def height(self, stamp_ns: int) -> float:
        if len(self.seg.stamp_ns) == 0:
            return 0.0
        return float(np.interp(stamp_ns, self.seg.stamp_ns, self.seg.height_filtered_m))


def walk_scans(before: Keyframe, scan_poses: list[ScanPose]) -> range:
    """Indices into `scan_poses` of the scans after `before` that hang on it: a walk's scans
    up to the keyframe that ends it (they are the list's last)."""
    first = len(scan_poses)
    while first > 0:
        sp = scan_poses[first - 1]
        if sp.keyframe != before.id or sp.stamp_ns <= before.stamp_ns:
            break
        first -= 1
    return range(first, len(scan_poses))


def walk_path_m(before: Keyframe, after: Keyframe, scan_poses: list[ScanPose]) -> float:
    """The distance the odometry travelled from `before` to `after` (the scans between hang on
    `before`), not the straight line: a switch-back stairwell's walk between two floors is a
    few metres from end to end and 15-25 m along its flights and landings."""
    points = [after.pose[:3, 3]]
    points += [(before.pose @ scan_poses[n].relative)[:3, 3]
               for n in reversed(walk_scans(before, scan_poses))]
    points.append(before.pose[:3, 3])
    return float(np.linalg.norm(np.diff(np.array(points), axis=0), axis=1).sum())


def walk_heading(cfg: MappingConfig, gyro: GyroIntegrator | None, before: Keyframe,
                 after: Keyframe, measured: F64, scan_poses: list[ScanPose]) -> F64:
    """The relative pose across a stair walk, its turn weighed between the registrations'
    and the IMU gyro's by their variances (`stairs_sigma_yaw_deg`,
    `stairs_gyro_sigma_yaw_deg`); the scans from `before` to `after` take their heading
    from the gyro, ramped to the weighed turn at `after` (their positions stay).

    On the stairs the registrations run without the gyro's hold (see `Mapper.add_scan`), and
    they slip: 0.3-0.6 deg within a scan or two as the robot tips onto the first step or half
    way up, and an excursion of -0.4 deg at the foot while the scan sees the flights. Over
    stairs seeds 0-2 the turn between the keyframes either side of a walk came out
    0.00-0.70 deg off from the registrations and 0.04-0.17 deg from the gyro (its bias,
    measured at the stand-stills, wanders over the walk's 20 s).
    """
    sigma_gyro = math.radians(cfg.stairs.gyro_sigma_yaw_deg)
    if (gyro is None or sigma_gyro <= 0 or not gyro.covers(before.stamp_ns)
            or not gyro.covers(after.stamp_ns)):
        return measured
    sigma_reg = math.radians(cfg.stairs.sigma_yaw_deg)

    def gyro_heading(stamp_ns: int) -> float:  # world yaw, turned by the gyro from `before`
        return yaw_rad(before.pose[:3, :3] @ gyro.delta(before.stamp_ns, stamp_ns))

    # The gyro's heading at `after` less the registrations'.
    gap = wrap_angle(gyro_heading(after.stamp_ns) - yaw_rad(after.pose))
    weighed = gap * sigma_reg**2 / (sigma_reg**2 + sigma_gyro**2)
    span_ns = after.stamp_ns - before.stamp_ns
    for n in walk_scans(before, scan_poses):
        sp = scan_poses[n]
        pose = before.pose @ sp.relative
        heading = (gyro_heading(sp.stamp_ns)
                   + (weighed - gap) * (sp.stamp_ns - before.stamp_ns) / span_ns)
        pose[:3, :3] = yaw_pose(wrap_angle(heading - yaw_rad(pose)))[:3, :3] @ pose[:3, :3]
        scan_poses[n] = ScanPose(sp.stamp_ns, sp.keyframe, inverse(before.pose) @ pose)
    target = after.pose.copy()
    target[:3, :3] = yaw_pose(weighed)[:3, :3] @ after.pose[:3, :3]
    return inverse(before.pose) @ target
