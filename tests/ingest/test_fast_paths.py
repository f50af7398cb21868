"""The fast read paths give exactly what the general ones give.

- The direct PointCloud2 parser (with its per-sensor layout cache) against rosbags' generic
  deserialiser and against a plain numpy reading of the same bytes, over real sensor layouts.
- The zero-copy indexed MCAP reader against mcap's own SeekingReader, and the zero-copy ROS 1
  reader against rosbags' Reader: same messages, same bytes, same order, for every compression
  and for time windows.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from fractions import Fraction
from pathlib import Path
from typing import Any

import ingest_logwriter as lw
import numpy as np
import pytest
from mcap.reader import SeekingReader

from mfmap.errors import DecodeError
from mfmap.ingest import open_log
from mfmap.ingest.config import IngestConfig
from mfmap.ingest.decode import POINTFIELD_DTYPES, decode_pointcloud2
from mfmap.ingest.lidartime import TimeSpec
from mfmap.ingest.mcap_backend import McapBackend
from mfmap.ingest.wire import parse_pointcloud2

STAMP_NS = 1_700_000_000_250_000_000
DATATYPE = {code: dt for dt, code in POINTFIELD_DTYPES.items()}

# name -> (fields as (name, offset, numpy type, count), point_step, row padding bytes)
LAYOUTS: dict[str, tuple[list[tuple[str, int, str, int]], int, int]] = {
    # Ouster: t is uint32 ns since the stamp; 48-byte points with unused fields and padding.
    "ouster": ([("x", 0, "f4", 1), ("y", 4, "f4", 1), ("z", 8, "f4", 1), ("intensity", 16, "f4", 1),
                ("t", 20, "u4", 1), ("reflectivity", 24, "u2", 1), ("ring", 26, "u2", 1),
                ("ambient", 28, "u2", 1), ("range", 32, "u4", 1)], 48, 0),
    # Velodyne: packed 22-byte points (time unaligned), time is float32 seconds relative.
    "velodyne": ([("x", 0, "f4", 1), ("y", 4, "f4", 1), ("z", 8, "f4", 1), ("intensity", 12, "f4", 1),
                  ("ring", 16, "u2", 1), ("time", 18, "f4", 1)], 22, 0),
    # Hesai-like: float64 xyz in scrambled order, absolute float64 timestamp, padded rows.
    "padded-f64": ([("timestamp", 0, "f8", 1), ("z", 8, "f8", 1), ("ring", 18, "u2", 1),
                    ("x", 24, "f8", 1), ("y", 40, "f8", 1)], 56, 12),
    # x declared as a float32[3] vector holding x, y, z; y and z fields alias it.
    "count-3": ([("x", 0, "f4", 3), ("y", 4, "f4", 1), ("z", 8, "f4", 1), ("intensity", 12, "u1", 1)], 16, 0),
}
HEIGHT, WIDTH = 4, 16
# How each layout's time field reads (as the source decides from the values).
TIMING: dict[str, TimeSpec | None] = {
    "ouster": TimeSpec("t", "uint32", "ns", "relative", 0, "start", "test", 100.0),
    "velodyne": TimeSpec("time", "float32", "s", "relative", 0, "end", "test", 100.0),
    "padded-f64": TimeSpec("timestamp", "float64", "s", "absolute", 0, "start", "test", 100.0),
    "count-3": None,
}


def _points(name: str, big_endian: bool, seed: int) -> tuple[bytes, np.ndarray[Any, Any], int]:
    """Serialised point bytes, the structured array they hold, and the row step."""
    fields, step, pad = LAYOUTS[name]
    order = ">" if big_endian else "<"
    dt = np.dtype({"names": [f[0] for f in fields if f[3] == 1 or f[0] == "x"],
                   "formats": [order + f[2] for f in fields if f[3] == 1 or f[0] == "x"],
                   "offsets": [f[1] for f in fields if f[3] == 1 or f[0] == "x"], "itemsize": step})
    rng = np.random.default_rng(seed)
    arr = np.zeros((HEIGHT, WIDTH), dt)
    for f in fields:
        if f[0] in ("x", "y", "z"):
            arr[f[0]] = rng.uniform(-30, 30, arr.shape)
        elif f[0] == "t":
            arr[f[0]] = rng.integers(0, 100_000_000, arr.shape)
        elif f[0] == "time":
            arr[f[0]] = rng.uniform(-0.1, 0.0, arr.shape)
        elif f[0] == "timestamp":
            arr[f[0]] = STAMP_NS / 1e9 + rng.uniform(0, 0.1, arr.shape)
        else:
            arr[f[0]] = rng.integers(0, 200, arr.shape)
    flat = arr.reshape(-1)
    flat["x"][[1, 7, 30]] = np.nan  # no-returns
    flat["y"][[9]] = np.inf
    for c in ("x", "y", "z"):
        flat[c][[3, 40]] = 0.0  # Ouster-style no-returns at the origin
    row_step = step * WIDTH + pad
    rows = [arr[r].tobytes() + bytes(range(pad)) for r in range(HEIGHT)]
    return b"".join(rows), flat, row_step


def _message(store: Any, name: str, big_endian: bool, seed: int) -> tuple[Any, np.ndarray[Any, Any]]:
    fields, step, _pad = LAYOUTS[name]
    data, arr, row_step = _points(name, big_endian, seed)
    T = store.types
    point_fields = [T["sensor_msgs/msg/PointField"](name=n, offset=o, datatype=DATATYPE[t], count=c)
                    for n, o, t, c in fields]
    header = lw._header(store, STAMP_NS, "lidar")
    msg = T["sensor_msgs/msg/PointCloud2"](
        header=header, height=HEIGHT, width=WIDTH, fields=point_fields, is_bigendian=big_endian,
        point_step=step, row_step=row_step, data=np.frombuffer(data, np.uint8), is_dense=False,
    )
    return msg, arr


def _expected(arr: np.ndarray[Any, Any]) -> dict[str, np.ndarray[Any, Any]]:
    """What the decoder must return, computed field by field with plain numpy."""
    x, y, z = (arr[c].astype(np.float64) for c in ("x", "y", "z"))
    keep = np.isfinite(x) & np.isfinite(y) & np.isfinite(z) & ~((x == 0) & (y == 0) & (z == 0))
    out = {"xyz": np.stack([arr["x"], arr["y"], arr["z"]], axis=1)[keep].astype(np.float32)}
    names = arr.dtype.names or ()
    if "intensity" in names:
        out["intensity"] = arr["intensity"][keep].astype(np.float32)
    if "ring" in names:
        out["ring"] = arr["ring"][keep].astype(np.uint16)
    if "t" in names:
        out["t"] = arr["t"][keep].astype(np.int64)
    if "time" in names:
        out["t"] = np.round(arr["time"][keep].astype(np.float64) * 1e9).astype(np.int64)
    if "timestamp" in names:
        # The value the float64 holds, exactly, less the stamp: to the nanosecond.
        out["t"] = np.array([round(Fraction(float(v)) * 10**9) - STAMP_NS
                             for v in arr["timestamp"][keep]], dtype=np.int64)
    return out


def _same(cloud: Any, expected: dict[str, np.ndarray[Any, Any]]) -> None:
    assert cloud.xyz.dtype == np.float32 and cloud.xyz.flags.c_contiguous
    np.testing.assert_array_equal(cloud.xyz, expected["xyz"])
    for key, got in (("intensity", cloud.intensity), ("ring", cloud.ring), ("t", cloud.t_offset_ns)):
        if key in expected:
            assert got is not None and got.dtype == expected[key].dtype
            np.testing.assert_array_equal(got, expected[key])
        else:
            assert got is None


WIRES = ["cdr-le", "cdr-be", "ros1"]


@pytest.mark.parametrize("wire", WIRES)
@pytest.mark.parametrize("big_endian", [False, True], ids=["le-points", "be-points"])
@pytest.mark.parametrize("layout", sorted(LAYOUTS))
def test_direct_parser_equals_general_path(layout: str, big_endian: bool, wire: str) -> None:
    ros1 = wire == "ros1"
    store = lw.typestore(ros1)
    encoding = "ros1" if ros1 else "cdr"
    for seed in range(3):  # the first scan fills the layout cache, the next ones hit it
        msg, arr = _message(store, layout, big_endian, seed)
        if ros1:
            data = bytes(store.serialize_ros1(msg, "sensor_msgs/msg/PointCloud2"))
            general = store.deserialize_ros1(data, "sensor_msgs/msg/PointCloud2")
        else:
            data = bytes(store.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2", little_endian=wire == "cdr-le"))
            general = store.deserialize_cdr(data, "sensor_msgs/msg/PointCloud2")
        fast = decode_pointcloud2(parse_pointcloud2(data, encoding), STAMP_NS, timing=TIMING[layout])
        slow = decode_pointcloud2(general, STAMP_NS, timing=TIMING[layout])
        expected = _expected(arr)
        assert expected["xyz"].shape == (HEIGHT * WIDTH - 6, 3)
        _same(fast, expected)
        _same(slow, expected)
        assert fast.frame_id == slow.frame_id == "lidar"


def test_layout_cache_never_mixes_sensors() -> None:
    """Scans of two sensors interleaved: every scan decoded with its own layout."""
    store = lw.typestore(False)
    names = [name for _ in range(3) for name in ("ouster", "velodyne", "count-3")]
    msgs = [_message(store, name, False, seed) for seed in range(3) for name in ("ouster", "velodyne", "count-3")]
    for name, (msg, arr) in zip(names, msgs, strict=True):
        data = bytes(store.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2"))
        _same(decode_pointcloud2(parse_pointcloud2(data, "cdr"), STAMP_NS, timing=TIMING[name]),
              _expected(arr))
    # A scan whose layout block is cached but whose data is short is still a DecodeError.
    msg, _arr = msgs[0]
    data = bytes(store.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2"))
    parse_pointcloud2(data, "cdr")
    with pytest.raises(DecodeError, match="truncated or corrupt PointCloud2"):
        parse_pointcloud2(data[: len(data) // 2], "cdr", where="x")


def _shuffled_log(tmp_path: Path, compression: str) -> Path:
    """The standard log with jittered log times (out of order across topics), small chunks."""
    from mcap.writer import CompressionType

    store = lw.typestore(False)
    rnd = random.Random(3)
    # Up to 150 ms of jitter: chunks overlap in time, as with a recorder's per-topic queues.
    jittered = [(topic, msgtype, t + rnd.randrange(0, 150_000_000), msg)
                for topic, msgtype, t, msg in lw.messages(store)]
    # Two messages at the same log time in different chunks: order by chunk, then position.
    jittered.append(("/baro/pressure", "sensor_msgs/msg/FluidPressure", jittered[5][2],
                     lw.pressure_msg(store, lw.T0_NS, 99_000.0)))
    comp = {"none": CompressionType.NONE, "zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4}[compression]
    return lw.write_mcap_items(tmp_path / f"{compression}.mcap", jittered, store, chunk_size=3000,
                               compression=comp)


@pytest.mark.parametrize("compression", ["none", "zstd", "lz4"])
def test_indexed_reader_equals_mcap_seeking_reader(tmp_path: Path, compression: str) -> None:
    path = _shuffled_log(tmp_path, compression)
    backend = McapBackend([path])
    assert backend.files[0].indexed and len(backend.files[0].chunk_indexes) > 5
    all_topics = sorted(lw.EXPECTED.counts)
    windows = [(None, None), (lw.T0_NS + 200_000_000, lw.T0_NS + 700_000_000), (None, lw.T0_NS + 300_000_000)]
    for topics in (all_topics, ["/lidar/points"], ["/baro/pressure", "/imu/data"]):
        for start, end in windows:
            ours = [(m.topic, m.log_time_ns, bytes(m.payload[2]))
                    for m in backend.iter_raw(topics, start, end)]
            with path.open("rb") as f:
                theirs = [(c.topic, m.log_time, bytes(m.data)) for _s, c, m in SeekingReader(f).iter_messages(
                    topics=topics, starting_at=start, ending_at=end, log_time_order=True)]
            assert ours == theirs
            assert ours  # every window holds messages
    assert sum(1 for _ in backend.iter_raw(all_topics, None, None)) == sum(lw.EXPECTED.counts.values()) + 1


@pytest.mark.parametrize("compression", ["none", "bz2", "lz4"])
def test_ros1_reader_equals_rosbags(written_log: Callable[[str], Path], compression: str) -> None:
    from rosbags.rosbag1 import Reader

    from mfmap.ingest.bag_backend import RosbagsBackend

    path = written_log(f"ros1-{compression}")
    backend = RosbagsBackend(path, "ros1")
    try:
        windows = [(None, None), (lw.T0_NS + 200_000_000, lw.T0_NS + 700_000_000)]
        for topics in (sorted(lw.EXPECTED.counts), ["/lidar/points"], ["/imu/data", "/odom"]):
            for start, end in windows:
                ours = [(m.topic, m.log_time_ns, bytes(m.payload[1])) for m in backend.iter_raw(topics, start, end)]
                with Reader(path) as reader:
                    conns = [c for c in reader.connections if c.topic in topics]
                    stop = None if end is None else end + 1
                    theirs = [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages(conns, start, stop)]
                assert ours == theirs and ours
    finally:
        backend.close()


def _small_rows(path: Path, direct: bool, monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    import mfmap.ingest.series as series

    with monkeypatch.context() as m:
        if not direct:
            m.setattr(series, "_FLAT", {})
        with open_log(path, IngestConfig()) as src:
            rows = src._series.read()
            return {role.name: (r.stamps, r.values, r.frame, r.child) for role, r in rows.items()}


@pytest.mark.parametrize("fmt", lw.FORMATS)
def test_direct_small_message_parser_equals_generic(
    written_log: Callable[[str], Path], fmt: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Barometer, IMU and odometry read by the direct parser: every stamp, value and frame the
    generic deserialiser gives, in every format and encoding the writers produce."""
    import mfmap.ingest.series as series

    path = written_log(fmt)
    calls = 0
    parse = series.parse_stamped_doubles

    def counting(*args: Any) -> Any:
        nonlocal calls
        calls += 1
        return parse(*args)

    monkeypatch.setattr(series, "parse_stamped_doubles", counting)
    direct = _small_rows(path, True, monkeypatch)
    # Every message once, and each topic's first once more (checked against the generic one).
    assert calls == lw.BARO_N + lw.IMU_N + lw.ODOM_N + 3
    generic = _small_rows(path, False, monkeypatch)
    assert direct == generic
    assert [len(direct[r][0]) for r in ("BARO", "IMU", "ODOM")] == [lw.BARO_N, lw.IMU_N, lw.ODOM_N]


