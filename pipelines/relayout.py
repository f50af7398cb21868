"""Rewrite a log's lidar into another driver's layout, to check mfmap reads it the same.

    .venv/bin/python pipelines/relayout.py LOG --as velodyne -o OUT.mcap
    .venv/bin/python pipelines/relayout.py LOG --as scan2d-rplidar -o OUT.mcap
    .venv/bin/python pipelines/relayout.py LOG --as ouster --drop-transform -o OUT.mcap

Only the lidar messages change (and /tf_static where an option says so); every other message is
copied byte for byte, into the same kind of container (MCAP, ROS 1 bag, ROS 2 bag), by the real
writers (mcap's Writer, rosbags' rosbag1/rosbag2 Writers). The points stay the same points in
the base frame; what changes is how a driver would have laid them out: field types and order,
organised or not, the header stamp at the sweep's start or end, and the time field's unit and
reference:

| layout | as published by | fields | organised | stamp | per-point time |
|---|---|---|---|---|---|
| ouster | ouster-ros | x y z intensity t ring | rings x columns | start | `t` uint32 ns from the stamp |
| velodyne | velodyne_pointcloud | x y z intensity ring time (22 B) | no | end | `time` float32 s from the stamp (<= 0) |
| hesai | HesaiLidar_ROS_2.0 | x y z _ intensity ring timestamp | no | start | `timestamp` float64 epoch s |
| robosense | rslidar_sdk | x y z intensity ring timestamp (26 B) | columns x rings | end | `timestamp` float64 epoch s |
| livox | livox_ros_driver2 (xfer_format 0) | x y z intensity tag line timestamp | no | start | `timestamp` float64 epoch **ns** |
| livox-custom | livox_ros_driver2 CustomMsg | offset_time x y z reflectivity tag line | no | start | `offset_time` uint32 ns from `timebase` |
| notime | (a driver without time) | x y z intensity | as the source | start | none |
| scan2d | a 2D scanner (LaserScan) | the ring nearest level | - | start | beams in sweep order |
| scan2d-rplidar | rplidar_ros | the same, ranges reversed | - | start | time_increment > 0 against the sweep |

The source's lidar must be organised (rings x columns, as ouster-ros and the simulator write) so
that the columns give the sweep order.
"""

from __future__ import annotations

import argparse
import math
import shutil
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from mfmap.errors import MfmapError
from mfmap.ingest import open_log
from mfmap.ingest.config import IngestConfig
from mfmap.ingest.decode import cloud_layout, quat_to_matrix
from mfmap.ingest.lidartime import TimeSpec
from mfmap.ingest.wire import parse_pointcloud2
from mfmap.types import Role

LAYOUTS = ("ouster", "velodyne", "hesai", "robosense", "livox", "livox-custom", "notime",
           "scan2d", "scan2d-rplidar")
MOUNTS = ("upside-down", "turned")
CLOUD = "sensor_msgs/msg/PointCloud2"
SCAN = "sensor_msgs/msg/LaserScan"
CUSTOM = "livox_ros_driver2/msg/CustomMsg"
TF = "tf2_msgs/msg/TFMessage"
IMU = "sensor_msgs/msg/Imu"
PRESSURE = "sensor_msgs/msg/FluidPressure"
TEMPERATURE = "sensor_msgs/msg/Temperature"

CUSTOM_POINT_DEF = """uint32 offset_time
float32 x
float32 y
float32 z
uint8 reflectivity
uint8 tag
uint8 line
"""
CUSTOM_MSG_DEF = """std_msgs/Header header
uint64 timebase
uint32 point_num
uint8 lidar_id
uint8[3] rsvd
livox_ros_driver2/CustomPoint[] points
"""

