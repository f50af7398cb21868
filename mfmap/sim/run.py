"""`simulate()`: a scenario's building, trajectory and sensors, written as a log with ground truth."""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mfmap.errors import MfmapError, OutputError
from mfmap.progress import NullProgress, Progress
from mfmap.sim import groundtruth
from mfmap.sim.building import Building
from mfmap.sim.route import RouteBuilder
from mfmap.sim.scenarios import SCENARIOS, ScenarioSpec, building_for
from mfmap.sim.sensors import (
    BARO_MOUNT,
    IMU_MOUNT,
    LASER_MOUNT,
    LIDAR_MOUNT,
    POINT_FIELDS,
    Barometer,
    Imu,
    Kinematics,
    Laser,
    Lidar,
    Mount,
    Scenes,
    Thermometer,
    WheelOdometry,
)
from mfmap.sim.trajectory import DT_S, RATE_HZ, Trajectory, quaternions
from mfmap.sim.world import World
from mfmap.sim.writers import LogWriter, u8
from mfmap.types import F64

logger = logging.getLogger(__name__)

TOPIC_LIDAR = "/lidar/points"
TOPIC_SCAN = "/scan"
TOPIC_IMU = "/imu/data"
TOPIC_ODOM = "/odom"
TOPIC_BARO = "/baro/pressure"
TOPIC_BARO_TEMPERATURE = "/baro/temperature"
TOPIC_TF_STATIC = "/tf_static"
TOPIC_DEPTH = "/camera/depth/image_raw"
TOPIC_DEPTH_INFO = "/camera/depth/camera_info"
TOPIC_COLOUR = "/camera/rgb/image_raw/compressed"
TOPIC_COLOUR_INFO = "/camera/rgb/camera_info"
BASE_FRAME = "base_link"
ODOM_FRAME = "odom"
IMU_RATE_HZ = 200
ODOM_RATE_HZ = 50

# Messages of one second, (stamp, order among equal stamps, topic, message), written sorted.
Batch = list[tuple[int, int, str, Any]]


@dataclass(frozen=True)
class SimResult:
    scenario: str
    fmt: str
    seed: int
    out_dir: Path
    log_path: Path
    gt_trajectory: Path
    gt_points: Path
    gt_floors: Path
    gt_cloud: Path
    start_ns: int
    duration_s: float
    n_floors: int
    message_counts: dict[str, int]
    log_bytes: int
    wall_time_s: float
    plots: list[Path] = field(default_factory=list)


def start_stamp_ns(seed: int) -> int:
    """A real-looking epoch start: 2024-05-06 09:00 UTC plus a seed-dependent offset."""
    return (1_714_986_000 + 86_400 * (seed % 365) + 37 * (seed % 97)) * 1_000_000_000 + 123_456_789


def reference_pressure_pa(seed: int) -> float:
    return 101_325.0 + float(np.random.default_rng([seed, 29]).uniform(-1200.0, 900.0))


def build_trajectory(spec: ScenarioSpec, building: Building, seed: int, reps: int) -> Trajectory:
    rng = np.random.default_rng([seed, 3])
    builder = RouteBuilder(building, spec.start_floor, rng, v_max=spec.v_max)
    if spec.session is not None:
        spec.session.place(builder)
    spec.route(builder, reps)
    return builder.finish(rng)


def scenario_route(spec: ScenarioSpec, seed: int, duration_scale: float = 1.0) -> tuple[Building, int, Trajectory]:
    """The scenario's building for `seed`, the log's own seed and its route, as `simulate`
    writes them (each floor visit's tour repeated round(duration_scale) times, at least once)."""
    building = building_for(spec, seed)
    # A session of a building shares the building with its other sessions, not their day.
    log_seed = spec.session.log_seed(seed) if spec.session is not None else seed
    return building, log_seed, build_trajectory(spec, building, log_seed, max(1, round(duration_scale)))


def make_barometer(spec: ScenarioSpec, building: Building, traj: Trajectory, seed: int) -> Barometer:
    """The scenario's barometer in its world: the world drawn from the seed, prepared for the
    route (zones, doors, cabin), and the sensor on top."""
    p0 = reference_pressure_pa(seed)
    world = World.draw(spec.world, building, p0, seed)
    baro = Barometer(spec.baro, traj, p0, seed, world)
    world.prepare(building, traj, baro.true_height(np.arange(len(traj.xyz))))
    return baro


