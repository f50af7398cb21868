"""A small log of a robot turning on the spot in a room, written with the real writers.

The lidar is Ouster-like (organised rings x columns, `t` uint32 ns from the header stamp at the
sweep's start, columns clockwise from behind the sensor) and its points are ray-cast against the
room at each column's own time, so every scan carries the twist of the turn that a deskew must
take out. The IMU's gyro, the wheel odometry and /tf_static are consistent with it. Small
(16 x 256 points, 10 Hz, 24 s) so a test can rewrite it into every driver's layout.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from mfmap.sim.writers import LogWriter, u8

T0_NS = 1_714_986_000_123_456_789
RINGS, COLUMNS = 16, 256
PERIOD_NS = 100_000_000
COLUMN_NS = PERIOD_NS // COLUMNS  # 390 625 ns
SCANS = 240
RATE_RAD_S = 0.8  # the robot turns at this rate after the first 2 s
LIDAR_XYZ = (0.1, 0.0, 0.5)
LIDAR_YAW = 0.03
IMU_XYZ = (0.0, 0.05, 0.2)
# The room (x0, y0, x1, y1) and a pillar inside it, metres; floor at 0, ceiling at 3 m.
ROOM = (-3.0, -2.5, 5.0, 3.5)
PILLAR = (1.5, 1.0, 2.1, 1.6)
CEILING_M = 3.0
ELEVATION = np.radians(np.linspace(15.0, -15.0, RINGS))
POINT_DTYPE = np.dtype({"names": ["x", "y", "z", "intensity", "t", "ring"],
                        "formats": ["<f4", "<f4", "<f4", "<f4", "<u4", "<u2"],
                        "offsets": [0, 4, 8, 16, 20, 24], "itemsize": 32})
POINT_FIELDS = (("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 16, 7), ("t", 20, 6), ("ring", 24, 4))
NAMES = {"mcap": "log.mcap", "ros1": "log.bag", "ros2": "log"}


def yaw_at(t_s: np.ndarray[Any, Any] | float) -> np.ndarray[Any, Any]:
    """The robot's heading: still for 2 s, then turning at RATE_RAD_S."""
    t = np.asarray(t_s, dtype=np.float64)
    return RATE_RAD_S * np.clip(t - 2.0, 0.0, None)


def rate_at(t_s: np.ndarray[Any, Any] | float) -> np.ndarray[Any, Any]:
    return np.where(np.asarray(t_s) >= 2.0, RATE_RAD_S, 0.0)


def _box_range(ox: np.ndarray[Any, Any], oy: np.ndarray[Any, Any], dx: np.ndarray[Any, Any],
               dy: np.ndarray[Any, Any],
               box: tuple[float, float, float, float], inside: bool) -> np.ndarray[Any, Any]:
    """Horizontal distance along unit directions from (ox, oy) to a box's sides (the first
    side hit from outside, the side left through from inside)."""
    x0, y0, x1, y1 = box
    with np.errstate(divide="ignore", invalid="ignore"):
        tx0, tx1 = (x0 - ox) / dx, (x1 - ox) / dx
        ty0, ty1 = (y0 - oy) / dy, (y1 - oy) / dy
    near = np.maximum(np.minimum(tx0, tx1), np.minimum(ty0, ty1))
    far = np.minimum(np.maximum(tx0, tx1), np.maximum(ty0, ty1))
    if inside:
        return far
    return np.where((near <= far) & (near > 0), near, np.inf)


def scan_points(k: int) -> np.ndarray[Any, Any]:
    """Scan k as an organised (RINGS, COLUMNS) record array in the lidar frame."""
    t_col = k * PERIOD_NS / 1e9 + np.arange(COLUMNS) * COLUMN_NS / 1e9
    yaw = yaw_at(t_col)  # base heading at each column's time
    ox = LIDAR_XYZ[0] * np.cos(yaw) - LIDAR_XYZ[1] * np.sin(yaw)
    oy = LIDAR_XYZ[0] * np.sin(yaw) + LIDAR_XYZ[1] * np.cos(yaw)
    az = math.pi - 2 * math.pi * np.arange(COLUMNS) / COLUMNS  # in the lidar frame, clockwise
    world = yaw + LIDAR_YAW + az
    dx, dy = np.cos(world), np.sin(world)
    horizontal = np.minimum(_box_range(ox, oy, dx, dy, ROOM, True),
                            _box_range(ox, oy, dx, dy, PILLAR, False))
    pts = np.zeros((RINGS, COLUMNS), POINT_DTYPE)
    tan = np.tan(ELEVATION)[:, None]
    height = LIDAR_XYZ[2]
    # Up to the ceiling or down to the floor where the beam meets it before the wall.
    reach = np.where(tan > 0, (CEILING_M - height) / np.where(tan > 0, tan, 1.0),
                     np.where(tan < 0, -height / np.where(tan < 0, tan, 1.0), np.inf))
    d = np.minimum(horizontal[None, :], reach)
    pts["x"] = (d * np.cos(az)[None, :]).astype(np.float32)
    pts["y"] = (d * np.sin(az)[None, :]).astype(np.float32)
    pts["z"] = (d * tan).astype(np.float32)
    pts["intensity"] = 100.0
    pts["t"] = (np.arange(COLUMNS) * COLUMN_NS)[None, :]
    pts["ring"] = np.arange(RINGS, dtype=np.uint16)[:, None]
    # A few no-returns, as every lidar has: the same columns of the top ring each scan.
    pts["x"][0, 5::40] = np.nan
    pts["y"][0, 5::40] = np.nan
    pts["z"][0, 5::40] = np.nan
    return pts