# (name, offset, numpy type, PointField datatype) and point_step of each PointCloud2 layout.
_DATATYPE = {"i1": 1, "u1": 2, "i2": 3, "u2": 4, "i4": 5, "u4": 6, "f4": 7, "f8": 8}
FIELDS: dict[str, tuple[list[tuple[str, int, str]], int]] = {
    "ouster": ([("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4"), ("intensity", 16, "f4"),
                ("t", 20, "u4"), ("ring", 24, "u2")], 32),
    "velodyne": ([("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4"), ("intensity", 12, "f4"),
                  ("ring", 16, "u2"), ("time", 18, "f4")], 22),
    "hesai": ([("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4"), ("intensity", 16, "f4"),
               ("ring", 20, "u2"), ("timestamp", 24, "f8")], 32),
    "robosense": ([("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4"), ("intensity", 12, "f4"),
                   ("ring", 16, "u2"), ("timestamp", 18, "f8")], 26),
    "livox": ([("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4"), ("intensity", 12, "f4"),
               ("tag", 16, "u1"), ("line", 17, "u1"), ("timestamp", 18, "f8")], 26),
    "notime": ([("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4"), ("intensity", 12, "f4")], 16),
}


class RelayoutError(MfmapError):
    """A log that cannot be rewritten (no organised lidar with per-point time, bad options)."""


@dataclass
class Scan:
    """One organised source scan (rings x columns), its points in the (new) sensor frame."""

    stamp_ns: int
    frame: str
    xyz: np.ndarray[Any, Any]  # (H, W, 3) float32, NaN where no return
    intensity: np.ndarray[Any, Any]  # (H, W) float32
    ring: np.ndarray[Any, Any]  # (H, W) uint16
    t_ns: np.ndarray[Any, Any]  # (H, W) int64 time from stamp_ns
    valid: np.ndarray[Any, Any]  # (H, W) bool


@dataclass(frozen=True)
class Options:
    layout: str
    drop_transform: bool = False
    tf_on_tf: bool = False
    mount: str | None = None
    imu_no_orientation: bool = False
    imu_rotated: bool = False
    baro_unit: str = "Pa"
    temperature_topic: bool = False


# ----- the layouts ----------------------------------------------------------------------------


def _rotation(name: str) -> np.ndarray[Any, Any]:
    if name == "upside-down":
        return np.diag([1.0, -1.0, -1.0])  # roll 180 deg
    if name == "turned":
        return np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # yaw 90 deg
    raise RelayoutError(f"unknown mount '{name}' (known: {', '.join(MOUNTS)})")


def _header(types: dict[str, Any], ros1: bool, stamp_ns: int, frame: str) -> Any:
    stamp = types["builtin_interfaces/msg/Time"](sec=stamp_ns // 1_000_000_000,
                                                 nanosec=stamp_ns % 1_000_000_000)
    if ros1:
        return types["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)
    return types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)


def _epoch_s(stamp_ns: int, t_ns: np.ndarray[Any, Any]) -> np.ndarray[Any, Any]:
    """stamp + t as float64 epoch seconds (whole seconds first: one rounding, not two)."""
    sec, rem = divmod(stamp_ns, 1_000_000_000)
    return float(sec) + (rem + t_ns.astype(np.float64)) / 1e9


def _cloud(types: dict[str, Any], ros1: bool, layout: str, scan: Scan, order: str) -> tuple[Any, int]:
    """The scan as one PointCloud2 layout; returns the message and its header stamp."""
    fields, step = FIELDS[layout]
    dtype = np.dtype({"names": [f[0] for f in fields], "formats": ["<" + f[2] for f in fields],
                      "offsets": [f[1] for f in fields], "itemsize": step})
    def take(a: np.ndarray[Any, Any]) -> np.ndarray[Any, Any]:
        # Firing order: column by column, the rings within a column.
        return np.swapaxes(a, 0, 1) if order == "columns" else a

    xyz, inten, ring = take(scan.xyz), take(scan.intensity), take(scan.ring)
    t_ns, valid = take(scan.t_ns), take(scan.valid)
    organised = layout in ("robosense", "notime", "ouster")
    if organised:
        grid = np.zeros(valid.shape, dtype)
        sel: Any = Ellipsis  # every point, in its place
    else:
        grid = np.zeros(int(valid.sum()), dtype)
        sel = valid
    stamp = scan.stamp_ns
    t_last = int(scan.t_ns.max())
    if layout in ("velodyne", "robosense"):
        stamp = scan.stamp_ns + t_last  # the last firing's time: the sweep's end
    grid["x"], grid["y"], grid["z"] = xyz[..., 0][sel], xyz[..., 1][sel], xyz[..., 2][sel]
    grid["intensity"] = inten[sel]
    if "ring" in (grid.dtype.names or ()):
        grid["ring"] = ring[sel]
    if layout == "livox":
        grid["line"] = ring[sel].astype(np.uint8)
        grid["timestamp"] = (scan.stamp_ns + t_ns[sel]).astype(np.float64)  # epoch ns in a double
    elif layout == "ouster":
        grid["t"] = t_ns[sel].astype(np.uint32)
    elif layout == "velodyne":
        grid["time"] = ((t_ns[sel] - t_last) / 1e9).astype(np.float32)
    elif layout in ("hesai", "robosense"):
        grid["timestamp"] = _epoch_s(scan.stamp_ns, t_ns[sel])
    if organised:
        rows, cols = grid.shape
    else:
        rows, cols = 1, len(grid)
    point_fields = [types["sensor_msgs/msg/PointField"](name=n, offset=o, datatype=_DATATYPE[f], count=1)
                    for n, o, f in fields]
    msg = types[CLOUD](
        header=_header(types, ros1, stamp, scan.frame), height=rows, width=cols,
        fields=point_fields, is_bigendian=False, point_step=step, row_step=step * cols,
        data=np.frombuffer(grid.tobytes(), np.uint8), is_dense=not organised)
    return msg, stamp


