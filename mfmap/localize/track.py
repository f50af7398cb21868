"""Tracking a log's scans on one floor of the map: scans prepared, predicted and registered.

Each registered scan is aligned by point-to-plane ICP (the mapping stage's `icp`, on a target
whose k-d tree is built once per floor) from the pose the motion prior predicts: wheel odometry
for the translation and the IMU's gyro for the rotation since the last registered scan.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mfmap.localize.config import LocalizeConfig
from mfmap.mapping.cabin import CabinFilter
from mfmap.mapping.geometry import deskew, transform, twist
from mfmap.mapping.motion import MotionModel
from mfmap.mapping.registration import IcpTarget, downsample, icp
from mfmap.types import F32, F64, I64, Extrinsics, OdomSeries

# ICP passes of a tracked scan (correspondence distance, Tukey kernel, iterations): the motion
# prior over a few tenths of a second is good to centimetres, and the first pass has room for
# a few decimetres (wheels slipping, the first scan after a ride or stairs). The last pass's
# distance is the fit distance, so its fitness is the scan's (no query more).
TRACK_PASSES = ((0.5, 0.2, 3), (None, 0.05, 5))
# The first scan on a floor reached by stairs, whose heading and height the climb may have
# drifted: wider first passes.
WIDE_PASSES = ((1.0, 0.5, 10), (0.3, 0.1, 10), (None, 0.05, 8))
# Per-point sweep times span one rotation; the deskew twist is the motion over it.
SWEEP_NS = 100_000_000


@dataclass(frozen=True)
class Registered:
    pose: F64
    fitness: float


class ScanPrep:
    """Scans from the sensor frame to deskewed, thinned points in the base frame."""

    def __init__(self, cfg: LocalizeConfig, extrinsics: Extrinsics, motion: MotionModel,
                 cabin: CabinFilter | None, wheels: Wheels) -> None:
        self.cfg = cfg
        self.extrinsics = extrinsics
        self.motion = motion
        self.cabin = cabin
        self.wheels = wheels
        self.missing_frames: set[str] = set()

    def delta(self, from_ns: int, to_ns: int, quick: bool = False) -> F64:
        """The base's motion from from_ns to to_ns (base at to_ns in the base at from_ns): the
        wheels' translation and the gyro's rotation. `quick`: the wheels' alone, x, y and yaw,
        which is start enough for a registration (the slerps of the other cost a millisecond);
        not for poses kept without one (the wheels' yaw is off by a percent of the turn)."""
        if quick and self.wheels.usable:
            return self.wheels.delta(from_ns, to_ns)
        rel = self.motion.relative(from_ns, to_ns)
        out = np.eye(4) if rel is None else rel
        if self.motion.rotation_from_gyro(from_ns, to_ns):
            assert self.motion.gyro is not None
            out[:3, :3] = self.motion.gyro.delta(from_ns, to_ns)
        return out

    def points(self, stamp_ns: int, frame_id: str, xyz: F32, t_offset_ns: I64 | None,
               predicted: F64, voxel_m: float | None = None,
               velocity: tuple[F64, F64] | None = None) -> F64:
        """The scan in the base frame at its stamp, thinned to `voxel_m` (scan_voxel_m);
        deskewed with `velocity` (body angular, linear), else the motion prior's over the sweep."""
        rng = np.linalg.norm(xyz, axis=1)
        keep = (rng > self.cfg.min_range_m) & (rng < self.cfg.max_range_m)
        to_base = self.extrinsics.get(frame_id)
        if to_base is None:
            self.missing_frames.add(frame_id)
            to_base = np.eye(4)
        pts = transform(xyz[keep], to_base)
        if t_offset_ns is not None and len(t_offset_ns) == len(xyz) and len(pts):
            angular, linear = velocity or twist(self.delta(stamp_ns, stamp_ns + SWEEP_NS, quick=True),
                                                SWEEP_NS / 1e9)
            pts = deskew(pts, t_offset_ns[keep].astype(np.float64) / 1e9, angular, linear)
        if self.cabin is not None and len(pts):
            pts = self.cabin.apply(pts, stamp_ns, predicted, to_base[:3, 3])
        return downsample(pts, voxel_m or self.cfg.scan_voxel_m)

    def thin(self, points: F64) -> F64:
        """At most scan_points of the points, evenly spread over them (deterministically)."""
        if len(points) <= self.cfg.scan_points:
            return points
        return points[np.linspace(0, len(points) - 1, self.cfg.scan_points).astype(np.int64)]

    def in_cabin(self, stamp_ns: int, predicted: F64) -> bool:
        return self.cabin is not None and self.cabin.robot_inside(stamp_ns, predicted)


def register(points: F64, target: IcpTarget, predicted: F64, fit_distance_m: float,
             wide: bool = False, tolerance: float = 1e-5) -> Registered:
    """ICP of a scan (base frame) onto a floor from the predicted pose, and its fitness."""
    pose, fit = predicted, 0.0
    for max_distance, kernel, iterations in WIDE_PASSES if wide else TRACK_PASSES:
        result = icp(points, target, pose, max_distance or fit_distance_m, kernel, iterations,
                     tolerance=tolerance)
        pose, fit = result.transform, result.fitness
    return Registered(pose, fit)


class Wheels:
    """Wheel odometry as plain arrays: how far the robot drove and turned between two stamps,
    at the cost of a few interpolations (the motion model's slerps cost a millisecond a scan)."""

    def __init__(self, odom: OdomSeries | None) -> None:
        self.usable = odom is not None and len(odom) >= 2
        if not self.usable:
            return
        assert odom is not None
        order = np.argsort(odom.stamp_ns, kind="stable")
        self.t_ns = odom.stamp_ns[order].astype(np.float64)
        self.xy = odom.xyz[order, :2]
        q = odom.quat_xyzw[order]
        self.yaw = np.unwrap(2.0 * np.arctan2(q[:, 2], q[:, 3]))
        # Distance along the path, for spreading a pose change over the scans between two.
        self.path_m = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(self.xy, axis=0).T))])

    def along(self, stamps_ns: np.ndarray | int) -> np.ndarray:
        return np.interp(np.asarray(stamps_ns, dtype=np.float64), self.t_ns, self.path_m)

    def heading(self, stamps_ns: np.ndarray | int) -> np.ndarray:
        return np.interp(np.asarray(stamps_ns, dtype=np.float64), self.t_ns, self.yaw)

    def delta(self, from_ns: int, to_ns: int) -> F64:
        """The planar motion from from_ns to to_ns in the base frame at from_ns (4x4)."""
        t = np.array([from_ns, to_ns], dtype=np.float64)
        x = np.interp(t, self.t_ns, self.xy[:, 0])
        y = np.interp(t, self.t_ns, self.xy[:, 1])
        yaw = np.interp(t, self.t_ns, self.yaw)
        c, s = math.cos(yaw[0]), math.sin(yaw[0])
        dx, dy = x[1] - x[0], y[1] - y[0]
        turn = float(yaw[1] - yaw[0])
        out = np.eye(4)
        out[:2, :2] = [[math.cos(turn), -math.sin(turn)], [math.sin(turn), math.cos(turn)]]
        out[0, 3], out[1, 3] = c * dx + s * dy, -s * dx + c * dy
        return out

    def moved(self, from_ns: int, to_ns: int) -> tuple[float, float]:
        """(metres driven, degrees turned) from from_ns to to_ns."""
        t = np.array([from_ns, to_ns], dtype=np.float64)
        xy = np.column_stack([np.interp(t, self.t_ns, self.xy[:, 0]), np.interp(t, self.t_ns, self.xy[:, 1])])
        yaw = np.interp(t, self.t_ns, self.yaw)
        return float(np.hypot(*(xy[1] - xy[0]))), float(np.degrees(abs(yaw[1] - yaw[0])))


def interpolate(first: F64, last: F64, shares_turn: np.ndarray, shares_path: np.ndarray) -> F64:
    """Poses between two registered ones (M, 4, 4): rotation by `shares_turn` of the turn
    between them (slerp), position by `shares_path` of the way, shares in [0, 1]."""
    from scipy.spatial.transform import Rotation, Slerp

    out = np.tile(np.eye(4), (len(shares_turn), 1, 1))
    if len(shares_turn) == 0:
        return out
    slerp = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([first[:3, :3], last[:3, :3]])))
    out[:, :3, :3] = slerp(np.clip(shares_turn, 0.0, 1.0)).as_matrix()
    out[:, :3, 3] = first[:3, 3] + np.clip(shares_path, 0.0, 1.0)[:, None] * (last[:3, 3] - first[:3, 3])
    return out


__all__ = ["Registered", "ScanPrep", "Wheels", "interpolate", "register"]
