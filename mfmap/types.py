"""Plain data passed between stages.

Stamps are integer nanoseconds (`*_ns`), positions metres, rotations as 4x4 homogeneous matrices
(float64) or quaternions in (x, y, z, w) order. Arrays are numpy; clouds are float32 to keep
memory small, poses float64.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum

import numpy as np
import numpy.typing as npt

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
U16 = npt.NDArray[np.uint16]
I32 = npt.NDArray[np.int32]


class Role(str, Enum):
    """What a topic is used for; assigned by message type."""

    LIDAR = "lidar"
    SCAN2D = "scan2d"
    BARO = "baro"
    IMU = "imu"
    ODOM = "odom"
    TF_STATIC = "tf_static"
    TEMPERATURE = "temperature"  # the barometer's air temperature (its height scale)


# ROS message type (normalised "pkg/msg/Name") -> role.
ROLE_BY_TYPE: dict[str, Role] = {
    "sensor_msgs/msg/PointCloud2": Role.LIDAR,
    # Livox's own scan message (its definition is read from the log).
    "livox_ros_driver2/msg/CustomMsg": Role.LIDAR,
    "livox_ros_driver/msg/CustomMsg": Role.LIDAR,
    "sensor_msgs/msg/LaserScan": Role.SCAN2D,
    "sensor_msgs/msg/FluidPressure": Role.BARO,
    "sensor_msgs/msg/Imu": Role.IMU,
    "nav_msgs/msg/Odometry": Role.ODOM,
    "tf2_msgs/msg/TFMessage": Role.TF_STATIC,
    "sensor_msgs/msg/Temperature": Role.TEMPERATURE,
}


class TransitionKind(str, Enum):
    ELEVATOR = "elevator"
    STAIRS = "stairs"
    UNKNOWN = "unknown"


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a log as `mfmap info` reports it."""

    name: str
    msgtype: str  # normalised "pkg/msg/Name"
    count: int
    first_ns: int | None
    last_ns: int | None
    role: Role | None  # the role this topic was chosen for, if any
    candidate_for: Role | None  # the role its type could play

    @property
    def rate_hz(self) -> float:
        if self.count < 2 or self.first_ns is None or self.last_ns is None:
            return 0.0
        span = (self.last_ns - self.first_ns) / 1e9
        return (self.count - 1) / span if span > 0 else 0.0


@dataclass(frozen=True)
class Cloud:
    """One decoded 3D lidar scan, points in the sensor frame, NaN no-returns dropped."""

    stamp_ns: int
    frame_id: str
    xyz: F32  # (N, 3)
    intensity: F32 | None = None  # (N,)
    ring: U16 | None = None  # (N,)
    t_offset_ns: I64 | None = None  # (N,) per-point time relative to stamp_ns


@dataclass(frozen=True)
class Scan2D:
    """One decoded LaserScan as 2D points in the sensor frame (invalid ranges dropped)."""

    stamp_ns: int
    frame_id: str
    xy: F32  # (N, 2)
    t_offset_ns: I64 | None = None  # (N,) from time_increment when the scanner gives it


@dataclass(frozen=True)
class PressureSeries:
    """Barometer trace in Pa, sorted by time."""

    stamp_ns: I64
    pressure_pa: F64
    frame_id: str = ""

    def __len__(self) -> int:
        return int(self.stamp_ns.shape[0])


@dataclass(frozen=True)
class TemperatureSeries:
    """sensor_msgs/Temperature readings in deg C, sorted by time."""

    stamp_ns: I64
    temperature_c: F64
    frame_id: str = ""
    topic: str = ""

    def __len__(self) -> int:
        return int(self.stamp_ns.shape[0])


@dataclass(frozen=True)
class ImuSeries:
    stamp_ns: I64
    gyro_rad_s: F64  # (N, 3)
    accel_m_s2: F64  # (N, 3)
    orientation_xyzw: F64  # (N, 4); NaN rows when the IMU gives none
    frame_id: str = ""

    def __len__(self) -> int:
        return int(self.stamp_ns.shape[0])