def custom_points(scan: Scan) -> np.ndarray[Any, Any]:
    """The scan's returns in firing order as CustomPoint records (unpadded)."""
    valid = np.swapaxes(scan.valid, 0, 1)
    dtype = np.dtype({"names": ["offset_time", "x", "y", "z", "reflectivity", "tag", "line"],
                      "formats": ["<u4", "<f4", "<f4", "<f4", "u1", "u1", "u1"],
                      "offsets": [0, 4, 8, 12, 16, 17, 18], "itemsize": 19})
    xyz = np.swapaxes(scan.xyz, 0, 1)[valid]
    out = np.zeros(len(xyz), dtype)
    out["offset_time"] = np.swapaxes(scan.t_ns, 0, 1)[valid]
    out["x"], out["y"], out["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    out["reflectivity"] = np.clip(np.swapaxes(scan.intensity, 0, 1)[valid], 0, 255)
    out["line"] = np.swapaxes(scan.ring, 0, 1)[valid]
    return out


def custom_bytes(store: Any, ros1: bool, stamp_ns: int, frame: str, points: np.ndarray[Any, Any]) -> bytes:
    """A serialised livox_ros_driver2/msg/CustomMsg: rosbags serialises everything up to the
    point sequence (of an empty message), the points are appended as numpy records at the
    layout the wire wants (CDR: each point padded to 20 bytes, but the last; ROS 1: packed).
    The same bytes as rosbags' serialiser gives for the whole message, hundreds of times faster
    than building a message object per point."""
    types = store.types
    empty = types[CUSTOM](header=_header(types, ros1, stamp_ns, frame), timebase=stamp_ns,
                          point_num=len(points), lidar_id=0, rsvd=np.zeros(3, np.uint8), points=[])
    head = bytearray(store.serialize_ros1(empty, CUSTOM) if ros1 else store.serialize_cdr(empty, CUSTOM))
    head[-4:] = len(points).to_bytes(4, "little")
    if ros1 or len(points) == 0:
        return bytes(head) + points.tobytes()
    padded = np.zeros(len(points), np.dtype({"names": list(points.dtype.names or ()),
                                             "formats": [points.dtype.fields[n][0] for n in points.dtype.names or ()],
                                             "offsets": [points.dtype.fields[n][1] for n in points.dtype.names or ()],
                                             "itemsize": 20}))
    for name in points.dtype.names or ():
        padded[name] = points[name]
    return bytes(head) + padded.tobytes()[:-1]


@dataclass(frozen=True)
class Ring:
    """The ring a 2D scan is cut from, and its columns' azimuths: az(c) = start + c * step."""

    index: int
    start_rad: float
    step_rad: float
    increment_s: float


def _ring_of(scan: Scan) -> Ring:
    xyz, valid = scan.xyz, scan.valid
    elevation = np.full(valid.shape[0], np.inf)
    for r in range(valid.shape[0]):
        p = xyz[r][valid[r]]
        if len(p) > 10:
            elevation[r] = abs(float(np.median(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))))
    r = int(np.argmin(elevation))
    cols = np.flatnonzero(valid[r])
    az = np.arctan2(xyz[r, cols, 1], xyz[r, cols, 0]).astype(np.float64)
    width = valid.shape[1]
    steps = np.mod(np.diff(az) / np.diff(cols) + math.pi, 2 * math.pi) - math.pi
    step = math.copysign(2 * math.pi / width, float(np.median(steps)))
    start = az - cols * step
    start_rad = math.atan2(float(np.sin(start).mean()), float(np.cos(start).mean()))
    dt = np.diff(scan.t_ns[r].astype(np.float64))
    return Ring(r, start_rad, step, float(np.median(dt)) / 1e9)