def simulate(
    scenario: str,
    out_dir: Path | str,
    fmt: str = "mcap",
    seed: int = 0,
    plot: bool = False,
    duration_scale: float = 1.0,
    progress: Progress | None = None,
) -> SimResult:
    """Write `scenario`'s log (`fmt`: mcap, ros1, ros2) and its ground truth into `out_dir`.

    `duration_scale` repeats each floor visit's tour round(duration_scale) times (at least once):
    the same building and checkpoints, a longer log."""
    if scenario not in SCENARIOS:
        raise MfmapError(f"unknown scenario '{scenario}' (valid: {', '.join(SCENARIOS)})")
    if duration_scale <= 0:
        raise MfmapError(f"duration_scale must be positive, got {duration_scale}")
    progress = progress or NullProgress()
    t_wall = time.perf_counter()
    spec = SCENARIOS[scenario]
    out = _output_folder(Path(out_dir))
    building, log_seed, traj = scenario_route(spec, seed, duration_scale)
    start_ns = start_stamp_ns(log_seed)
    duration_s = round(traj.duration_s)
    baro = make_barometer(spec, building, traj, log_seed)
    with LogWriter(out, fmt) as writer:
        counts = _write_log(writer, spec, building, traj, baro, start_ns, duration_s, log_seed, progress)
    log_path = writer.path
    scan_rate = spec.lidar.rate_hz if spec.lidar else spec.laser.rate_hz  # type: ignore[union-attr]
    scan_times = np.arange(duration_s * scan_rate) / scan_rate
    paths = groundtruth.write_all(out, spec, building, traj, baro, start_ns, scan_times, seed)
    if spec.session is not None:
        paths["session"] = spec.session.write(out, scenario, seed, building, spec.start_floor, start_ns)
    plots = _plots(out, log_path, building, traj, baro, start_ns) if plot else []
    size = _log_bytes(log_path)
    return SimResult(
        scenario,
        fmt,
        seed,
        out,
        log_path,
        paths["trajectory"],
        paths["points"],
        paths["floors"],
        paths["cloud"],
        start_ns,
        float(duration_s),
        building.n_floors,
        counts,
        size,
        time.perf_counter() - t_wall,
        plots,
    )


def _output_folder(out: Path) -> Path:
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(f"cannot create the output folder ({err.strerror})", out) from err
    return out


def _plots(out: Path, log_path: Path, building: Building, traj: Trajectory, baro: Barometer, start_ns: int) -> list[Path]:
    """Floor plans with the route, and the pressure trace against the floors."""
    from mfmap.sim.plot import plot_floorplans, plot_pressure

    return [
        plot_floorplans(building, traj, out / "floorplans.png"),
        plot_pressure(log_path, traj, baro, building, start_ns, out / "pressure.png"),
    ]


def _log_bytes(log_path: Path) -> int:
    """Size of the log: its file, or every file of its folder (ROS 2 bags)."""
    return (
        sum(p.stat().st_size for p in log_path.rglob("*") if p.is_file())
        if log_path.is_dir()
        else log_path.stat().st_size
    )


def _stamp(start_ns: int, t_s_num: int, rate_hz: int) -> int:
    """Stamp of message number t_s_num of a stream at rate_hz (exact integer arithmetic)."""
    return start_ns + (t_s_num * 1_000_000_000) // rate_hz


@dataclass
class _Sensors:
    """The log's sensors, each drawing its own noise from the seed."""

    lidar: Lidar | None
    laser: Laser | None
    imu: Imu
    odom: WheelOdometry
    baro: Barometer
    thermo: Thermometer | None
    camera: Any  # RgbdCamera: mfmap.sim.camera loads only for a scenario with a camera


@dataclass
class _Kit:
    """Message parts shared by every message of a kind: point fields, covariances."""

    fields: list[Any]
    vec3: Any
    quat: Any
    cov_imu: F64
    cov_gyro: F64
    cov_acc: F64
    cov_pose: F64
    cov_twist: F64


