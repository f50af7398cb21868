"""Fuzzing the readers and decoders (hypothesis): random PointCloud2 headers and field tables,
random MCAP records, logs cut short or with bytes overwritten. Every input gives a valid result
or one MfmapError (one line, naming the input); never another exception, never unbounded
memory."""

from __future__ import annotations

import functools
import io
import os
import tempfile
import tracemalloc
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import ingest_logwriter as lw
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mfmap.errors import MfmapError
from mfmap.ingest import open_log
from mfmap.ingest.decode import decode_laserscan, decode_pointcloud2
from mfmap.ingest.wire import parse_pointcloud2
from mfmap.types import Cloud, Role


def fuzz(examples: int) -> settings:
    """Hypothesis settings: `examples` inputs (times MFMAP_FUZZ_SCALE, for a deeper run), derived
    from the test's name and with no example database, so every machine tries the same ones.
    Reading a whole log under tracemalloc takes about a second: those tests try fewer."""
    scale = float(os.environ.get("MFMAP_FUZZ_SCALE", "1"))
    return settings(max_examples=max(1, round(examples * scale)), deadline=None, derandomize=True,
                    database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


MAX_BYTES = 1 << 20  # the decoder's size limit in these tests (ingest.max_cloud_mb)
MEMORY_LIMIT = 64 << 20  # what one decode or one read of a small log may allocate at its peak

STORE = lw.typestore(ros1=False)
STORE1 = lw.typestore(ros1=True)
FIELD_NAMES = ["x", "y", "z", "intensity", "ring", "t", "time", "timestamp", "rgb", "xyz", ""]


def _bounded(fn: Callable[[], Any]) -> Any:
    """fn(), with the peak of what it allocates (Python and numpy) checked against the limit."""
    tracemalloc.start()
    try:
        return fn()
    finally:
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        assert peak < MEMORY_LIMIT, f"{peak / 1e6:.0f} MB at the peak"


def _valid_cloud(cloud: Cloud, points: int) -> None:
    assert cloud.xyz.dtype == np.float32 and cloud.xyz.ndim == 2 and cloud.xyz.shape[1] == 3
    assert cloud.xyz.shape[0] <= points
    assert np.isfinite(cloud.xyz).all()
    for extra in (cloud.intensity, cloud.ring, cloud.t_offset_ns):
        assert extra is None or extra.shape == (cloud.xyz.shape[0],)


def _one_line(err: MfmapError) -> None:
    text = str(err)
    assert text and "\n" not in text and "Traceback" not in text


# ----- PointCloud2 headers and field tables ----------------------------------------------------

u32 = st.one_of(st.integers(0, 64), st.integers(0, 2**32 - 1))


@st.composite
def pointclouds(draw: st.DrawFn) -> Any:
    PointField = STORE.types["sensor_msgs/msg/PointField"]
    fields = [
        PointField(name=draw(st.one_of(st.sampled_from(FIELD_NAMES), st.text(max_size=6))),
                   offset=draw(st.one_of(st.integers(0, 40), st.integers(0, 2**32 - 1))),
                   datatype=draw(st.integers(0, 255)), count=draw(st.integers(0, 4)))
        for _ in range(draw(st.integers(0, 8)))
    ]
    if draw(st.booleans()):  # a plausible float32 x, y, z layout, so decoding goes deeper
        fields += [PointField(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")]
    height, width = draw(st.one_of(st.integers(0, 6), u32)), draw(st.one_of(st.integers(0, 20), u32))
    point_step = draw(st.one_of(st.integers(0, 48), u32))
    row_step = draw(st.one_of(st.just(min(point_step * width, 2**32 - 1)), u32))
    size = draw(st.one_of(st.just(min(row_step * height, 1 << 16)), st.integers(0, 4096)))
    data = np.frombuffer(draw(st.binary(min_size=min(size, 4096), max_size=min(size, 4096))),
                         dtype=np.uint8)
    if size > data.size:
        data = np.concatenate([data, np.frombuffer(np.random.default_rng(size).bytes(size - data.size),
                                                   dtype=np.uint8)])
    return STORE.types["sensor_msgs/msg/PointCloud2"](
        header=lw._header(STORE, 1_700_000_000_000_000_000, "lidar"), height=height, width=width,
        fields=fields, is_bigendian=draw(st.booleans()), point_step=point_step, row_step=row_step,
        data=data, is_dense=draw(st.booleans()))


@fuzz(150)
@given(pointclouds())
def test_random_pointcloud2_headers_decode_or_fail_in_one_line(msg: Any) -> None:
    points = msg.height * msg.width
    try:
        cloud = _bounded(lambda: decode_pointcloud2(msg, 0, "fuzz", MAX_BYTES))
    except MfmapError as err:
        _one_line(err)
    else:
        _valid_cloud(cloud, points)
    # The same message through the serialised bytes and the direct parser.
    data = bytes(STORE.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2"))
    try:
        parsed = _bounded(lambda: parse_pointcloud2(data, "cdr", "fuzz"))
        cloud = _bounded(lambda: decode_pointcloud2(parsed, 0, "fuzz", MAX_BYTES))
    except MfmapError as err:
        _one_line(err)
    else:
        _valid_cloud(cloud, points)


@fuzz(150)
@given(st.sampled_from(["cdr", "ros1"]), st.data())
def test_mutated_pointcloud2_bytes_parse_or_fail_in_one_line(encoding: str, data: st.DataObject) -> None:
    store = STORE if encoding == "cdr" else STORE1
    msg = lw.cloud_msg(store, 1, 1_700_000_000_000_000_000)
    raw = bytearray(store.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2") if encoding == "cdr"
                    else store.serialize_ros1(msg, "sensor_msgs/msg/PointCloud2"))
    for _ in range(data.draw(st.integers(1, 6))):
        at = data.draw(st.integers(0, len(raw) - 1))
        raw[at] = data.draw(st.integers(0, 255))
    cut = data.draw(st.one_of(st.just(len(raw)), st.integers(0, len(raw))))
    try:
        parsed = _bounded(lambda: parse_pointcloud2(bytes(raw[:cut]), encoding, "fuzz"))
        cloud = _bounded(lambda: decode_pointcloud2(parsed, 0, "fuzz", MAX_BYTES))
    except MfmapError as err:
        _one_line(err)
    else:
        _valid_cloud(cloud, int(parsed.height) * int(parsed.width))


@fuzz(150)
@given(st.lists(st.floats(allow_nan=True, allow_infinity=True, width=32), max_size=64),
       st.floats(allow_nan=True, allow_infinity=True), st.floats(allow_nan=True, allow_infinity=True),
       st.floats(allow_nan=True, allow_infinity=True))
def test_random_laserscans_decode_or_fail_in_one_line(ranges: list[float], angle_min: float,
                                                      increment: float, range_max: float) -> None:
    msg = STORE.types["sensor_msgs/msg/LaserScan"](
        header=lw._header(STORE, 1, "laser"), angle_min=angle_min, angle_max=angle_min,
        angle_increment=increment, time_increment=0.0, scan_time=0.1, range_min=0.1,
        range_max=range_max, ranges=np.array(ranges, dtype=np.float32),
        intensities=np.zeros(0, dtype=np.float32))
    try:
        scan = decode_laserscan(msg, 1)
    except MfmapError as err:
        _one_line(err)
    else:
        assert scan.xy.shape[1] == 2 and np.isfinite(scan.xy).all()


# ----- random MCAP records and damaged logs -----------------------------------------------------


def _read_everything(path: Path) -> None:
    """What a build reads of a log: every role's stream, decoded."""

    def read() -> None:
        with open_log(path) as src:
            for role in (Role.BARO, Role.IMU, Role.ODOM):
                try:
                    {Role.BARO: src.pressure, Role.IMU: src.imu, Role.ODOM: src.odometry}[role]()
                except MfmapError as err:
                    _one_line(err)
            src.extrinsics()
            for role, stream in ((Role.LIDAR, src.clouds), (Role.SCAN2D, src.scans2d)):
                if role in src.roles:
                    for item in stream():
                        if isinstance(item, Cloud):
                            _valid_cloud(item, 1 << 20)
            for topic in src.topics:
                for _ in src.messages(topic.name):
                    pass

    try:
        _bounded(read)
    except MfmapError as err:
        _one_line(err)


def _record(record: Any) -> bytes:
    from mcap.records import RecordBuilder

    builder = RecordBuilder()
    record.write(builder)
    return bytes(builder.end())


@st.composite
def mcap_records(draw: st.DrawFn) -> bytes:
    """An MCAP file of random records: schemas and channels of the types mfmap reads (or not),
    messages whose payloads are real messages with bytes overwritten, or noise."""
    from mcap.records import Channel, DataEnd, Footer, Header, Message, Schema

    types = ["sensor_msgs/msg/PointCloud2", "sensor_msgs/msg/FluidPressure", "sensor_msgs/msg/Imu",
             "nav_msgs/msg/Odometry", "tf2_msgs/msg/TFMessage", "sensor_msgs/msg/LaserScan"]
    payloads = {t: bytes(STORE.serialize_cdr(m, t)) for n, t, _, m in lw.messages(STORE)
                for _ in [0] if t in types}
    out = io.BytesIO()
    out.write(b"\x89MCAP0\r\n")
    out.write(_record(Header(profile=draw(st.sampled_from(["ros2", "ros1", ""])), library="fuzz")))
    ids = st.integers(0, 5)
    for _ in range(draw(st.integers(0, 25))):
        kind = draw(st.sampled_from(["schema", "channel", "message", "message", "noise"]))
        if kind == "schema":
            name = draw(st.one_of(st.sampled_from(types), st.text(max_size=12)))
            text = STORE.generate_msgdef(name, ros_version=2)[0] if name in types and draw(st.booleans()) \
                else draw(st.text(max_size=40))
            out.write(_record(Schema(id=draw(ids), name=name, encoding=draw(st.sampled_from(
                ["ros2msg", "ros1msg", "jsonschema", ""])), data=text.encode())))
        elif kind == "channel":
            out.write(_record(Channel(id=draw(ids), schema_id=draw(ids), topic=draw(st.sampled_from(
                ["/lidar", "/baro", "/imu", "/odom", "/tf_static", "/scan"])),
                message_encoding=draw(st.sampled_from(["cdr", "ros1", "json"])), metadata={})))
        elif kind == "message":
            data = bytearray(payloads[draw(st.sampled_from(sorted(payloads)))])
            for _ in range(draw(st.integers(0, 4))):
                data[draw(st.integers(0, len(data) - 1))] = draw(st.integers(0, 255))
            t = draw(st.one_of(st.integers(0, 2**64 - 1),
                               st.integers(lw.T0_NS, lw.T0_NS + 10**10)))
            out.write(_record(Message(channel_id=draw(ids), log_time=t, publish_time=t, sequence=0,
                                      data=bytes(data[: draw(st.integers(0, len(data)))]))))
        else:
            out.write(draw(st.binary(max_size=64)))
    if draw(st.booleans()):
        out.write(_record(DataEnd(data_section_crc=0)))
        out.write(_record(Footer(summary_start=0, summary_offset_start=0, summary_crc=0)))
        out.write(b"\x89MCAP0\r\n")
    return out.getvalue()


@fuzz(100)
@given(mcap_records())
def test_random_mcap_records_read_or_fail_in_one_line(data: bytes) -> None:
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "fuzz.mcap"
        path.write_bytes(data)
        _read_everything(path)


@functools.cache
def _log_bytes(fmt: str) -> bytes:
    """The standard test log in a single-file format, as bytes (kept out of hypothesis' reports,
    which would print them)."""
    with tempfile.TemporaryDirectory() as folder:
        return lw.write_log(Path(folder), fmt).read_bytes()


def _damaged(data: bytes, draw: st.DataObject) -> Iterator[bytes]:
    yield data[: draw.draw(st.integers(0, len(data) - 1), label="cut")]
    raw = bytearray(data)
    for _ in range(draw.draw(st.integers(1, 8), label="bytes overwritten")):
        at = draw.draw(st.integers(0, len(raw) - 1))
        raw[at] = draw.draw(st.integers(0, 255))
    yield bytes(raw)


@fuzz(30)
@given(st.sampled_from(["mcap-ros2", "mcap-ros1", "ros1-none", "ros1-bz2", "ros1-lz4"]), st.data())
def test_logs_cut_short_or_overwritten_read_or_fail_in_one_line(fmt: str, data: st.DataObject) -> None:
    suffix = ".mcap" if fmt.startswith("mcap") else ".bag"
    with tempfile.TemporaryDirectory() as folder:
        for k, damaged in enumerate(_damaged(_log_bytes(fmt), data)):
            path = Path(folder) / f"log{k}{suffix}"
            path.write_bytes(damaged)
            _read_everything(path)


@fuzz(15)
@given(st.sampled_from(["ros2-sqlite3", "ros2-mcap"]), st.data())
def test_ros2_bags_cut_short_read_or_fail_in_one_line(fmt: str, data: st.DataObject) -> None:
    with tempfile.TemporaryDirectory() as folder:
        bag = lw.write_log(Path(folder), fmt)
        storage = next(p for p in bag.iterdir() if p.suffix in (".db3", ".mcap"))
        raw = storage.read_bytes()
        storage.write_bytes(raw[: data.draw(st.integers(0, len(raw) - 1), label="cut")])
        _read_everything(bag)


@pytest.mark.parametrize("x_type", [1, 2, 3, 4, 5, 6, 8])  # every integer type, and float64
def test_a_cloud_with_x_of_another_type_than_y_and_z_decodes(x_type: int) -> None:
    """Found by a deeper fuzzing run: an int8 x beside float32 y and z made the squared range's
    sum an int8 and numpy refuse the cast."""
    msg = lw.cloud_msg(STORE, 1, 1_700_000_000_000_000_000)
    x = next(f for f in msg.fields if f.name == "x")
    x.datatype = x_type
    cloud = decode_pointcloud2(msg, 0, "fuzz", MAX_BYTES)
    _valid_cloud(cloud, msg.height * msg.width)
    assert cloud.xyz.shape[0] > 0