def _laser(types: dict[str, Any], ros1: bool, scan: Scan, ring: Ring, rplidar: bool) -> tuple[Any, int]:
    r = ring.index
    ranges = np.where(scan.valid[r], np.hypot(scan.xyz[r, :, 0], scan.xyz[r, :, 1]), np.inf).astype(np.float32)
    inten = np.where(scan.valid[r], scan.intensity[r], 0.0).astype(np.float32)
    width = len(ranges)
    start, step = ring.start_rad, ring.step_rad
    if rplidar:
        # rplidar_ros: a clockwise sweep's ranges reversed into counter-clockwise order, the
        # beam times (time_increment > 0) left as they were: they now run against the sweep.
        ranges, inten = ranges[::-1].copy(), inten[::-1].copy()
        start, step = start + (width - 1) * step, -step
    msg = types[SCAN](
        header=_header(types, ros1, scan.stamp_ns, scan.frame), angle_min=start,
        angle_max=start + (width - 1) * step, angle_increment=step,
        time_increment=ring.increment_s, scan_time=ring.increment_s * width, range_min=0.1,
        range_max=120.0, ranges=ranges, intensities=inten)
    return msg, scan.stamp_ns


# ----- reading the source scans ------------------------------------------------------------


class _Source:
    """Decodes the source lidar's organised scans with the time reading mfmap decides."""

    def __init__(self, path: Path, opts: Options) -> None:
        with open_log(path, IngestConfig(assume_identity_extrinsics=True)) as src:
            if Role.LIDAR not in src.roles:
                raise RelayoutError("the log has no PointCloud2 lidar to rewrite", path)
            self.topic = src.roles[Role.LIDAR]
            timing = src.lidar_timing()
            if not isinstance(timing, TimeSpec):
                raise RelayoutError("the lidar has no per-point time to rewrite from", path)
            self.timing = timing
            self.tf_static = src.roles.get(Role.TF_STATIC)
            self.imu_topic = src.roles.get(Role.IMU)
            self.baro_topic = src.roles.get(Role.BARO)
            self.lidar_frame = (src._first_frame(Role.LIDAR) or "").lstrip("/")
            self.imu_frame = (src._first_frame(Role.IMU) or "").lstrip("/")
        self.rotation = _rotation(opts.mount) if opts.mount else None
        self.path = path

    def scan(self, data: Any, encoding: str) -> Scan:
        msg = parse_pointcloud2(data, encoding)
        if msg.height < 2:
            raise RelayoutError("the lidar's clouds are not organised (rings x columns)", self.path)
        layout = cloud_layout(list(msg.fields), msg.height, msg.width, msg.point_step,
                              msg.row_step, msg.is_bigendian, len(msg.data), str(self.path),
                              time_fields=(self.timing.field,))
        arr = np.ndarray((msg.height, msg.width), layout.dtype, msg.data, 0,
                         (msg.row_step, msg.point_step))
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        xyz = np.stack([arr["x"], arr["y"], arr["z"]], axis=-1).astype(np.float32)
        valid = np.isfinite(xyz).all(axis=-1) & (np.abs(xyz).sum(axis=-1) > 0)
        if self.rotation is not None:
            # Exact: a half or quarter turn only swaps and negates coordinates.
            xyz = (xyz @ self.rotation).astype(np.float32)
        t_ns = self.timing.offsets_ns(arr[self.timing.field].reshape(-1), stamp).reshape(arr.shape)
        inten = arr["intensity"].astype(np.float32) if layout.has_intensity else np.zeros(arr.shape, np.float32)
        ring = (arr["ring"].astype(np.uint16) if layout.has_ring
                else np.repeat(np.arange(msg.height, dtype=np.uint16)[:, None], msg.width, 1))
        xyz[~valid] = np.nan
        return Scan(stamp, msg.header.frame_id, xyz, inten, ring, t_ns, valid)


