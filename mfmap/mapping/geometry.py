"""Small SE(3) helpers on 4x4 numpy poses (no open3d, no gtsam)."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation, Slerp

from mfmap.floors.filters import MAD_TO_SIGMA
from mfmap.types import F32, F64, I64, ImuSeries, OdomSeries

_RECENT = 8  # poses remembered per interpolator (stamps asked for again soon)


def make_pose(rotation: F64, translation: F64) -> F64:
    pose = np.eye(4)
    pose[:3, :3] = rotation
    pose[:3, 3] = translation
    return pose


def inverse(pose: F64) -> F64:
    out = np.eye(4)
    out[:3, :3] = pose[:3, :3].T
    out[:3, 3] = -pose[:3, :3].T @ pose[:3, 3]
    return out


def rotation_angle_rad(pose: F64) -> float:
    cos = (np.trace(pose[:3, :3]) - 1.0) / 2.0
    return float(np.arccos(np.clip(cos, -1.0, 1.0)))


def tilt_change_deg(delta: F64) -> float:
    """How far a relative pose turns the base's up (degrees)."""
    return float(np.degrees(np.arccos(np.clip(delta[2, 2], -1.0, 1.0))))


def pull_tilt(pose: F64, towards: F64, share: float) -> F64:
    """`pose` turned about a horizontal axis of its base so that its tilt (the world's up in its
    base) keeps `share` of its difference from `towards`'s; its position, and its heading to
    first order, stay."""
    up = pose[:3, :3].T[:, 2]  # the world's up in the base
    target = towards[:3, :3].T[:, 2]
    axis = np.cross(up, target)
    sin = float(np.linalg.norm(axis))
    if sin < 1e-12:
        return pose
    angle = math.atan2(sin, float(up @ target))
    turn = Rotation.from_rotvec(axis / sin * angle * (1.0 - share)).as_matrix()  # up -> towards
    out = pose.copy()
    out[:3, :3] = pose[:3, :3] @ turn.T
    return out


def yaw_rad(pose: F64) -> float:
    return float(np.arctan2(pose[1, 0], pose[0, 0]))