def _write_log(
    w: LogWriter,
    spec: ScenarioSpec,
    building: Building,
    traj: Trajectory,
    baro: Barometer,
    start_ns: int,
    duration_s: int,
    seed: int,
    progress: Progress,
) -> dict[str, int]:
    sensors = _open_sensors(w, spec, building, traj, baro, start_ns, duration_s, seed)
    T = w.types
    kit = _Kit(
        fields=[T["sensor_msgs/msg/PointField"](name=n, offset=o, datatype=d, count=1) for n, o, d in POINT_FIELDS],
        vec3=T["geometry_msgs/msg/Vector3"],
        quat=T["geometry_msgs/msg/Quaternion"],
        cov_imu=np.diag([1e-5, 1e-5, 1e-5]).reshape(-1),
        cov_gyro=np.diag([9e-6] * 3).reshape(-1),
        cov_acc=np.diag([9e-4] * 3).reshape(-1),
        cov_pose=np.diag([0.01, 0.01, 1e6, 1e6, 1e6, 0.005]).reshape(-1),
        cov_twist=np.diag([2.5e-5, 1e6, 1e6, 1e6, 1e6, 1e-5]).reshape(-1),
    )
    n_scans = duration_s * (spec.lidar.rate_hz if spec.lidar else spec.laser.rate_hz)  # type: ignore[union-attr]
    with progress.stage("simulate", total=n_scans) as bar:
        for sec in range(duration_s):
            batch = _scan_messages(w, sensors, kit, sec, start_ns, bar)
            kin = Kinematics.of(traj, sec * RATE_HZ, (sec + 1) * RATE_HZ)
            batch += _motion_messages(w, sensors, kit, kin, sec, start_ns)
            batch += _baro_messages(w, spec, sensors, sec, start_ns)
            if sensors.camera is not None:
                batch += _camera_messages(w, sensors.camera, sec, start_ns)
            batch.sort(key=lambda m: (m[0], m[1]))
            for stamp, _, topic, msg in batch:
                w.write(topic, stamp, msg)
    return dict(w.counts)


def _open_sensors(
    w: LogWriter,
    spec: ScenarioSpec,
    building: Building,
    traj: Trajectory,
    baro: Barometer,
    start_ns: int,
    duration_s: int,
    seed: int,
) -> _Sensors:
    """The scenario's sensors, their topics, and /tf_static with their mounts."""
    scenes = Scenes(building, traj)
    lidar = Lidar(spec.lidar, scenes, seed) if spec.lidar else None
    laser = Laser(spec.laser, scenes, seed) if spec.laser else None
    imu = Imu(traj, seed)
    odom = WheelOdometry(seed)
    world = baro.world
    thermo = Thermometer(world, baro, duration_s, seed) if world and world.thermometer else None
    mounts = [IMU_MOUNT, BARO_MOUNT]
    if lidar:
        w.add_topic(TOPIC_LIDAR, "sensor_msgs/msg/PointCloud2")
        mounts.insert(0, LIDAR_MOUNT)
    if laser:
        w.add_topic(TOPIC_SCAN, "sensor_msgs/msg/LaserScan")
        mounts.append(LASER_MOUNT)
    w.add_topic(TOPIC_IMU, "sensor_msgs/msg/Imu")
    w.add_topic(TOPIC_ODOM, "nav_msgs/msg/Odometry")
    w.add_topic(TOPIC_BARO, "sensor_msgs/msg/FluidPressure")
    if thermo:
        w.add_topic(TOPIC_BARO_TEMPERATURE, "sensor_msgs/msg/Temperature")
    camera = None
    if spec.camera is not None:
        from mfmap.sim.camera import CAMERA_MOUNT, RgbdCamera

        camera = RgbdCamera(spec.camera, scenes, seed)
        mounts.append(CAMERA_MOUNT)
        for topic, msgtype in ((TOPIC_DEPTH, "sensor_msgs/msg/Image"),
                               (TOPIC_DEPTH_INFO, "sensor_msgs/msg/CameraInfo"),
                               (TOPIC_COLOUR, "sensor_msgs/msg/CompressedImage"),
                               (TOPIC_COLOUR_INFO, "sensor_msgs/msg/CameraInfo")):
            w.add_topic(topic, msgtype)
    w.add_topic(TOPIC_TF_STATIC, "tf2_msgs/msg/TFMessage", latched=True)
    w.write(TOPIC_TF_STATIC, start_ns, _tf_static(w, mounts, start_ns))
    return _Sensors(lidar, laser, imu, odom, baro, thermo, camera)


