"""The lidar odometry's motion prior between two scans, and the tracking state it starts from."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from mfmap.mapping.config import MotionPrior
from mfmap.mapping.geometry import GyroIntegrator, PoseInterpolator, inverse, twist
from mfmap.types import F64, I64, Extrinsics, ImuSeries, Keyframe, OdomSeries


@dataclass
class TrackState:
    """The odometry's state at the last scan."""

    visit: int = -1
    pose: F64 = field(default_factory=lambda: np.eye(4))  # base in world at the last scan
    stamp_ns: int | None = None
    delta: F64 = field(default_factory=lambda: np.eye(4))  # last scan-to-scan motion
    delta_dt_s: float = 0.1
    keyframe: Keyframe | None = None  # last keyframe handed out
    map_pose: F64 | None = None  # pose of the last local-map update (also during stairs)
    link_previous: bool = True  # odometry edge from the previous keyframe (False after a ride)
    scan_index: int = 0


# A MEMS gyro's scale factor is good to about half a percent.
GYRO_SCALE_SIGMA = 0.005
LEVEL_PIECE_NS = 250_000_000  # a tip onto or off a flight takes about half a second


class MotionModel:
    """Initial guess of the motion between two scans: odometry, IMU gyro, constant velocity."""

    def __init__(self, prior: MotionPrior, odom: OdomSeries | None, imu: ImuSeries | None,
                 extrinsics: Extrinsics) -> None:
        self.odom = PoseInterpolator.from_odometry(odom) if odom is not None else None
        self.gyro: GyroIntegrator | None = None
        if imu is not None and GyroIntegrator.usable(imu):
            imu_to_base = extrinsics.get(imu.frame_id)
            self.gyro = GyroIntegrator(imu, imu_to_base if imu_to_base is not None else np.eye(4),
                                       odom)
        use_odom = prior in (MotionPrior.AUTO, MotionPrior.ODOMETRY)
        use_gyro = prior in (MotionPrior.AUTO, MotionPrior.IMU)
        if not use_odom:
            self.odom = None
        if not use_gyro:
            self.gyro = None
        self.source = "odometry" if self.odom else ("imu" if self.gyro else "constant velocity")
        self.odom_scale = 1.0  # the wheels' distance scale (calibrated against the lidar)
        self._imu_stamp_ns: I64 | None = None
        self._accel_base: F64 | None = None
        if imu is not None and len(imu) > 0:
            imu_to_base = extrinsics.get(imu.frame_id)
            rot = np.eye(3) if imu_to_base is None else imu_to_base[:3, :3]
            self._imu_stamp_ns = imu.stamp_ns
            self._accel_base = imu.accel_m_s2 @ rot.T

    def level(self, pose: F64, start_ns: int, end_ns: int) -> F64:
        """The pose with its roll and pitch from gravity (mean accelerometer over the window).

        Used after an elevator ride: the cabin's vertical acceleration averages out and does
        not tilt the mean, so the new floor starts level even if the old one ended tilted.
        """
        if self._imu_stamp_ns is None or self._accel_base is None:
            return pose
        window = (self._imu_stamp_ns >= start_ns) & (self._imu_stamp_ns <= end_ns)
        if window.sum() < 10:
            return pose
        up = self._accel_base[window].mean(axis=0)
        up /= np.linalg.norm(up)
        # Roll/pitch rotation taking the base's measured "up" to the world's z axis.
        tilt, _ = Rotation.align_vectors([[0.0, 0.0, 1.0]], [up])
        yaw = float(np.arctan2(pose[1, 0], pose[0, 0]))
        tilt_yaw = float(np.arctan2(tilt.as_matrix()[1, 0], tilt.as_matrix()[0, 0]))
        rotation = Rotation.from_euler("z", yaw - tilt_yaw) * tilt
        out = pose.copy()
        out[:3, :3] = rotation.as_matrix()
        return out

    def stands_level(self, at_ns: int, half_ns: int, max_deg: float) -> bool:
        """Whether the base stood within max_deg of level from half_ns before at_ns to half_ns
        after: the mean accelerometer of every quarter second between (False without one). The
        robot's own acceleration leans it too, about a degree per 0.17 m/s^2."""
        if self._imu_stamp_ns is None or self._accel_base is None or max_deg <= 0:
            return False
        edges = np.arange(at_ns - half_ns, at_ns + half_ns + 1, LEVEL_PIECE_NS)
        bounds = np.searchsorted(self._imu_stamp_ns, edges)
        if len(bounds) < 2 or np.any(np.diff(bounds) < 2):
            return False
        sums = np.add.reduceat(self._accel_base[bounds[0]:bounds[-1]], bounds[:-1] - bounds[0],
                               axis=0)
        cos = sums[:, 2] / np.linalg.norm(sums, axis=1)
        return bool(np.all(cos >= np.cos(np.radians(max_deg))))

    def predict(self, state: TrackState, stamp_ns: int) -> F64:
        if state.stamp_ns is None:
            return np.eye(4)
        dt = (stamp_ns - state.stamp_ns) / 1e9
        angular, linear = twist(state.delta, state.delta_dt_s)
        delta = np.eye(4)
        delta[:3, :3] = Rotation.from_rotvec(angular * dt).as_matrix()
        delta[:3, 3] = linear * dt
        if self.odom is not None and self.odom.covers(state.stamp_ns) and self.odom.covers(stamp_ns):
            delta = inverse(self.odom.at(state.stamp_ns)) @ self.odom.at(stamp_ns)
            delta[:3, 3] *= self.odom_scale
        if self.gyro is not None and self.gyro.covers(state.stamp_ns) and self.gyro.covers(stamp_ns):
            delta[:3, :3] = self.gyro.delta(state.stamp_ns, stamp_ns)
        return delta

    def heading_var(self, dt_s: float, turn_rad: float) -> float:
        """Variance (rad^2) the gyro adds to a heading predicted over dt_s with this much turn:
        its angle random walk, measured at the log's stand-stills, and a scale factor good to
        GYRO_SCALE_SIGMA."""
        if self.gyro is None:
            return 0.0
        return (self.gyro.heading_noise_rad_sqrt_s ** 2 * max(dt_s, 0.0)
                + (GYRO_SCALE_SIGMA * turn_rad) ** 2)

    def rotation_from_gyro(self, from_ns: int | None, to_ns: int) -> bool:
        """Whether `predict` took the rotation from from_ns to to_ns from the gyro."""
        return (from_ns is not None and self.gyro is not None and self.gyro.covers(from_ns)
                and self.gyro.covers(to_ns))

    def relative(self, from_ns: int, to_ns: int) -> F64 | None:
        """Base at to_ns in the base at from_ns, from wheel odometry (None without it)."""
        rel = self.wheels(from_ns, to_ns)
        if rel is not None:
            rel[:3, 3] *= self.odom_scale
        return rel

    def wheels(self, from_ns: int, to_ns: int) -> F64 | None:
        """The same as measured by the wheels, without the calibrated scale."""
        if self.odom is None:
            return None
        return inverse(self.odom.at(from_ns)) @ self.odom.at(to_ns)

