"""Small robot logs written with the REAL writers, in every format mfmap reads.

The content is fixed and known (see EXPECTED), so tests can assert exact counts, stamps and
decoded values. Messages are built with rosbags' message classes and serialised by rosbags
(CDR or ROS 1); the containers are written by mcap's Writer and rosbags' rosbag1/rosbag2 Writers.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

T0_NS = 1_700_000_000_000_000_000
LIDAR_N, LIDAR_DT = 10, 100_000_000  # 10 scans at 10 Hz
LIDAR2_N = 3
BARO_N, BARO_DT = 50, 40_000_000
IMU_N, IMU_DT = 100, 10_000_000
ODOM_N, ODOM_DT = 20, 50_000_000
SCAN_N, SCAN_DT = 5, 200_000_000
# The recorder logs each lidar scan 5 ms after its sweep ended; its header stamps the start.
LIDAR_LATENCY_NS = LIDAR_DT + 5_000_000
ROWS, COLS = 4, 8
NAN_PER_SCAN = 3  # the first three points of every scan are no-returns
TF_LIDAR_XYZ = (0.1, 0.0, 0.5)  # lidar in base_link, rotated 90 deg about z

FORMATS = ["mcap-ros2", "mcap-ros1", "ros1-none", "ros1-bz2", "ros1-lz4", "ros2-sqlite3", "ros2-mcap"]


@dataclass(frozen=True)
class Expected:
    counts: dict[str, int]


EXPECTED = Expected(
    counts={
        "/lidar/points": LIDAR_N,
        "/lidar2/points": LIDAR2_N,
        "/baro/pressure": BARO_N,
        "/imu/data": IMU_N,
        "/odom": ODOM_N,
        "/scan": SCAN_N,
        "/tf_static": 1,
    }
)


def lidar_points(k: int) -> np.ndarray[Any, Any]:
    """(ROWS*COLS, 3) float32 points of scan k (the first NAN_PER_SCAN become NaN on the wire)."""
    i = np.arange(ROWS * COLS, dtype=np.float32)
    pts = np.stack([i * 0.5 + k, -i * 0.25, np.full_like(i, 0.1 * k)], axis=1).astype(np.float32)
    return pts


def point_time_ns(index: np.ndarray[Any, Any]) -> np.ndarray[Any, Any]:
    """Ouster-like uint32 ns from the stamp: the columns of a 10 Hz sweep fire 12.5 ms apart."""
    return ((index % COLS) * (LIDAR_DT // COLS)).astype(np.uint32)


def pressure_pa(i: int) -> float:
    return 101_325.0 - 0.5 * i


def typestore(ros1: bool) -> Typestore:
    """A typestore with every type the test log uses (Noetic's lacks tf2_msgs/TFMessage)."""
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if "tf2_msgs/msg/TFMessage" not in store.fielddefs:
        store.register(
            get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage")
        )
    return store


def _header(store: Typestore, stamp_ns: int, frame: str) -> Any:
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    stamp = Time(sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)
    if "seq" in [f[0] for f in store.fielddefs["std_msgs/msg/Header"][1]]:
        return Header(seq=0, stamp=stamp, frame_id=frame)
    return Header(stamp=stamp, frame_id=frame)


def _cloud(store: Typestore, k: int, stamp_ns: int) -> Any:
    PointField = store.types["sensor_msgs/msg/PointField"]
    # Field order scrambled and padded on purpose: t, then intensity, a gap, then x y z, ring.
    point_step = 32
    dt = np.dtype(
        {
            "names": ["t", "intensity", "x", "y", "z", "ring"],
            "formats": ["<u4", "<f4", "<f4", "<f4", "<f4", "<u2"],
            "offsets": [0, 4, 12, 16, 20, 24],
            "itemsize": point_step,
        }
    )
    n = ROWS * COLS
    arr = np.zeros(n, dtype=dt)
    pts = lidar_points(k)
    pts[:NAN_PER_SCAN] = np.nan
    arr["x"], arr["y"], arr["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    arr["intensity"] = np.arange(n, dtype=np.float32) + 100 * k
    arr["ring"] = np.arange(n) // COLS
    arr["t"] = point_time_ns(np.arange(n))
    fields = [
        PointField(name="t", offset=0, datatype=6, count=1),
        PointField(name="intensity", offset=4, datatype=7, count=1),
        PointField(name="x", offset=12, datatype=7, count=1),
        PointField(name="y", offset=16, datatype=7, count=1),
        PointField(name="z", offset=20, datatype=7, count=1),
        PointField(name="ring", offset=24, datatype=4, count=1),
    ]
    return store.types["sensor_msgs/msg/PointCloud2"](
        header=_header(store, stamp_ns, "lidar"),
        height=ROWS,
        width=COLS,
        fields=fields,
        is_bigendian=False,
        point_step=point_step,
        row_step=point_step * COLS,
        data=np.frombuffer(arr.tobytes(), dtype=np.uint8),
        is_dense=False,
    )


def _vec(store: Typestore, x: float, y: float, z: float) -> Any:
    return store.types["geometry_msgs/msg/Vector3"](x=x, y=y, z=z)


def _quat(store: Typestore, x: float, y: float, z: float, w: float) -> Any:
    return store.types["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)


def messages(store: Typestore) -> Iterator[tuple[str, str, int, Any]]:
    """(topic, msgtype, log_time_ns, message) in log-time order."""
    out: list[tuple[str, str, int, Any]] = []
    for k in range(LIDAR_N):
        stamp = T0_NS + k * LIDAR_DT
        out.append(("/lidar/points", "sensor_msgs/msg/PointCloud2", stamp + LIDAR_LATENCY_NS,
                    _cloud(store, k, stamp)))
    for k in range(LIDAR2_N):
        stamp = T0_NS + k * 300_000_000 + 1
        out.append(("/lidar2/points", "sensor_msgs/msg/PointCloud2", stamp, _cloud(store, k, stamp)))
    for i in range(BARO_N):
        stamp = T0_NS + i * BARO_DT
        msg = store.types["sensor_msgs/msg/FluidPressure"](
            header=_header(store, stamp, "baro"), fluid_pressure=pressure_pa(i), variance=0.0
        )
        out.append(("/baro/pressure", "sensor_msgs/msg/FluidPressure", stamp, msg))
    cov = np.zeros(9, dtype=np.float64)
    no_orientation = cov.copy()
    no_orientation[0] = -1.0
    for i in range(IMU_N):
        stamp = T0_NS + i * IMU_DT
        msg = store.types["sensor_msgs/msg/Imu"](
            header=_header(store, stamp, "imu"),
            orientation=_quat(store, 0.0, 0.0, 0.0, 1.0),
            orientation_covariance=no_orientation if i % 2 else cov,
            angular_velocity=_vec(store, 0.01 * i, 0.0, 0.0),
            angular_velocity_covariance=cov,
            linear_acceleration=_vec(store, 0.0, 0.0, 9.81),
            linear_acceleration_covariance=cov,
        )
        out.append(("/imu/data", "sensor_msgs/msg/Imu", stamp, msg))
    for i in range(ODOM_N):
        stamp = T0_NS + i * ODOM_DT
        pose = store.types["geometry_msgs/msg/PoseWithCovariance"](
            pose=store.types["geometry_msgs/msg/Pose"](
                position=store.types["geometry_msgs/msg/Point"](x=0.05 * i, y=0.0, z=0.0),
                orientation=_quat(store, 0.0, 0.0, 0.0, 1.0),
            ),
            covariance=np.zeros(36),
        )
        twist = store.types["geometry_msgs/msg/TwistWithCovariance"](
            twist=store.types["geometry_msgs/msg/Twist"](
                linear=_vec(store, 1.0, 0.0, 0.0), angular=_vec(store, 0.0, 0.0, 0.1)
            ),
            covariance=np.zeros(36),
        )
        msg = store.types["nav_msgs/msg/Odometry"](
            header=_header(store, stamp, "odom"), child_frame_id="base_link", pose=pose, twist=twist
        )
        out.append(("/odom", "nav_msgs/msg/Odometry", stamp, msg))
    for i in range(SCAN_N):
        stamp = T0_NS + i * SCAN_DT
        ranges = np.array([1.0, np.nan, 2.0, np.inf, 50.0, 0.01, 3.0, 4.0], dtype=np.float32)
        msg = store.types["sensor_msgs/msg/LaserScan"](
            header=_header(store, stamp, "laser"),
            angle_min=0.0,
            angle_max=7 * math.pi / 4,
            angle_increment=math.pi / 4,
            time_increment=0.001,
            scan_time=0.1,
            range_min=0.1,
            range_max=30.0,
            ranges=ranges,
            intensities=np.zeros(8, dtype=np.float32),
        )
        out.append(("/scan", "sensor_msgs/msg/LaserScan", stamp, msg))
    s = math.sqrt(0.5)
    tfs = []
    for child, xyz, q in (("lidar", TF_LIDAR_XYZ, (0.0, 0.0, s, s)), ("imu", (0.0, 0.0, 0.2), (0.0, 0.0, 0.0, 1.0))):
        tfs.append(
            store.types["geometry_msgs/msg/TransformStamped"](
                header=_header(store, 0, "base_link"),
                child_frame_id=child,
                transform=store.types["geometry_msgs/msg/Transform"](
                    translation=_vec(store, *xyz), rotation=_quat(store, *q)
                ),
            )
        )
    out.append(("/tf_static", "tf2_msgs/msg/TFMessage", T0_NS - 1_000_000,
                store.types["tf2_msgs/msg/TFMessage"](transforms=tfs)))
    out.sort(key=lambda m: m[2])
    yield from out


Item = tuple[str, str, int, Any]
Edit = Callable[[Typestore, list[Item]], Iterable[Item]]


def write_log(folder: Path, fmt: str, edit: Edit | None = None) -> Path:
    """Write the standard test log in `fmt` under `folder`; returns the path to open.

    `edit(store, items)` may change the (topic, msgtype, log_time_ns, message) items first; they
    are written in the order it returns them (the recording order)."""
    folder.mkdir(parents=True, exist_ok=True)

    def items(store: Typestore) -> Iterable[Item]:
        out = list(messages(store))
        return edit(store, out) if edit is not None else out

    if fmt in ("mcap-ros2", "mcap-ros1"):
        store = typestore(fmt == "mcap-ros1")
        return write_mcap_items(folder / "log.mcap", items(store), store, ros1=fmt == "mcap-ros1")
    if fmt.startswith("ros1-"):
        return _write_ros1(folder / "log.bag", fmt.split("-", 1)[1], items)
    if fmt.startswith("ros2-"):
        return _write_ros2(folder / "log", fmt.split("-", 1)[1], items)
    raise ValueError(fmt)


def _write_mcap(path: Path, ros1: bool, **writer_kw: Any) -> Path:
    store = typestore(ros1)
    return write_mcap_items(path, messages(store), store, ros1=ros1, **writer_kw)


def restamp(store: Typestore, msg: Any, stamp_ns: int) -> Any:
    """The message with its header stamp set to stamp_ns (a copy)."""
    import copy

    out = copy.copy(msg)
    out.header = _header(store, stamp_ns, msg.header.frame_id)
    return out


def write_mcap_items(
    path: Path,
    items: Iterable[tuple[str, str, int, Any]],
    store: Typestore,
    ros1: bool = False,
    no_definition: Collection[str] = (),
    **writer_kw: Any,
) -> Path:
    """Write (topic, msgtype, log_time_ns, message) items with mcap's Writer.

    Types in `no_definition` get a schema with an empty definition. `writer_kw` go to the
    Writer (chunk_size, use_chunking, index_types, repeat_channels, ...).
    """
    from mcap.writer import Writer

    with path.open("wb") as f:
        w = Writer(f, **writer_kw)
        w.start(profile="ros1" if ros1 else "ros2", library="mfmap-tests")
        channels: dict[str, int] = {}
        for topic, msgtype, t, msg in items:
            if topic not in channels:
                text = "" if msgtype in no_definition else store.generate_msgdef(
                    msgtype, ros_version=1 if ros1 else 2
                )[0]
                name = msgtype.replace("/msg/", "/") if ros1 else msgtype
                sid = w.register_schema(name, "ros1msg" if ros1 else "ros2msg", text.encode())
                channels[topic] = w.register_channel(topic, "ros1" if ros1 else "cdr", sid)
            data = store.serialize_ros1(msg, msgtype) if ros1 else store.serialize_cdr(msg, msgtype)
            w.add_message(channels[topic], log_time=t, data=bytes(data), publish_time=t)
        w.finish()
    return path


def pressure_msg(store: Typestore, stamp_ns: int, value: float) -> Any:
    return store.types["sensor_msgs/msg/FluidPressure"](
        header=_header(store, stamp_ns, "baro"), fluid_pressure=value, variance=0.0
    )


def cloud_msg(store: Typestore, k: int, stamp_ns: int) -> Any:
    """Scan k of the standard log as a PointCloud2 message."""
    return _cloud(store, k, stamp_ns)


def _write_ros1(path: Path, compression: str,
                items: Callable[[Typestore], Iterable[Item]] = messages) -> Path:
    from rosbags.rosbag1 import Writer

    store = typestore(ros1=True)
    w = Writer(path)
    if compression != "none":
        w.set_compression(getattr(Writer.CompressionFormat, compression.upper()))
    # Small chunks, so the bag has many chunks like a real one.
    w.chunk_threshold = 4096
    with w:
        conns: dict[str, Any] = {}
        for topic, msgtype, t, msg in items(store):
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msgtype, typestore=store)
            w.write(conns[topic], t, store.serialize_ros1(msg, msgtype))
    return path


def _write_ros2(path: Path, storage: str,
                items: Callable[[Typestore], Iterable[Item]] = messages) -> Path:
    from rosbags.rosbag2 import StoragePlugin, Writer

    store = typestore(ros1=False)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as w:
        conns: dict[str, Any] = {}
        for topic, msgtype, t, msg in items(store):
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msgtype, typestore=store)
            w.write(conns[topic], t, store.serialize_cdr(msg, msgtype))
    return path
