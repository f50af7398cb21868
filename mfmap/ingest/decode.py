"""Message decoders: deserialised ROS messages -> mfmap types.

The decoders take the attribute-style messages that rosbags' deserialisers produce (ROS 1 and
ROS 2 alike: `header.stamp.sec`, `header.stamp.nanosec`) and return numpy-backed values. A
PointCloud2 is decoded with ONE structured numpy dtype laid over the raw bytes, whatever the field
order, padding, byte order or row padding, so no Python code runs per point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from mfmap.errors import DecodeError
from mfmap.ingest.lidartime import TIME_FIELDS, AzimuthSpec, TimeSpec
from mfmap.types import Cloud, Scan2D

# sensor_msgs/PointField datatype -> numpy type character code (byte order added later).
POINTFIELD_DTYPES: dict[int, str] = {
    1: "i1",
    2: "u1",
    3: "i2",
    4: "u2",
    5: "i4",
    6: "u4",
    7: "f4",
    8: "f8",
}

# A single scan larger than this is a corrupt header, not a lidar (a 128x2048 Ouster scan with
# every field is about 25 MB).
DEFAULT_MAX_CLOUD_BYTES = 1 << 30

_VOID12 = np.dtype((np.void, 12))


def stamp_ns_of(msg: Any, log_time_ns: int) -> int:
    """Header stamp in int ns; the log time when the message has no header or a zero stamp."""
    header = getattr(msg, "header", None)
    if header is None:
        return int(log_time_ns)
    stamp = header.stamp
    ns = int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
    return ns if ns != 0 else int(log_time_ns)


@dataclass(frozen=True)
class CloudLayout:
    """The parts of a PointCloud2 header the decoder needs, validated."""

    dtype: np.dtype[Any]  # the wanted fields at their offsets, itemsize point_step
    span: np.dtype[Any]  # the same fields packed from the first wanted byte to the last
    span_offset: int  # byte offset of the span inside a point
    height: int
    width: int
    point_step: int
    row_step: int
    time_fields: tuple[str, ...]  # the fields that may hold a point's time, present in the cloud
    has_intensity: bool
    has_ring: bool
    # Every field of the message as (name, offset, numpy type or '?', count), for `mfmap info`.
    fields: tuple[tuple[str, int, str, int], ...] = ()

    @property
    def time_field(self) -> str | None:
        return self.time_fields[0] if self.time_fields else None

    def dtype_name(self, field: str) -> str:
        return str(np.dtype(self.dtype.fields[field][0]).newbyteorder("=").name)  # type: ignore[index]


def cloud_layout(
    fields: list[Any],
    height: int,
    width: int,
    point_step: int,
    row_step: int,
    is_bigendian: bool,
    data_len: int,
    where: str,
    max_bytes: int = DEFAULT_MAX_CLOUD_BYTES,
    time_fields: tuple[str, ...] = TIME_FIELDS,
) -> CloudLayout:
    """Check a PointCloud2's sizes against its data and build the structured dtype.

    `where` names the file and topic for the error message; `time_fields` are the fields kept
    as candidates for a point's time.
    """
    order = ">" if is_bigendian else "<"
    _check_sizes(height, width, point_step, row_step, data_len, where, max_bytes)
    names, formats, offsets = _wanted_fields(fields, point_step, order, time_fields, where)
    dtype = np.dtype(
        {"names": names, "formats": formats, "offsets": offsets, "itemsize": max(point_step, 1)}
    )
    listed = tuple(
        (str(f.name), int(f.offset), np.dtype(POINTFIELD_DTYPES[int(f.datatype)]).name
         if int(f.datatype) in POINTFIELD_DTYPES else "?", int(f.count))
        for f in fields
    )
    return CloudLayout(
        dtype=dtype,
        span=_span_dtype(names, formats, offsets),
        span_offset=min(offsets),
        height=height,
        width=width,
        point_step=point_step,
        row_step=row_step,
        time_fields=tuple(n for n in time_fields if n in names and n not in ("x", "y", "z")),
        has_intensity="intensity" in names,
        has_ring="ring" in names,
        fields=listed,
    )


def _check_sizes(height: int, width: int, point_step: int, row_step: int, data_len: int,
                 where: str, max_bytes: int) -> None:
    """A PointCloud2's sizes, checked against each other, the limit and its data's length."""
    if height < 0 or width < 0 or point_step < 0 or row_step < 0:
        raise DecodeError("PointCloud2 with negative sizes", where)
    claimed = height * width * point_step
    if claimed > max_bytes or row_step * height > max_bytes:
        raise DecodeError(
            f"PointCloud2 claims {max(claimed, row_step * height) / 1e9:.1f} GB "
            f"({height}x{width} points of {point_step} bytes), more than the "
            f"{max_bytes / 1e9:.1f} GB limit: corrupt header",
            where,
        )
    if height * width > 0 and row_step < width * point_step:
        raise DecodeError(
            f"PointCloud2 row_step {row_step} is smaller than width*point_step "
            f"{width}*{point_step}",
            where,
        )
    # Exactly row_step*height bytes, or the last row's padding left off: anything else means
    # the header and the data disagree.
    if height * width > 0 and data_len not in (
        row_step * height,
        row_step * (height - 1) + width * point_step,
    ):
        raise DecodeError(
            f"PointCloud2 data is {data_len} bytes but width*height*point_step = "
            f"{width}*{height}*{point_step} (row_step {row_step}) needs {row_step * height}",
            where,
        )


def _wanted_fields(fields: list[Any], point_step: int, order: str, time_fields: tuple[str, ...],
                   where: str) -> tuple[list[str], list[str], list[int]]:
    """(names, numpy formats, offsets) of the fields the decoder reads, in the order wanted."""
    by_name: dict[str, Any] = {}
    for f in fields:
        by_name.setdefault(str(f.name), f)
    missing = [n for n in ("x", "y", "z") if n not in by_name]
    if missing:
        raise DecodeError(f"PointCloud2 has no field {'/'.join(missing)}", where)
    names: list[str] = []
    formats: list[str] = []
    offsets: list[int] = []
    wanted = list(dict.fromkeys(["x", "y", "z", "intensity", "ring", *time_fields]))
    for name in wanted:
        f = by_name.get(name)
        if f is None:
            continue
        code = POINTFIELD_DTYPES.get(int(f.datatype))
        if code is None:
            raise DecodeError(f"PointCloud2 field '{name}' has unknown datatype {f.datatype}", where)
        size = int(code[1])
        # A field with count > 1 is an array; the first element sits at the field's offset.
        if int(f.offset) < 0 or int(f.offset) + size > point_step:
            raise DecodeError(
                f"PointCloud2 field '{name}' at offset {f.offset} does not fit in "
                f"point_step {point_step}",
                where,
            )
        names.append(name)
        formats.append(order + code)
        offsets.append(int(f.offset))
    return names, formats, offsets


def _span_dtype(names: list[str], formats: list[str], offsets: list[int]) -> np.dtype[Any]:
    """Packed record of the wanted fields; consecutive float32 x, y, z become one 'xyz' (3,)."""
    lo = min(offsets)
    hi = max(o + int(f[2:]) for o, f in zip(offsets, formats, strict=True))
    fields = dict(zip(names, zip(formats, offsets, strict=True), strict=True))
    (fx, ox), (fy, oy), (fz, oz) = fields.pop("x"), fields.pop("y"), fields.pop("z")
    spec: dict[str, tuple[Any, int]]
    if fx == fy == fz and fx[1:] == "f4" and oy == ox + 4 and oz == ox + 8:
        spec = {"xyz": ((fx, (3,)), ox)}
    else:
        spec = {"x": (fx, ox), "y": (fy, oy), "z": (fz, oz)}
    spec.update(fields)
    return np.dtype(
        {
            "names": list(spec),
            "formats": [f for f, _ in spec.values()],
            "offsets": [o - lo for _, o in spec.values()],
            "itemsize": hi - lo,
        }
    )


Timing = TimeSpec | AzimuthSpec | None


def decode_pointcloud2(
    msg: Any,
    stamp_ns: int,
    where: str = "",
    max_bytes: int = DEFAULT_MAX_CLOUD_BYTES,
    drop_zero: bool = True,
    timing: Timing = None,
) -> Cloud:
    """sensor_msgs/PointCloud2 -> Cloud (sensor frame, non-finite points dropped).

    `drop_zero` also drops points at exactly (0, 0, 0), which Ouster and other drivers send for
    no-returns in organised clouds. `timing` gives each point's time (a decided reading of a
    time field, or the azimuth); without it the cloud has no per-point time.
    """
    layout, buf = pointcloud2_layout(msg, where, max_bytes)
    return decode_with_layout(layout, buf, stamp_ns, str(msg.header.frame_id), drop_zero, timing)


def pointcloud2_layout(msg: Any, where: str = "", max_bytes: int = DEFAULT_MAX_CLOUD_BYTES,
                       time_fields: tuple[str, ...] = TIME_FIELDS) -> tuple[CloudLayout, Any]:
    """The validated layout of a PointCloud2 message and its data buffer."""
    data = msg.data
    buf = data if isinstance(data, (bytes, bytearray, memoryview)) else np.asarray(data)
    data_len = len(buf) if not isinstance(buf, np.ndarray) else int(buf.nbytes)
    key = getattr(msg, "layout_key", b"")
    cache_key = (key, data_len, max_bytes, time_fields)
    layout = _LAYOUTS.get(cache_key) if key else None
    if layout is None:
        layout = _layout_of(msg, data_len, where, max_bytes, time_fields)
        if key:
            if len(_LAYOUTS) >= 64:
                _LAYOUTS.clear()
            _LAYOUTS[cache_key] = layout
    return layout, buf


# Validated layouts by (serialised layout bytes, data length, size limit, time fields): the
# checks and the dtypes are built once per sensor, not once per scan.
_LAYOUTS: dict[tuple[bytes, int, int, tuple[str, ...]], CloudLayout] = {}


def _layout_of(msg: Any, data_len: int, where: str, max_bytes: int,
               time_fields: tuple[str, ...]) -> CloudLayout:
    return cloud_layout(
        list(msg.fields),
        int(msg.height),
        int(msg.width),
        int(msg.point_step),
        int(msg.row_step),
        bool(msg.is_bigendian),
        data_len,
        where,
        max_bytes,
        time_fields,
    )


@dataclass(frozen=True)
class DecodedPoints:
    """The kept points of one scan, in storage order, and the raw values of its time fields."""

    xyz: np.ndarray[Any, np.dtype[np.float32]]
    intensity: np.ndarray[Any, np.dtype[np.float32]] | None
    ring: np.ndarray[Any, np.dtype[np.uint16]] | None
    times: dict[str, np.ndarray[Any, Any]]


def decode_with_layout(
    layout: CloudLayout, buf: Any, stamp_ns: int, frame_id: str, drop_zero: bool = True,
    timing: Timing = None,
) -> Cloud:
    """Decode the raw point bytes of a validated layout."""
    wanted = (timing.field,) if isinstance(timing, TimeSpec) else ()
    pts = decode_points(layout, buf, drop_zero, wanted)
    return cloud_of(pts, stamp_ns, frame_id, timing)


def cloud_of(pts: DecodedPoints, stamp_ns: int, frame_id: str, timing: Timing) -> Cloud:
    """A Cloud of decoded points with each point's time from `timing`."""
    t_offset = None
    if isinstance(timing, TimeSpec) and timing.field in pts.times:
        t_offset = timing.offsets_ns(pts.times[timing.field], stamp_ns)
    elif isinstance(timing, AzimuthSpec):
        t_offset = timing.offsets_ns(pts.xyz)
    return Cloud(
        stamp_ns=stamp_ns,
        frame_id=frame_id,
        xyz=pts.xyz,
        intensity=pts.intensity,
        ring=pts.ring,
        t_offset_ns=t_offset,
    )