def test_direct_small_message_parser_reports_a_cut_message() -> None:
    """A message that ends early raises (the source turns it into a DecodeError naming the
    topic); the doubles of a whole one come out at their CDR alignment."""
    import struct

    from mfmap.ingest.wire import parse_stamped_doubles

    frame = b"imu_link\x00"  # 9 bytes: the doubles start at the next multiple of 8 after it
    head = b"\x00\x01\x00\x00" + struct.pack("<iI", 12, 500) + struct.pack("<I", len(frame)) + frame
    pad = b"\x00" * ((-(len(head) - 4)) % 8)
    body = struct.pack("<37d", *range(37))
    stamp, name, child, values = parse_stamped_doubles(head + pad + body, "cdr", 37)
    assert (stamp, name, child, values) == (12_000_000_500, "imu_link", "", tuple(float(v) for v in range(37)))
    with pytest.raises(struct.error):
        parse_stamped_doubles(head + pad + body[:-8], "cdr", 37)


def test_a_cut_pressure_message_is_a_decode_error_naming_the_topic(tmp_path: Path) -> None:
    """A message cut short after the topic's first (which the direct parser checks against
    the generic one): one DecodeError naming the file, the topic and the type."""
    from mcap.writer import Writer

    store = lw.typestore(ros1=False)
    msgtype = "sensor_msgs/msg/FluidPressure"
    path = tmp_path / "cut.mcap"
    with path.open("wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="mfmap-tests")
        sid = w.register_schema(msgtype, "ros2msg", store.generate_msgdef(msgtype, ros_version=2)[0].encode())
        channel = w.register_channel("/pressure", "cdr", sid)
        for i in range(4):
            t = lw.T0_NS + i * 10**8
            data = bytes(store.serialize_cdr(lw.pressure_msg(store, t, 101_000.0 + i), msgtype))
            w.add_message(channel, log_time=t, data=data[:-12] if i == 2 else data, publish_time=t)
        w.finish()
    with open_log(path) as src, pytest.raises(
        DecodeError, match=r"cut\.mcap topic /pressure: unexpected sensor_msgs/msg/FluidPressure layout"
    ):
        src.pressure()