# ----- containers: read and write the same kind ----------------------------------------------


@dataclass(frozen=True)
class Topic:
    name: str
    msgtype: str
    encoding: str  # "cdr" | "ros1"
    definition: str  # message definition text ("" when the source had none)
    digest: str = ""
    extra: Any = None  # container-specific connection details
    store: Any = None  # the typestore that serialises a rewritten topic (bags: its definition)


class _Writer:
    def __init__(self, kind: str, out: Path, storage: str = "sqlite3") -> None:
        self.kind = kind
        self.ids: dict[str, Any] = {}
        if kind == "mcap":
            from mcap.writer import CompressionType, Writer

            self._file = out.open("wb")
            self._w: Any = Writer(self._file, chunk_size=4 << 20, compression=CompressionType.LZ4)
            self._w.start(profile="ros2", library="mfmap-relayout")
        elif kind == "ros1":
            from rosbags.rosbag1 import Writer as Writer1

            self._w = Writer1(out)
            self._w.set_compression(Writer1.CompressionFormat.LZ4)
            self._w.open()
        else:
            from rosbags.rosbag2 import StoragePlugin
            from rosbags.rosbag2 import Writer as Writer2

            plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
            self._w = Writer2(out, version=9, storage_plugin=plugin)
            self._w.open()

    def add(self, topic: Topic) -> None:
        if self.kind == "mcap":
            schema, channel = topic.extra if topic.extra is not None else (None, None)
            name = schema.name if schema is not None else topic.msgtype
            enc = schema.encoding if schema is not None else ("ros1msg" if topic.encoding == "ros1" else "ros2msg")
            data = schema.data if schema is not None else topic.definition.encode()
            sid = self._w.register_schema(name=name, encoding=enc, data=data)
            meta = dict(channel.metadata) if channel is not None else {}
            self.ids[topic.name] = self._w.register_channel(
                topic=topic.name, message_encoding=topic.encoding, schema_id=sid, metadata=meta)
        elif self.kind == "ros1":
            ext = topic.extra
            if topic.store is not None:
                self.ids[topic.name] = self._w.add_connection(
                    topic.name, topic.msgtype, typestore=topic.store,
                    latching=getattr(ext, "latching", None))
            else:
                self.ids[topic.name] = self._w.add_connection(
                    topic.name, topic.msgtype, msgdef=topic.definition, md5sum=topic.digest or None,
                    callerid=getattr(ext, "callerid", None), latching=getattr(ext, "latching", None))
        else:
            qos = getattr(topic.extra, "offered_qos_profiles", []) if topic.extra is not None else []
            if topic.store is not None:
                self.ids[topic.name] = self._w.add_connection(
                    topic.name, topic.msgtype, typestore=topic.store, offered_qos_profiles=qos)
            elif topic.definition:
                self.ids[topic.name] = self._w.add_connection(
                    topic.name, topic.msgtype, msgdef=topic.definition, rihs01=topic.digest,
                    offered_qos_profiles=qos)
            else:  # a bag written before message definitions were stored
                self.ids[topic.name] = self._w.add_connection(
                    topic.name, topic.msgtype, typestore=get_typestore(Stores.LATEST),
                    offered_qos_profiles=qos)

    def write(self, topic: str, log_time_ns: int, data: bytes | memoryview) -> None:
        if self.kind == "mcap":
            self._w.add_message(self.ids[topic], log_time=log_time_ns, data=bytes(data),
                                publish_time=log_time_ns)
        else:
            self._w.write(self.ids[topic], log_time_ns, bytes(data))

    def close(self) -> None:
        if self.kind == "mcap":
            self._w.finish()
            self._file.close()
        else:
            self._w.close()