def wrap_angle(angle_rad: float) -> float:
    """The angle in [-pi, pi)."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


def yaw_pose(yaw: float, translation: F64 | None = None) -> F64:
    c, s = np.cos(yaw), np.sin(yaw)
    pose = np.eye(4)
    pose[:2, :2] = [[c, -s], [s, c]]
    if translation is not None:
        pose[:3, 3] = translation
    return pose


def twist(delta: F64, dt_s: float) -> tuple[F64, F64]:
    """Body-frame (angular rad/s, linear m/s) of a relative pose covered in dt_s."""
    if dt_s <= 0:
        return np.zeros(3), np.zeros(3)
    rotvec = Rotation.from_matrix(delta[:3, :3]).as_rotvec()
    return rotvec / dt_s, delta[:3, 3] / dt_s


def transform(points: F32 | F64, pose: F64) -> F64:
    return np.asarray(points, dtype=np.float64) @ pose[:3, :3].T + pose[:3, 3]


def deskew(points: F64, t_offset_s: F64, angular_rad_s: F64, linear_m_s: F64) -> F64:
    """Express points measured at stamp + t in the base frame at the stamp.

    Constant body twist over the sweep: T(t) = exp(t * xi), first order in translation.
    """
    if not np.any(angular_rad_s) and not np.any(linear_m_s):
        return points
    out = points + t_offset_s[:, None] * linear_m_s[None, :]
    rate = float(np.linalg.norm(angular_rad_s))
    if rate > 0.0:
        # One axis for the whole sweep: Rodrigues' formula per point, vectorised (a rotation
        # object per point costs several times more).
        kx, ky, kz = angular_rad_s / rate
        skew = np.array([[0.0, -kz, ky], [kz, 0.0, -kx], [-ky, kx, 0.0]])
        theta = t_offset_s * rate
        out += np.sin(theta)[:, None] * (points @ skew.T)
        out += (1.0 - np.cos(theta))[:, None] * (points @ (skew @ skew).T)
    return out


def deskew_measured(points: F64, t_offset_s: F64, rotations: Callable[[F64], F64],
                    linear_m_s: F64) -> F64:
    """As `deskew`, the rotation measured rather than assumed constant: `rotations(t)` gives
    the base at each time t (s from the reference) in the base at the reference time, from the
    gyro. A robot tipping off a stair turns 20 deg in half a second; a constant rate over the
    sweep, taken from the motion since the scan before, is degrees off there."""
    times, index = np.unique(t_offset_s, return_inverse=True)  # one per column of a spinning lidar
    per_point = rotations(times)[index]
    return np.einsum("nij,nj->ni", per_point, points) + t_offset_s[:, None] * linear_m_s[None, :]


class PoseInterpolator:
    """Pose of a timestamped series at any time (linear position, slerp rotation)."""

    def __init__(self, stamp_ns: I64, xyz: F64, quat_xyzw: F64) -> None:
        order = np.argsort(stamp_ns, kind="stable")
        self.stamp_ns = np.asarray(stamp_ns)[order]
        self.xyz = np.asarray(xyz, dtype=np.float64)[order]
        rotations = Rotation.from_quat(np.asarray(quat_xyzw, dtype=np.float64)[order])
        self._t_s = self._seconds(self.stamp_ns)
        self._slerp = Slerp(self._t_s, rotations)
        # The mapper asks for each scan's stamp twice (as the end of one motion step and the
        # start of the next): a few recent answers save half of the slerps.
        self._recent: dict[int, F64] = {}

    def _seconds(self, stamp_ns: I64 | int) -> F64:
        return (np.asarray(stamp_ns, dtype=np.int64) - int(self.stamp_ns[0])).astype(np.float64) / 1e9

    def at(self, stamp_ns: int) -> F64:
        cached = self._recent.get(stamp_ns)
        if cached is not None:
            return cached.copy()
        t = float(np.clip(self._seconds(stamp_ns), 0.0, self._t_s[-1]))
        xyz = np.array([np.interp(t, self._t_s, self.xyz[:, k]) for k in range(3)])
        pose = make_pose(self._slerp([t]).as_matrix()[0], xyz)
        if len(self._recent) >= _RECENT:
            self._recent.pop(next(iter(self._recent)))
        self._recent[stamp_ns] = pose
        return pose.copy()

    def covers(self, stamp_ns: int) -> bool:
        return bool(self.stamp_ns[0] <= stamp_ns <= self.stamp_ns[-1])

    @classmethod
    def from_odometry(cls, odom: OdomSeries) -> PoseInterpolator | None:
        if len(odom) < 2:
            return None
        return cls(odom.stamp_ns, odom.xyz, odom.quat_xyzw)


def still_mask(stamp_ns: I64, odom: OdomSeries | None, still_m_s: float = 0.005,
               still_rad_s: float = 0.005) -> npt.NDArray[np.bool_]:
    """Which of the stamps fall where wheel odometry says the robot stands still."""
    if odom is None or len(odom) < 2 or len(stamp_ns) == 0:
        return np.zeros(len(stamp_ns), dtype=bool)
    speed = np.linalg.norm(odom.linear_m_s, axis=1)
    turn = np.linalg.norm(odom.angular_rad_s, axis=1)
    still = ((speed < still_m_s) & (turn < still_rad_s)).astype(np.float64)
    at = np.interp(stamp_ns.astype(np.float64), odom.stamp_ns.astype(np.float64), still)
    return np.asarray(at > 0.999)


def gyro_bias(stamp_ns: I64, gyro_rad_s: F64, still: npt.NDArray[np.bool_], min_samples: int = 50,
              window_s: float = 120.0, step_s: float = 5.0) -> F64:
    """Gyro bias at every sample, (n, 3): the median rate while wheel odometry says the robot
    stands still (`still`, from `still_mask`: zero-velocity updates), over the still samples
    within window_s / 2 of it.

    A 0.1 deg/s bias is 1 deg after a 10 s turn in an elevator cabin, where lidar cannot help.
    A MEMS gyro's bias also wanders: one median over a whole log was 4e-4 rad/s off at some
    rides, 0.3 deg over the cabin's 180 deg turn; the still robot in the cabin during the ride
    measures it right there. Times with no still samples near them take the nearest estimate;
    without enough still samples in the log the bias is zero.
    """
    n = len(stamp_ns)
    if still.sum() < min_samples:
        return np.zeros((n, 3))
    t_s = (stamp_ns - stamp_ns[0]).astype(np.float64) / 1e9
    still_t = t_s[still]
    still_rate = gyro_rad_s[still]
    grid = np.arange(0.0, t_s[-1] + step_s, step_s)
    lo = np.searchsorted(still_t, grid - window_s / 2.0, side="left")
    hi = np.searchsorted(still_t, grid + window_s / 2.0, side="right")
    ok = (hi - lo) >= min_samples
    if not ok.any():
        return np.repeat(np.median(still_rate, axis=0)[None, :], n, axis=0)
    # The median: the first and last samples of a stand-still can already turn.
    medians = np.array([np.median(still_rate[a:b], axis=0) for a, b in zip(lo[ok], hi[ok], strict=True)])
    return np.column_stack([np.interp(t_s, grid[ok], medians[:, a]) for a in range(3)])


# A gyro's angle random walk when the log has no stand-still to measure it (0.7 deg/sqrt(h),
# a consumer MEMS part; the simulator's is 0.012 deg/sqrt(s)).
DEFAULT_HEADING_NOISE_RAD_SQRT_S = math.radians(0.012)


def heading_noise(stamp_ns: I64, yaw_rate_rad_s: F64, still: npt.NDArray[np.bool_],
                  min_samples: int = 200) -> float:
    """The bias-corrected gyro's angle random walk about z (rad / sqrt(s)): the robust spread of
    its rate while the robot stands still (`still`, from `still_mask`), times the square root of
    the sample interval."""
    if still.sum() < min_samples:
        return DEFAULT_HEADING_NOISE_RAD_SQRT_S
    rate = yaw_rate_rad_s[still]
    spread = MAD_TO_SIGMA * float(np.median(np.abs(rate - np.median(rate))))
    dt_s = float(np.median(np.diff(stamp_ns))) / 1e9
    return spread * math.sqrt(max(dt_s, 0.0))


def rotations_to(stamp_ns: I64, rate_rad_s: F64, ref_ns: int) -> F64:
    """Each sample's body frame in the body frame at ref_ns, (n, 3, 3), from body rates (bias
    taken off) at sorted stamps around it: midpoint steps chained by a parallel prefix product,
    log2(n) batched products instead of a Python loop over the samples."""
    t_s = (stamp_ns - ref_ns).astype(np.float64) / 1e9
    steps = Rotation.from_rotvec(0.5 * (rate_rad_s[1:] + rate_rad_s[:-1]) * np.diff(t_s)[:, None])
    chain = steps.as_matrix()
    shift = 1
    while shift < len(chain):  # chain[i] becomes steps[0] ... steps[i]
        chain = np.concatenate([chain[:shift], chain[:-shift] @ chain[shift:]])
        shift *= 2
    in_first = np.concatenate([np.eye(3)[None], chain])  # sample i in the first sample's frame
    near = int(np.argmin(np.abs(t_s)))
    ref_in_first = in_first[near] @ Rotation.from_rotvec(-t_s[near] * rate_rad_s[near]).as_matrix()
    return np.asarray(ref_in_first.T @ in_first)


class GyroIntegrator:
    """Rotation of the base between two times from the IMU gyro (rotated into the base frame)."""

    def __init__(self, imu: ImuSeries, imu_to_base: F64, odom: OdomSeries | None = None) -> None:
        order = np.argsort(imu.stamp_ns, kind="stable")
        self.stamp_ns = imu.stamp_ns[order]
        gyro_base = imu.gyro_rad_s[order] @ imu_to_base[:3, :3].T
        still = still_mask(self.stamp_ns, odom)
        self.bias_rad_s = gyro_bias(self.stamp_ns, gyro_base, still)
        gyro_base = gyro_base - self.bias_rad_s
        self.heading_noise_rad_sqrt_s = heading_noise(self.stamp_ns, gyro_base[:, 2], still)
        dt = np.diff(self.stamp_ns).astype(np.float64) / 1e9
        # Cumulative orientation at every sample (right-multiplied body increments).
        increments = Rotation.from_rotvec(gyro_base[:-1] * dt[:, None])
        mats = np.empty((len(self.stamp_ns), 3, 3))
        mats[0] = np.eye(3)
        current = np.eye(3)
        inc_mats = increments.as_matrix()
        for k in range(len(dt)):
            current = current @ inc_mats[k]
            mats[k + 1] = current
        self._slerp = Slerp((self.stamp_ns - self.stamp_ns[0]).astype(np.float64) / 1e9,
                            Rotation.from_matrix(mats))
        self._end_s = float((self.stamp_ns[-1] - self.stamp_ns[0]) / 1e9)
        self._recent: dict[int, Rotation] = {}  # see PoseInterpolator

    def covers(self, stamp_ns: int) -> bool:
        return bool(self.stamp_ns[0] <= stamp_ns <= self.stamp_ns[-1])

    def _at(self, stamp_ns: int) -> Rotation:
        cached = self._recent.get(stamp_ns)
        if cached is not None:
            return cached
        t = float(np.clip((stamp_ns - int(self.stamp_ns[0])) / 1e9, 0.0, self._end_s))
        rotation = self._slerp([t])[0]
        if len(self._recent) >= _RECENT:
            self._recent.pop(next(iter(self._recent)))
        self._recent[stamp_ns] = rotation
        return rotation

    def around(self, ref_ns: int, offsets_s: F64) -> F64:
        """Rotations (M, 3, 3) of the base at ref_ns + offsets_s in the base at ref_ns."""
        t0 = (ref_ns - int(self.stamp_ns[0])) / 1e9
        times = np.clip(t0 + offsets_s, 0.0, self._end_s)
        ref = self._at(ref_ns).inv()
        return np.asarray((ref * self._slerp(times)).as_matrix())

    def delta(self, start_ns: int, end_ns: int) -> F64:
        """Rotation matrix of the base at end_ns expressed in the base at start_ns."""
        return (self._at(start_ns).inv() * self._at(end_ns)).as_matrix()

    @staticmethod
    def usable(imu: ImuSeries | None) -> bool:
        return imu is not None and len(imu) >= 2