def decode_points(
    layout: CloudLayout, buf: Any, drop_zero: bool = True, time_fields: tuple[str, ...] | None = None
) -> DecodedPoints:
    """The kept points of a validated layout; the raw values of `time_fields` (default: every
    candidate time field of the layout)."""
    fields = layout.time_fields if time_fields is None else time_fields
    h, w = layout.height, layout.width
    n = h * w
    if n == 0:
        return DecodedPoints(np.zeros((0, 3), np.float32), None, None, {})
    # The wanted fields of every point are first packed into one contiguous record array (one
    # strided pass over the message, which also drops any row padding); the validity test and
    # the gather of kept points then run on that dense copy, which is faster than working on
    # the sparse message bytes, and every output array is copied from it.
    packed_bytes = np.dtype((np.void, layout.span.itemsize))
    strided = np.ndarray(
        shape=(h, w),
        dtype=packed_bytes,
        buffer=buf,
        offset=layout.span_offset,
        strides=(layout.row_step, layout.point_step),
    )
    recs = np.array(strided, order="C").reshape(n).view(layout.span)
    names = layout.span.names or ()
    if "xyz" in names:
        packed = recs["xyz"]
        x, y, z = packed[:, 0], packed[:, 1], packed[:, 2]
    else:
        x, y, z = recs["x"], recs["y"], recs["z"]
    # One squared range per point, instead of reductions along the short axis of (N, 3):
    # NaN fails both comparisons, inf fails the second, an exact (0, 0, 0) the first.
    # In floats whatever the fields' types (a driver may send integer coordinates, or mix them);
    # a garbage coordinate squares to inf, which the test below drops.
    with np.errstate(over="ignore", invalid="ignore"):
        r2 = np.multiply(x, x, dtype=np.result_type(x.dtype, y.dtype, z.dtype, np.float32))
        r2 += y * y
        r2 += z * z
    keep = (r2 < np.inf) & (r2 > 0) if drop_zero else np.isfinite(r2)
    sel = recs
    if not bool(keep.all()):
        # Gathered as opaque bytes: np.take on a structured dtype copies field by field.
        sel = np.take(recs.view(packed_bytes), np.flatnonzero(keep)).view(layout.span)
    if sel.shape[0] == 0:
        xyz = np.zeros((0, 3), np.float32)  # every return NaN: no bytes to view
    elif "xyz" in names:
        # Copied as opaque 12-byte items, then viewed as floats: numpy copies a strided (N, 3)
        # float array element by element, several times slower.
        xyz_type, xyz_offset = layout.span.fields["xyz"][:2]  # type: ignore[index]
        xyz_bytes = np.ndarray((sel.shape[0],), _VOID12, sel, xyz_offset, sel.strides).copy()
        xyz = xyz_bytes.view(xyz_type.base).reshape(-1, 3)
        if not xyz.dtype.isnative:
            xyz = xyz.astype(np.float32)
    else:
        xyz = np.empty((sel.shape[0], 3), np.float32)
        xyz[:, 0], xyz[:, 1], xyz[:, 2] = sel["x"], sel["y"], sel["z"]
    intensity = sel["intensity"].astype(np.float32) if layout.has_intensity else None
    ring = sel["ring"].astype(np.uint16) if layout.has_ring else None
    times = {name: sel[name].astype(sel[name].dtype.newbyteorder("="))
             for name in fields if name in names}
    return DecodedPoints(xyz, intensity, ring, times)