def _kind(path: Path) -> tuple[str, str]:
    if path.is_dir():
        meta = (path / "metadata.yaml").read_text() if (path / "metadata.yaml").is_file() else ""
        return "ros2", "mcap" if "storage_identifier: mcap" in meta else "sqlite3"
    with path.open("rb") as f:
        head = f.read(16)
    if head.startswith(b"\x89MCAP"):
        return "mcap", ""
    if head.startswith(b"#ROSBAG V2.0"):
        return "ros1", ""
    raise RelayoutError("not an MCAP file, a ROS 1 bag or a ROS 2 bag folder", path)


def _read(path: Path, kind: str) -> tuple[list[Topic], Iterator[tuple[str, int, Any]]]:
    """The source's topics and its messages (topic, log time, serialised bytes) in log order."""
    if kind == "mcap":
        from mcap.reader import make_reader

        f = path.open("rb")
        reader = make_reader(f)
        summary = reader.get_summary()
        if summary is None:
            raise RelayoutError("the MCAP file has no summary", path)
        topics = []
        for ch in summary.channels.values():
            schema = summary.schemas.get(ch.schema_id)
            name = schema.name if schema is not None else ""
            msgtype = name if "/msg/" in name else name.replace("/", "/msg/", 1)
            topics.append(Topic(ch.topic, msgtype, ch.message_encoding,
                                schema.data.decode() if schema is not None else "", "", (schema, ch)))

        def mcap_messages() -> Iterator[tuple[str, int, Any]]:
            try:
                for _s, ch, m in reader.iter_messages(log_time_order=True):
                    yield ch.topic, m.log_time, m.data
            finally:
                f.close()

        return topics, mcap_messages()
    if kind == "ros1":
        from rosbags.rosbag1 import Reader as Reader1

        r1 = Reader1(path)
        r1.open()
        topics = [Topic(c.topic, c.msgtype, "ros1", c.msgdef.data, c.digest, c.ext) for c in r1.connections]

        def ros1_messages() -> Iterator[tuple[str, int, Any]]:
            try:
                for c, t, raw in r1.messages():
                    yield c.topic, t, raw
            finally:
                r1.close()

        return topics, ros1_messages()
    from rosbags.rosbag2 import Reader as Reader2

    r2 = Reader2(path)
    r2.open()
    topics = [Topic(c.topic, c.msgtype, "cdr", c.msgdef.data, c.digest, c.ext) for c in r2.connections]

    def ros2_messages() -> Iterator[tuple[str, int, Any]]:
        try:
            for c, t, raw in r2.messages():
                yield c.topic, t, raw
        finally:
            r2.close()

    return topics, ros2_messages()


# ----- the rewrite ---------------------------------------------------------------------------


def _typestore(ros1: bool) -> Any:
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if TF not in store.fielddefs:
        store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TF))
    store.register(get_types_from_msg(CUSTOM_POINT_DEF, "livox_ros_driver2/msg/CustomPoint"))
    store.register(get_types_from_msg(CUSTOM_MSG_DEF.replace(
        "std_msgs/Header", "Header" if ros1 else "std_msgs/Header"), CUSTOM))
    return store


def _definition(store: Any, msgtype: str, ros1: bool) -> tuple[str, str]:
    text, digest = store.generate_msgdef(msgtype, ros_version=1 if ros1 else 2)
    return text, digest


@dataclass
class Result:
    out: Path
    scans: int
    layout: str
    copied: int


def relayout(path: Path | str, out: Path | str, opts: Options) -> Result:
    """Write `path` with its lidar in `opts.layout` to `out` (the same kind of container)."""
    path, out = Path(path), Path(out)
    if opts.layout not in LAYOUTS:
        raise RelayoutError(f"unknown layout '{opts.layout}' (known: {', '.join(LAYOUTS)})")
    if out.exists():
        raise RelayoutError("exists already", out)
    kind, storage = _kind(path)
    source = _Source(path, opts)
    partial = out.with_name(out.name + ".partial")
    if partial.is_dir():
        shutil.rmtree(partial)
    elif partial.exists():
        partial.unlink()
    result = _rewrite(path, partial, kind, storage, source, opts)
    partial.rename(out)
    return Result(out, result.scans, result.layout, result.copied)