def _scan_messages(w: LogWriter, sensors: _Sensors, kit: _Kit, sec: int, start_ns: int, bar: Any) -> Batch:
    """One second of the 3D lidar's clouds and the 2D laser's scans."""
    T = w.types
    batch: Batch = []  # (stamp, order, topic, msg)
    lidar, laser = sensors.lidar, sensors.laser
    if lidar:
        rate = lidar.spec.rate_hz
        for k in range(sec * rate, (sec + 1) * rate):
            stamp = _stamp(start_ns, k, rate)
            pts = lidar.scan(k / rate)
            s = lidar.spec
            msg = T["sensor_msgs/msg/PointCloud2"](
                header=w.header(stamp, LIDAR_MOUNT.frame, TOPIC_LIDAR),
                height=s.beams,
                width=s.columns,
                fields=kit.fields,
                is_bigendian=False,
                point_step=pts.dtype.itemsize,
                row_step=pts.dtype.itemsize * s.columns,
                data=u8(pts),
                is_dense=False,
            )
            batch.append((stamp, 0, TOPIC_LIDAR, msg))
            bar.advance()
    if laser:
        s2 = laser.spec
        rate = s2.rate_hz
        for k in range(sec * rate, (sec + 1) * rate):
            stamp = _stamp(start_ns, k, rate)
            ranges, inten = laser.scan(k / rate)
            msg = T["sensor_msgs/msg/LaserScan"](
                header=w.header(stamp, LASER_MOUNT.frame, TOPIC_SCAN),
                angle_min=laser.angle_min,
                angle_max=laser.angle_min + laser.angle_inc * (s2.samples - 1),
                angle_increment=laser.angle_inc,
                time_increment=laser.time_inc_s,
                scan_time=1.0 / rate,
                range_min=s2.range_min_m,
                range_max=s2.range_max_m,
                ranges=ranges,
                intensities=inten,
            )
            batch.append((stamp, 0, TOPIC_SCAN, msg))
            bar.advance()
    return batch


def _motion_messages(
    w: LogWriter, sensors: _Sensors, kit: _Kit, kin: Kinematics, sec: int, start_ns: int
) -> Batch:
    """One second of the IMU (200 Hz) and the wheel odometry (50 Hz)."""
    T = w.types
    vec3, quat = kit.vec3, kit.quat
    batch: Batch = []
    i0, i1 = sec * RATE_HZ, (sec + 1) * RATE_HZ
    q, gyro, acc = sensors.imu.samples(kin)
    for j in range(i1 - i0):
        stamp = _stamp(start_ns, i0 + j, IMU_RATE_HZ)
        msg = T["sensor_msgs/msg/Imu"](
            header=w.header(stamp, IMU_MOUNT.frame, TOPIC_IMU),
            orientation=quat(x=q[j, 0], y=q[j, 1], z=q[j, 2], w=q[j, 3]),
            orientation_covariance=kit.cov_imu,
            angular_velocity=vec3(x=gyro[j, 0], y=gyro[j, 1], z=gyro[j, 2]),
            angular_velocity_covariance=kit.cov_gyro,
            linear_acceleration=vec3(x=acc[j, 0], y=acc[j, 1], z=acc[j, 2]),
            linear_acceleration_covariance=kit.cov_acc,
        )
        batch.append((stamp, 1, TOPIC_IMU, msg))
    step = RATE_HZ // ODOM_RATE_HZ
    for k in range(sec * ODOM_RATE_HZ, (sec + 1) * ODOM_RATE_HZ):
        x, y, yaw, v, wz = sensors.odom.step(kin, k * step)
        stamp = _stamp(start_ns, k, ODOM_RATE_HZ)
        pose = T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
            orientation=quat(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)),
        )
        twist = T["geometry_msgs/msg/Twist"](linear=vec3(x=v, y=0.0, z=0.0), angular=vec3(x=0.0, y=0.0, z=wz))
        msg = T["nav_msgs/msg/Odometry"](
            header=w.header(stamp, ODOM_FRAME, TOPIC_ODOM),
            child_frame_id=BASE_FRAME,
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=kit.cov_pose),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=kit.cov_twist),
        )
        batch.append((stamp, 2, TOPIC_ODOM, msg))
    return batch