def decode_laserscan(msg: Any, stamp_ns: int, reversed_time: bool = False, where: str = "") -> Scan2D:
    """sensor_msgs/LaserScan -> 2D points; NaN, inf and out-of-range readings dropped.

    Beam i is measured at stamp + i * time_increment (a negative increment: the stamp is the
    last beam's time); `reversed_time` takes the array as running against the sweep, beam i at
    (n - 1 - i) * time_increment, as rplidar_ros publishes a clockwise scanner (its ranges
    reversed into counter-clockwise order, its time_increment left positive).
    """
    ranges = np.asarray(msg.ranges, dtype=np.float32)
    i = np.arange(ranges.shape[0])
    angle_min, increment = float(msg.angle_min), float(msg.angle_increment)
    if not (math.isfinite(angle_min) and math.isfinite(increment)):
        raise DecodeError(f"LaserScan with angle_min {angle_min} and angle_increment {increment}: "
                          "no bearing for its ranges", where or None)
    angles = angle_min + i * increment
    # The limits compared in float64: a driver's range_max past float32's (1e300, say) would
    # overflow in a float32 comparison.
    wide = ranges.astype(np.float64)
    with np.errstate(invalid="ignore"):
        keep = np.isfinite(wide) & (wide >= float(msg.range_min)) & (wide <= float(msg.range_max))
    r = wide[keep]
    a = angles[keep]
    xy = np.stack([r * np.cos(a), r * np.sin(a)], axis=1).astype(np.float32)
    t_offset = None
    increment_ns = float(msg.time_increment) * 1e9
    # A beam apart by a second or more is no per-beam time (a sweep of seconds).
    if increment_ns != 0.0 and abs(increment_ns) < 1e9:
        beam = i[keep]
        if reversed_time:
            beam = ranges.shape[0] - 1 - beam
        t_offset = np.round(beam * increment_ns).astype(np.int64)
    return Scan2D(stamp_ns=stamp_ns, frame_id=str(msg.header.frame_id), xy=xy, t_offset_ns=t_offset)