def _rewrite(path: Path, out: Path, kind: str, storage: str, source: _Source, opts: Options) -> Result:
    topics, messages = _read(path, kind)
    by_name = {t.name: t for t in topics}
    lidar = by_name[source.topic]
    ros1 = lidar.encoding == "ros1"
    store = _typestore(ros1)
    types = store.types
    writer = _Writer(kind, out, storage)
    new_type = {"scan2d": SCAN, "scan2d-rplidar": SCAN, "livox-custom": CUSTOM}.get(opts.layout, CLOUD)
    lidar_out = "/scan" if new_type == SCAN else source.topic
    replaced = {source.topic}
    rewritten = {t for t in (source.tf_static, source.imu_topic, source.baro_topic) if t is not None}
    def new(name: str, msgtype: str, extra: Any = None) -> Topic:
        text, digest = _definition(store, msgtype, ros1)
        return Topic(name, msgtype, lidar.encoding, text, digest, extra, store)

    for t in topics:
        if t.name in replaced:
            writer.add(new(lidar_out, new_type))
        elif t.name == source.tf_static and opts.tf_on_tf:
            writer.add(new("/tf", TF))
        elif t.name in rewritten and t.encoding == lidar.encoding:
            writer.add(new(t.name, t.msgtype, None if kind == "mcap" else t.extra))
        else:
            writer.add(t)
    if opts.temperature_topic and source.baro_topic is not None:
        writer.add(new("/baro/temperature", TEMPERATURE))
    scans = copied = 0
    ring: Ring | None = None
    transforms: list[Any] = []
    last_tf_ns: int | None = None
    imu_rot = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # x<->y, z down

    def ser(msg: Any, msgtype: str) -> bytes:
        return bytes(store.serialize_ros1(msg, msgtype) if ros1 else store.serialize_cdr(msg, msgtype))

    def des(data: Any, msgtype: str) -> Any:
        return store.deserialize_ros1(data, msgtype) if ros1 else store.deserialize_cdr(data, msgtype)

    try:
        for topic, log_time, data in messages:
            if topic == source.topic:
                scan = source.scan(data, "ros1" if ros1 else "cdr")
                if opts.layout in ("scan2d", "scan2d-rplidar"):
                    ring = ring or _ring_of(scan)
                    msg, stamp = _laser(types, ros1, scan, ring, opts.layout == "scan2d-rplidar")
                elif opts.layout == "livox-custom":
                    msg, stamp = None, scan.stamp_ns
                else:
                    order = "rows" if opts.layout in ("ouster", "notime") else "columns"
                    msg, stamp = _cloud(types, ros1, opts.layout, scan, order)
                bytes_out = (custom_bytes(store, ros1, stamp, scan.frame, custom_points(scan))
                             if msg is None else ser(msg, new_type))
                # The recorder logs it as long after its (new) stamp as it did the original.
                writer.write(lidar_out, log_time + stamp - scan.stamp_ns, bytes_out)
                scans += 1
            elif topic == source.tf_static:
                tf = des(data, TF)
                kept = []
                for x in tf.transforms:
                    child = str(x.child_frame_id).lstrip("/")
                    if opts.mount is not None and child == source.lidar_frame:
                        x = _turned(types, x, _rotation(opts.mount))
                    if opts.imu_rotated and child == source.imu_frame:
                        x = _turned(types, x, imu_rot)
                    if opts.drop_transform and child == source.lidar_frame:
                        continue
                    kept.append(x)
                tf = types[TF](transforms=kept)
                transforms = kept
                if opts.tf_on_tf:
                    last_tf_ns = log_time
                    writer.write("/tf", log_time, ser(tf, TF))
                else:
                    writer.write(topic, log_time, ser(tf, TF))
            elif topic == source.imu_topic and (opts.imu_rotated or opts.imu_no_orientation):
                writer.write(topic, log_time, ser(_imu(types, des(data, IMU), opts, imu_rot), IMU))
            elif topic == source.baro_topic and (opts.baro_unit != "Pa" or opts.temperature_topic):
                msg = des(data, PRESSURE)
                if opts.temperature_topic:
                    temp = types[TEMPERATURE](header=msg.header, temperature=21.5, variance=0.01)
                    writer.write("/baro/temperature", log_time, ser(temp, TEMPERATURE))
                scale = {"Pa": 1.0, "hPa": 0.01, "kPa": 0.001}[opts.baro_unit]
                msg.fluid_pressure *= scale
                msg.variance *= scale * scale
                writer.write(topic, log_time, ser(msg, PRESSURE))
            else:
                writer.write(topic, log_time, data)
                copied += 1
            if opts.tf_on_tf and transforms and last_tf_ns is not None and log_time - last_tf_ns >= 100_000_000:
                # A ROS 1 static_transform_publisher on /tf: the same transforms at 10 Hz.
                last_tf_ns = log_time
                writer.write("/tf", log_time, ser(types[TF](transforms=transforms), TF))
    finally:
        writer.close()
    return Result(out, scans, opts.layout, copied)


