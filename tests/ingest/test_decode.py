"""PointCloud2 / LaserScan / pressure decoders on hand-built messages with known bytes."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from mfmap.errors import DecodeError
from mfmap.ingest.decode import decode_laserscan, decode_pointcloud2, pressure_unit

STAMP_NS = 1_700_000_000_250_000_000  # 0.25 s past a whole second


def field(name: str, offset: int, datatype: int, count: int = 1) -> SimpleNamespace:
    return SimpleNamespace(name=name, offset=offset, datatype=datatype, count=count)


def cloud_msg(
    arr: np.ndarray[Any, Any],
    fields: list[SimpleNamespace],
    height: int = 1,
    width: int | None = None,
    row_step: int | None = None,
    bigendian: bool = False,
    data: bytes | None = None,
) -> SimpleNamespace:
    width = arr.size // height if width is None else width
    step = arr.dtype.itemsize
    return SimpleNamespace(
        header=SimpleNamespace(stamp=SimpleNamespace(sec=0, nanosec=0), frame_id="os"),
        height=height,
        width=width,
        fields=fields,
        is_bigendian=bigendian,
        point_step=step,
        row_step=step * width if row_step is None else row_step,
        data=np.frombuffer(arr.tobytes() if data is None else data, np.uint8),
        is_dense=False,
    )


XYZ = np.array([[1.0, 2.0, 3.0], [-4.0, 5.5, 0.25], [7.0, -8.0, 9.0]], dtype=np.float32)


def test_any_field_order_and_padding() -> None:
    dt = np.dtype({"names": ["z", "intensity", "y", "x"], "formats": ["<f4", "<u2", "<f4", "<f4"],
                   "offsets": [0, 6, 12, 20], "itemsize": 40})
    arr = np.zeros(3, dt)
    arr["x"], arr["y"], arr["z"] = XYZ[:, 0], XYZ[:, 1], XYZ[:, 2]
    arr["intensity"] = [10, 20, 30]
    msg = cloud_msg(arr, [field("z", 0, 7), field("intensity", 6, 4), field("y", 12, 7), field("x", 20, 7)])
    c = decode_pointcloud2(msg, STAMP_NS)
    np.testing.assert_array_equal(c.xyz, XYZ)
    assert c.intensity is not None and c.intensity.dtype == np.float32
    np.testing.assert_array_equal(c.intensity, [10, 20, 30])
    assert c.ring is None and c.t_offset_ns is None and c.frame_id == "os"


def test_big_endian_float64() -> None:
    dt = np.dtype({"names": ["x", "y", "z"], "formats": [">f8", ">f8", ">f8"],
                   "offsets": [0, 8, 16], "itemsize": 24})
    arr = np.zeros(3, dt)
    arr["x"], arr["y"], arr["z"] = XYZ[:, 0], XYZ[:, 1], XYZ[:, 2]
    msg = cloud_msg(arr, [field("x", 0, 8), field("y", 8, 8), field("z", 16, 8)], bigendian=True)
    np.testing.assert_array_equal(decode_pointcloud2(msg, STAMP_NS).xyz, XYZ)
    # Read as little-endian the same bytes are garbage: the byte order is really honoured.
    msg.is_bigendian = False
    assert not np.array_equal(decode_pointcloud2(msg, STAMP_NS).xyz, XYZ)


def test_count_greater_than_one_takes_first_element() -> None:
    # "x" declared as a float32[3] vector holding x, y, z (as some drivers do), plus a z field.
    dt = np.dtype({"names": ["v", "z"], "formats": [("<f4", (3,)), "<f4"], "offsets": [0, 12],
                   "itemsize": 16})
    arr = np.zeros(3, dt)
    arr["v"] = XYZ
    arr["z"] = XYZ[:, 2]
    msg = cloud_msg(arr, [field("x", 0, 7, 3), field("y", 4, 7), field("z", 12, 7)])
    np.testing.assert_array_equal(decode_pointcloud2(msg, STAMP_NS).xyz, XYZ)


def _organised(nan_rows: list[int]) -> tuple[np.ndarray[Any, Any], list[SimpleNamespace]]:
    dt = np.dtype({"names": ["x", "y", "z", "ring"], "formats": ["<f4", "<f4", "<f4", "<u2"],
                   "offsets": [0, 4, 8, 16], "itemsize": 20})
    arr = np.zeros((2, 3), dt)
    arr["x"] = [[1, 2, 3], [4, 5, 6]]
    arr["y"], arr["z"] = 1.0, 2.0
    arr["ring"] = [[0, 0, 0], [1, 1, 1]]
    for r in nan_rows:
        arr["x"].reshape(-1)[r] = np.nan
    return arr, [field("x", 0, 7), field("y", 4, 7), field("z", 8, 7), field("ring", 16, 4)]


def test_organised_cloud_drops_nan_and_keeps_ring() -> None:
    arr, fields = _organised([1, 5])
    c = decode_pointcloud2(cloud_msg(arr, fields, height=2), STAMP_NS)
    np.testing.assert_array_equal(c.xyz[:, 0], [1, 3, 4, 5])
    assert c.ring is not None and c.ring.dtype == np.uint16
    np.testing.assert_array_equal(c.ring, [0, 0, 1, 1])


def test_row_step_padding() -> None:
    arr, fields = _organised([])
    rows = [arr[0].tobytes() + b"\xee" * 8, arr[1].tobytes() + b"\xee" * 8]
    msg = cloud_msg(arr, fields, height=2, width=3, row_step=3 * 20 + 8, data=b"".join(rows))
    c = decode_pointcloud2(msg, STAMP_NS)
    np.testing.assert_array_equal(c.xyz[:, 0], [1, 2, 3, 4, 5, 6])


def test_zero_points_dropped_unless_asked() -> None:
    arr, fields = _organised([])
    arr["x"][0, 0] = 0.0
    arr["y"][0, 0] = 0.0
    arr["z"][0, 0] = 0.0
    msg = cloud_msg(arr, fields, height=2)
    assert decode_pointcloud2(msg, STAMP_NS).xyz.shape == (5, 3)
    assert decode_pointcloud2(msg, STAMP_NS, drop_zero=False).xyz.shape == (6, 3)


def _xyz_msg() -> SimpleNamespace:
    dt = np.dtype({"names": ["x", "y", "z"], "formats": ["<f4"] * 3, "offsets": [0, 4, 8], "itemsize": 16})
    arr = np.zeros(3, dt)
    return cloud_msg(arr, [field("x", 0, 7), field("y", 4, 7), field("z", 8, 7)])


def test_size_mismatch_is_decode_error_naming_where() -> None:
    msg = _xyz_msg()
    msg.width, msg.row_step = 4, 64  # claims 4 points, data holds 3
    with pytest.raises(DecodeError, match=r"^log.mcap topic /pts: PointCloud2 data is 48 bytes"):
        decode_pointcloud2(msg, STAMP_NS, where="log.mcap topic /pts")
    msg.width, msg.row_step = 2, 32  # claims 2 points, data holds 3
    with pytest.raises(DecodeError, match="width\\*height\\*point_step = 2\\*1\\*16"):
        decode_pointcloud2(msg, STAMP_NS, where="log.mcap topic /pts")


def test_gigabyte_claim_rejected() -> None:
    msg = _xyz_msg()
    msg.width, msg.height, msg.row_step = 1 << 20, 1 << 12, 16 << 20
    with pytest.raises(DecodeError, match=r"claims 68\.7 GB"):
        decode_pointcloud2(msg, STAMP_NS, where="x")


def test_field_outside_point_and_missing_xyz() -> None:
    msg = _xyz_msg()
    msg.fields[2] = field("z", 14, 7)
    with pytest.raises(DecodeError, match="does not fit in point_step 16"):
        decode_pointcloud2(msg, STAMP_NS, where="x")
    msg.fields = msg.fields[:2]
    with pytest.raises(DecodeError, match="no field z"):
        decode_pointcloud2(msg, STAMP_NS, where="x")


def test_row_step_smaller_than_row() -> None:
    msg = _xyz_msg()
    msg.row_step = 40
    with pytest.raises(DecodeError, match="row_step 40 is smaller"):
        decode_pointcloud2(msg, STAMP_NS, where="x")


def test_laserscan_drops_invalid_ranges() -> None:
    msg = SimpleNamespace(
        header=SimpleNamespace(frame_id="laser"),
        angle_min=-np.pi / 2,
        angle_increment=np.pi / 2,
        time_increment=0.0,
        range_min=0.5,
        range_max=10.0,
        ranges=np.array([2.0, np.nan, 0.2, np.inf, 10.0, 11.0], np.float32),
    )
    s = decode_laserscan(msg, STAMP_NS)
    np.testing.assert_allclose(s.xy, [[0.0, -2.0], [0.0, -10.0]], atol=1e-5)
    assert s.t_offset_ns is None


@pytest.mark.parametrize(
    ("increment", "reversed_time", "want_ns"),
    [
        (1e-4, False, [0, 100_000, 200_000]),
        # The stamp is the last beam's time.
        (-1e-4, False, [0, -100_000, -200_000]),
        # rplidar_ros: the array runs against the sweep.
        (1e-4, True, [200_000, 100_000, 0]),
        # A beam a second or more after the one before it is no per-beam time, either way.
        (1.5, False, None),
        (-2.0, True, None),
        (float("nan"), False, None),
    ],
)
def test_laserscan_beam_times(increment: float, reversed_time: bool, want_ns: list[int] | None) -> None:
    msg = SimpleNamespace(
        header=SimpleNamespace(frame_id="laser"), angle_min=0.0, angle_increment=0.1,
        time_increment=increment, range_min=0.1, range_max=10.0,
        ranges=np.array([1.0, 2.0, 3.0], np.float32))
    s = decode_laserscan(msg, STAMP_NS, reversed_time)
    if want_ns is None:
        assert s.t_offset_ns is None
    else:
        assert s.t_offset_ns is not None
        np.testing.assert_array_equal(s.t_offset_ns, want_ns)


def test_laserscan_without_a_bearing_names_where() -> None:
    msg = SimpleNamespace(
        header=SimpleNamespace(frame_id="laser"), angle_min=0.0, angle_increment=float("inf"),
        time_increment=1e-4, range_min=0.1, range_max=10.0, ranges=np.ones(3, np.float32))
    with pytest.raises(DecodeError, match=r"^log\.mcap topic /scan: LaserScan with angle_min 0\.0 "
                       r"and angle_increment inf: no bearing"):
        decode_laserscan(msg, STAMP_NS, True, "log.mcap topic /scan")


@pytest.mark.parametrize(
    ("median", "unit"),
    [(101_325.0, "Pa"), (1013.25, "hPa"), (101.325, "kPa"), (62_000.0, "Pa"), (5.0, None)],
)
def test_pressure_unit_by_magnitude(median: float, unit: str | None) -> None:
    found = pressure_unit(np.array([median - 1e-3, median, median + 1e-3]))
    assert (found.name if found is not None else None) == unit


@pytest.mark.parametrize("wire", ["cdr-le", "cdr-be", "ros1"])
def test_direct_pointcloud2_parser_matches_rosbags(wire: str) -> None:
    import ingest_logwriter as lw

    from mfmap.ingest.wire import parse_pointcloud2

    ros1 = wire == "ros1"
    store = lw.typestore(ros1)
    msg = lw.cloud_msg(store, 3, STAMP_NS)
    msg.header.frame_id = "os_sensor"
    if ros1:
        data = bytes(store.serialize_ros1(msg, "sensor_msgs/msg/PointCloud2"))
    else:
        data = bytes(store.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2", little_endian=wire == "cdr-le"))
    parsed = parse_pointcloud2(data, "ros1" if ros1 else "cdr")
    assert (parsed.header.stamp.sec, parsed.header.stamp.nanosec) == (1_700_000_000, 250_000_000)
    assert parsed.header.frame_id == "os_sensor"
    assert [(f.name, f.offset, f.datatype, f.count) for f in parsed.fields] == [
        (f.name, f.offset, f.datatype, f.count) for f in msg.fields
    ]
    assert (parsed.height, parsed.width, parsed.point_step, parsed.row_step) == (4, 8, 32, 256)
    assert bytes(parsed.data) == bytes(msg.data)
    a, b = decode_pointcloud2(parsed, STAMP_NS), decode_pointcloud2(msg, STAMP_NS)
    np.testing.assert_array_equal(a.xyz, b.xyz)
    # Cut anywhere, the message is a DecodeError, never an IndexError or a short cloud.
    for cut in (2, 10, 60, len(data) - 200):
        with pytest.raises(DecodeError, match="truncated or corrupt PointCloud2"):
            parse_pointcloud2(data[:cut], "ros1" if ros1 else "cdr", where="x")