def _baro_messages(w: LogWriter, spec: ScenarioSpec, sensors: _Sensors, sec: int, start_ns: int) -> Batch:
    """One second of the barometer's pressure and, when it has one, its temperature."""
    T = w.types
    batch: Batch = []
    baro, thermo = sensors.baro, sensors.thermo
    b_rate = spec.baro.rate_hz
    b_step = RATE_HZ // b_rate
    ks = np.arange(sec * b_rate, (sec + 1) * b_rate)
    pressures = baro.samples(ks * b_step)
    for kb, p in zip(ks, pressures, strict=True):
        stamp = _stamp(start_ns, int(kb), b_rate)
        msg = T["sensor_msgs/msg/FluidPressure"](
            header=w.header(stamp, BARO_MOUNT.frame, TOPIC_BARO),
            fluid_pressure=float(p),
            variance=spec.baro.noise_pa**2,
        )
        batch.append((stamp, 3, TOPIC_BARO, msg))
    if thermo:
        t_rate = thermo.rate_hz
        for kt in range(sec * t_rate, (sec + 1) * t_rate):
            stamp = _stamp(start_ns, kt, t_rate)
            msg = T["sensor_msgs/msg/Temperature"](
                header=w.header(stamp, BARO_MOUNT.frame, TOPIC_BARO_TEMPERATURE),
                temperature=float(thermo.celsius[kt]),
                variance=thermo.noise_k**2,
            )
            batch.append((stamp, 4, TOPIC_BARO_TEMPERATURE, msg))
    return batch


def _camera_messages(w: LogWriter, camera: Any, sec: int, start_ns: int) -> Batch:
    """One second of the RGB-D camera: depth (16UC1 mm), jpeg colour and their CameraInfo."""
    import cv2

    T = w.types
    s = camera.spec
    frame = camera.mount.frame
    out: Batch = []
    roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    k = np.array(s.k, dtype=np.float64)
    p = np.array([k[0], 0, k[2], 0, 0, k[4], k[5], 0, 0, 0, 1, 0], dtype=np.float64)
    for kk in range(sec * s.rate_hz, (sec + 1) * s.rate_hz):
        stamp = _stamp(start_ns, kk, s.rate_hz)
        depth, rgb = camera.capture(kk / s.rate_hz)
        for topic in (TOPIC_DEPTH_INFO, TOPIC_COLOUR_INFO):
            mats = {"d": np.zeros(5), "k": k, "r": np.eye(3).reshape(-1), "p": p}
            if w.fmt == "ros1":
                mats = {key.upper(): v for key, v in mats.items()}
            info = T["sensor_msgs/msg/CameraInfo"](
                header=w.header(stamp, frame, topic), height=s.height, width=s.width,
                distortion_model="plumb_bob", binning_x=0, binning_y=0, roi=roi, **mats)
            out.append((stamp, 5, topic, info))
        out.append((stamp, 6, TOPIC_DEPTH, T["sensor_msgs/msg/Image"](
            header=w.header(stamp, frame, TOPIC_DEPTH), height=s.height, width=s.width,
            encoding="16UC1", is_bigendian=0, step=s.width * 2, data=u8(depth.astype("<u2")))))
        ok, jpeg = cv2.imencode(".jpg", np.ascontiguousarray(rgb[:, :, ::-1]),
                                [cv2.IMWRITE_JPEG_QUALITY, s.jpeg_quality])
        assert ok
        out.append((stamp, 7, TOPIC_COLOUR, T["sensor_msgs/msg/CompressedImage"](
            header=w.header(stamp, frame, TOPIC_COLOUR), format="rgb8; jpeg compressed bgr8",
            data=u8(jpeg.tobytes()))))
    return out


def _tf_static(w: LogWriter, mounts: list[Mount], stamp_ns: int) -> Any:
    T = w.types
    transforms = []
    for m in mounts:
        q = quaternions(np.array([m.rpy]))[0]
        transforms.append(
            T["geometry_msgs/msg/TransformStamped"](
                header=w.header(stamp_ns, BASE_FRAME, TOPIC_TF_STATIC),
                child_frame_id=m.frame,
                transform=T["geometry_msgs/msg/Transform"](
                    translation=T["geometry_msgs/msg/Vector3"](x=m.xyz[0], y=m.xyz[1], z=m.xyz[2]),
                    rotation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
                ),
            )
        )
    return T["tf2_msgs/msg/TFMessage"](transforms=transforms)


assert DT_S * RATE_HZ == 1.0