def _turned(types: dict[str, Any], x: Any, rotation: np.ndarray[Any, Any]) -> Any:
    """The transform of a frame turned by `rotation` in itself (its mount turned)."""
    from scipy.spatial.transform import Rotation

    r = x.transform.rotation
    m = quat_to_matrix(float(r.x), float(r.y), float(r.z), float(r.w)) @ rotation
    q = Rotation.from_matrix(m).as_quat()
    quat = types["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))
    x.transform.rotation = quat
    return x


def _imu(types: dict[str, Any], msg: Any, opts: Options, rotation: np.ndarray[Any, Any]) -> Any:
    if opts.imu_rotated:
        from scipy.spatial.transform import Rotation

        g, a = msg.angular_velocity, msg.linear_acceleration
        gn = rotation.T @ np.array([g.x, g.y, g.z])
        an = rotation.T @ np.array([a.x, a.y, a.z])
        vec = types["geometry_msgs/msg/Vector3"]
        msg.angular_velocity = vec(x=float(gn[0]), y=float(gn[1]), z=float(gn[2]))
        msg.linear_acceleration = vec(x=float(an[0]), y=float(an[1]), z=float(an[2]))
        q = msg.orientation
        m = quat_to_matrix(float(q.x), float(q.y), float(q.z), float(q.w)) @ rotation
        qn = Rotation.from_matrix(m).as_quat()
        msg.orientation = types["geometry_msgs/msg/Quaternion"](
            x=float(qn[0]), y=float(qn[1]), z=float(qn[2]), w=float(qn[3]))
    if opts.imu_no_orientation:
        cov = np.zeros(9)
        cov[0] = -1.0
        msg.orientation_covariance = cov
        msg.orientation = types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=0.0)
    return msg


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("log", type=Path)
    parser.add_argument("--as", dest="layout", required=True, choices=LAYOUTS)
    parser.add_argument("-o", "--out", type=Path, required=True)
    parser.add_argument("--drop-transform", action="store_true",
                        help="leave the lidar's transform out of /tf_static")
    parser.add_argument("--tf-on-tf", action="store_true",
                        help="publish the static transforms on /tf at 10 Hz (ROS 1 style), no /tf_static")
    parser.add_argument("--mount", choices=MOUNTS, help="turn the lidar's mount (and its transform)")
    parser.add_argument("--imu-no-orientation", action="store_true",
                        help="IMU without orientation (orientation_covariance[0] = -1)")
    parser.add_argument("--imu-rotated", action="store_true",
                        help="IMU mounted upside down with x and y swapped (and its transform)")
    parser.add_argument("--baro-unit", choices=("Pa", "hPa", "kPa"), default="Pa",
                        help="publish the pressure in this unit (FluidPressure wants Pa)")
    parser.add_argument("--temperature-topic", action="store_true",
                        help="also publish the barometer's temperature on its own topic")
    args = parser.parse_args(argv)
    try:
        result = relayout(args.log, args.out, Options(
            args.layout, args.drop_transform, args.tf_on_tf, args.mount, args.imu_no_orientation,
            args.imu_rotated, args.baro_unit, args.temperature_topic))
    except MfmapError as err:
        print(f"relayout: error: {err}", file=sys.stderr)
        return 1
    print(f"{result.out}: {result.scans} scans as {result.layout}, {result.copied} messages copied")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