@dataclass(frozen=True)
class OdomSeries:
    """Wheel (or other) odometry: pose in its own odom frame and body-frame twist."""

    stamp_ns: I64
    xyz: F64  # (N, 3)
    quat_xyzw: F64  # (N, 4)
    linear_m_s: F64  # (N, 3) body frame
    angular_rad_s: F64  # (N, 3) body frame
    frame_id: str = ""
    child_frame_id: str = ""

    def __len__(self) -> int:
        return int(self.stamp_ns.shape[0])


@dataclass(frozen=True)
class Extrinsics:
    """Static transforms: child frame -> 4x4 pose of that frame in the base frame."""

    base_frame: str
    sensor_to_base: dict[str, F64] = field(default_factory=dict)

    def get(self, frame_id: str) -> F64 | None:
        if frame_id in ("", self.base_frame):
            return np.eye(4)
        return self.sensor_to_base.get(frame_id)


# ----- floors stage -------------------------------------------------------------------------


@dataclass(frozen=True)
class Floor:
    id: int  # 0 = lowest
    elevation_m: float  # relative to the starting floor (z = 0)
    pressure_pa: float  # typical pressure on this floor; NaN without a barometer
    visits: tuple[tuple[int, int], ...]  # (start_ns, end_ns) of each visit

    def pressure_json(self) -> float | None:
        """The pressure as floors.json holds it: null where no barometer measured it."""
        return round(self.pressure_pa, 2) if math.isfinite(self.pressure_pa) else None


@dataclass(frozen=True)
class Transition:
    kind: TransitionKind
    from_floor: int
    to_floor: int
    start_ns: int
    end_ns: int
    height_change_m: float


@dataclass(frozen=True)
class FloorSegmentation:
    """What the floors stage hands on: floors, transitions, and the filtered trace."""

    floors: tuple[Floor, ...]
    transitions: tuple[Transition, ...]
    stamp_ns: I64  # the barometer samples
    height_raw_m: F64
    height_filtered_m: F64
    floor_of_sample: I32  # floor id per sample, -1 inside a transition
    warnings: tuple[str, ...] = ()

    def floor_at(self, stamp_ns: int) -> int:
        """Floor id at a time (-1 inside a transition)."""
        i = int(np.clip(np.searchsorted(self.stamp_ns, stamp_ns), 0, len(self.stamp_ns) - 1))
        return int(self.floor_of_sample[i])

    def visits(self) -> list[tuple[int, int, int]]:
        """Every floor visit in time order as (floor_id, start_ns, end_ns)."""
        out = [(f.id, s, e) for f in self.floors for (s, e) in f.visits]
        return sorted(out, key=lambda v: v[1])


# ----- mapping stage -------------------------------------------------------------------------


@dataclass
class Keyframe:
    """A keyframe of one floor visit. `pose` is base-in-world (initial guess, then optimised)."""

    id: int
    stamp_ns: int
    floor_id: int
    visit: int  # index into FloorSegmentation.visits()
    pose: F64  # (4, 4)
    cloud: F32  # (N, 3) downsampled, base frame, deskewed
    fitness: float  # registration quality in [0, 1]
    rmse_m: float


class EdgeKind(str, Enum):
    """What measured a pose edge. The kind is a key of the graph's factor statistics, and str()
    and f-strings (report.html, the terminal) must give the value, as Python 3.11's StrEnum does;
    mfmap also runs on 3.10, which has no StrEnum."""

    ODOMETRY = "odometry"
    LOOP = "loop"

    def __str__(self) -> str:
        return str(self.value)

    def __format__(self, spec: str) -> str:
        return format(str(self.value), spec)


@dataclass(frozen=True)
class PoseEdge:
    """A relative-pose measurement between keyframes: T_i^-1 * T_j = measured."""

    i: int
    j: int
    measured: F64  # (4, 4)
    information: F64  # (6, 6), gtsam order (rx, ry, rz, tx, ty, tz)
    kind: EdgeKind
    fitness: float = 1.0


@dataclass
class ScanPose:
    """Pose of the base at one lidar scan, expressed relative to a keyframe."""

    stamp_ns: int
    keyframe: int
    relative: F64  # (4, 4): keyframe pose^-1 * scan pose


@dataclass
class MappingResult:
    keyframes: list[Keyframe]
    edges: list[PoseEdge]
    scan_poses: list[ScanPose]
    warnings: list[str] = field(default_factory=list)
    stats: dict[str, float] = field(default_factory=dict)