def write(folder: Path, fmt: str, scans: int = SCANS) -> Path:
    """The room log in `fmt` (mcap, ros1, ros2) under `folder`, `scans` lidar scans long;
    returns the path to open."""
    folder.mkdir(parents=True, exist_ok=True)
    with LogWriter(folder, fmt) as w:
        T = w.types
        w.add_topic("/lidar/points", "sensor_msgs/msg/PointCloud2")
        w.add_topic("/imu/data", "sensor_msgs/msg/Imu")
        w.add_topic("/odom", "nav_msgs/msg/Odometry")
        w.add_topic("/baro/pressure", "sensor_msgs/msg/FluidPressure")
        w.add_topic("/tf_static", "tf2_msgs/msg/TFMessage", latched=True)
        vec3, quat = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
        mounts = [("lidar", LIDAR_XYZ, LIDAR_YAW), ("imu", IMU_XYZ, 0.0), ("baro", (0.0, 0.0, 0.3), 0.0)]
        transforms = [T["geometry_msgs/msg/TransformStamped"](
            header=w.header(T0_NS, "base_link", "/tf_static"), child_frame_id=name,
            transform=T["geometry_msgs/msg/Transform"](
                translation=vec3(x=xyz[0], y=xyz[1], z=xyz[2]),
                rotation=quat(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))))
            for name, xyz, yaw in mounts]
        w.write("/tf_static", T0_NS, T["tf2_msgs/msg/TFMessage"](transforms=transforms))
        fields = [T["sensor_msgs/msg/PointField"](name=n, offset=o, datatype=d, count=1) for n, o, d in POINT_FIELDS]
        batch: list[tuple[int, int, str, Any]] = []
        for k in range(scans):
            stamp = T0_NS + k * PERIOD_NS
            pts = scan_points(k)
            msg = T["sensor_msgs/msg/PointCloud2"](
                header=w.header(stamp, "lidar", "/lidar/points"), height=RINGS, width=COLUMNS,
                fields=fields, is_bigendian=False, point_step=32, row_step=32 * COLUMNS,
                data=u8(pts), is_dense=False)
            # Logged 5 ms after the sweep ended, as a driver stamping the sweep's start.
            batch.append((stamp + PERIOD_NS + 5_000_000, 0, "/lidar/points", msg))
        cov = np.zeros(9)
        for i in range(scans * PERIOD_NS // 5_000_000):
            stamp = T0_NS + i * 5_000_000
            t = i * 0.005
            yaw = float(yaw_at(t))
            msg = T["sensor_msgs/msg/Imu"](
                header=w.header(stamp, "imu", "/imu/data"),
                orientation=quat(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)),
                orientation_covariance=cov, angular_velocity=vec3(x=0.0, y=0.0, z=float(rate_at(t))),
                angular_velocity_covariance=cov, linear_acceleration=vec3(x=0.0, y=0.0, z=9.81),
                linear_acceleration_covariance=cov)
            batch.append((stamp, 1, "/imu/data", msg))
        for i in range(scans * PERIOD_NS // 20_000_000):
            stamp = T0_NS + i * 20_000_000
            t = i * 0.02
            yaw = float(yaw_at(t))
            pose = T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
                orientation=quat(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)))
            twist = T["geometry_msgs/msg/Twist"](linear=vec3(x=0.0, y=0.0, z=0.0),
                                                 angular=vec3(x=0.0, y=0.0, z=float(rate_at(t))))
            msg = T["nav_msgs/msg/Odometry"](
                header=w.header(stamp, "odom", "/odom"), child_frame_id="base_link",
                pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
                twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)))
            batch.append((stamp, 2, "/odom", msg))
        for i in range(scans * PERIOD_NS // 40_000_000):
            stamp = T0_NS + i * 40_000_000
            msg = T["sensor_msgs/msg/FluidPressure"](
                header=w.header(stamp, "baro", "/baro/pressure"), fluid_pressure=101_000.0 + 0.5 * (i % 3),
                variance=1.0)
            batch.append((stamp, 3, "/baro/pressure", msg))
        batch.sort(key=lambda m: (m[0], m[1]))
        for stamp, _, topic, msg in batch:
            w.write(topic, stamp, msg)
    return folder / NAMES[fmt]