@dataclass(frozen=True)
class PressureUnit:
    name: str
    to_pa: float


# Plausible barometer readings on Earth (from the Dead Sea to ~9 km up) in each unit.
_PRESSURE_UNITS = (
    (PressureUnit("Pa", 1.0), 25_000.0, 115_000.0),
    (PressureUnit("hPa", 100.0), 250.0, 1_150.0),
    (PressureUnit("kPa", 1000.0), 25.0, 115.0),
)


def pressure_unit(values_pa: np.ndarray[Any, Any]) -> PressureUnit | None:
    """The unit the readings were published in, judged by their median magnitude."""
    if values_pa.size == 0:
        return PressureUnit("Pa", 1.0)
    median = float(np.nanmedian(values_pa))
    for unit, low, high in _PRESSURE_UNITS:
        if low <= median <= high:
            return unit
    return None


def quat_to_matrix(x: float, y: float, z: float, w: float) -> np.ndarray[Any, np.dtype[np.float64]]:
    """Unit quaternion (x, y, z, w) -> 3x3 rotation matrix (normalised first)."""
    q = np.array([x, y, z, w], dtype=np.float64)
    norm = float(np.linalg.norm(q))
    if norm == 0.0:
        return np.eye(3)
    x, y, z, w = q / norm
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def transform_matrix(transform: Any) -> np.ndarray[Any, np.dtype[np.float64]]:
    """geometry_msgs/Transform -> 4x4 homogeneous matrix."""
    t, q = transform.translation, transform.rotation
    out = np.eye(4)
    out[:3, :3] = quat_to_matrix(float(q.x), float(q.y), float(q.z), float(q.w))
    out[:3, 3] = [float(t.x), float(t.y), float(t.z)]
    return out
