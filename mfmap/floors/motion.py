"""Is the robot moving horizontally? Evidence from odometry twist or IMU, used to tell an elevator
ride (height changes while the robot stands still) from stairs (height changes while it moves).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from mfmap.floors.config import FloorsConfig
from mfmap.types import F64, I64, ImuSeries, OdomSeries

BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class MotionEvidence:
    """Per-sample horizontal motion flags from one source ("odometry" or "imu")."""

    stamp_ns: I64
    moving: BoolArray
    source: str
    speed_m_s: F64 | None = None  # horizontal speed when the source measures it (odometry)

    def fraction_moving(self, start_ns: int, end_ns: int) -> float | None:
        """Fraction of samples in [start_ns, end_ns] flagged as moving; None without samples."""
        lo, hi = np.searchsorted(self.stamp_ns, [start_ns, end_ns], side="left")
        if hi <= lo:
            return None
        return float(np.mean(self.moving[lo:hi]))

    def path_m(self, start_ns: int, end_ns: int) -> float | None:
        """Horizontal distance travelled in [start_ns, end_ns] (None without a measured speed)."""
        if self.speed_m_s is None:
            return None
        lo, hi = np.searchsorted(self.stamp_ns, [start_ns, end_ns], side="left")
        if hi - lo < 2:
            return 0.0
        t_s = self.stamp_ns[lo:hi].astype(np.float64) / 1e9
        v = self.speed_m_s[lo:hi]
        return float(np.sum(0.5 * (v[1:] + v[:-1]) * np.diff(t_s)))

    def standstill_near(self, stamp_ns: int, within_ns: int, threshold_m_s: float, before: bool) -> int | None:
        """The last standstill sample before (or first after) stamp_ns within within_ns."""
        if self.speed_m_s is None:
            return None
        if before:
            lo, hi = np.searchsorted(self.stamp_ns, [stamp_ns - within_ns, stamp_ns], side="left")
        else:
            lo, hi = np.searchsorted(self.stamp_ns, [stamp_ns, stamp_ns + within_ns], side="right")
        still = np.flatnonzero(self.speed_m_s[lo:hi] < threshold_m_s)
        if still.size == 0:
            return None
        return int(self.stamp_ns[lo + (still[-1] if before else still[0])])


def _window(stamp_ns: I64, seconds: float) -> int:
    if stamp_ns.shape[0] < 2:
        return 1
    dt_s = float(np.median(np.diff(stamp_ns))) / 1e9
    return max(1, round(seconds / max(dt_s, 1e-6)))


def motion_from_odometry(odom: OdomSeries, cfg: FloorsConfig) -> MotionEvidence:
    """Moving when the body-frame horizontal speed or the yaw rate is above the config threshold."""
    speed = np.hypot(odom.linear_m_s[:, 0], odom.linear_m_s[:, 1])
    yaw_rate = np.abs(odom.angular_rad_s[:, 2])
    # Median over 0.5 s: one noisy twist message must not flip a stand-still into motion.
    size = _window(odom.stamp_ns, 0.5)
    smooth_speed = ndimage.uniform_filter1d(speed, size=_window(odom.stamp_ns, 0.2), mode="nearest")
    speed = ndimage.median_filter(speed, size=size, mode="nearest")
    yaw_rate = ndimage.median_filter(yaw_rate, size=size, mode="nearest")
    moving = (speed > cfg.moving.speed_m_s) | (yaw_rate > cfg.moving.yaw_rate_rad_s)
    return MotionEvidence(odom.stamp_ns.copy(), moving, "odometry", smooth_speed)


def motion_from_imu(imu: ImuSeries, cfg: FloorsConfig) -> MotionEvidence:
    """Moving when the horizontal acceleration varies (driving, steps) or the robot turns.

    Horizontal here is the IMU's x/y; an elevator's acceleration is vertical, so a level-mounted
    IMU in a cabin shows neither.
    """
    size = _window(imu.stamp_ns, 1.0)
    acc = imu.accel_m_s2[:, :2]
    mean = ndimage.uniform_filter1d(acc, size=size, axis=0, mode="nearest")
    mean_sq = ndimage.uniform_filter1d(acc**2, size=size, axis=0, mode="nearest")
    accel_std = np.sqrt(np.maximum(mean_sq - mean**2, 0.0).sum(axis=1))
    yaw_rate = ndimage.median_filter(np.abs(imu.gyro_rad_s[:, 2]), size=size, mode="nearest")
    moving = (accel_std > cfg.moving.accel_std_m_s2) | (yaw_rate > cfg.moving.yaw_rate_rad_s)
    return MotionEvidence(imu.stamp_ns.copy(), moving, "imu")
