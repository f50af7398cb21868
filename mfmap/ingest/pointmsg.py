"""Lidar messages that are not PointCloud2 (Livox's `livox_ros_driver2/msg/CustomMsg`): parsed
from the message definition the log carries.

Such a message is a header, a few scalars and a sequence of flat point structs. The definition
(rosbags' field definitions, built from the log's schema) gives every field's type, so the wire
layout follows from it: scalars are read with a cursor, and the point sequence is one numpy
structured view of the message bytes, whatever the struct's fields, their order or the padding
CDR puts between them. A driver version that adds or reorders point fields needs no code.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

from mfmap.errors import DecodeError
from mfmap.ingest.decode import DecodedPoints
from mfmap.ingest.lidartime import TIME_FIELDS

_PRIMITIVES: dict[str, str] = {
    "bool": "u1", "byte": "u1", "char": "u1", "int8": "i1", "uint8": "u1", "int16": "i2",
    "uint16": "u2", "int32": "i4", "uint32": "u4", "int64": "i8", "uint64": "u8",
    "float32": "f4", "float64": "f8",
}
_BASE, _NAME, _ARRAY, _SEQUENCE = 1, 2, 3, 4
# The synthesised time of a Livox point: its frame's time base plus the point's offset.
TIMEBASE_FIELD = "timebase+offset_time"
INTENSITY_FIELDS = ("intensity", "reflectivity")
RING_FIELDS = ("ring", "line")

# Message types read as lidar scans by this parser.
POINT_MESSAGE_TYPES = ("livox_ros_driver2/msg/CustomMsg", "livox_ros_driver/msg/CustomMsg")


@dataclass(frozen=True)
class PointMessage:
    """One parsed message: its scalar fields by dotted path, and the point structs."""

    scalars: dict[str, Any]
    points: np.ndarray[Any, Any]


class _Cursor:
    def __init__(self, buf: memoryview, cdr: bool) -> None:
        self.buf = buf
        self.cdr = cdr
        self.order = ("<" if buf[1] & 1 else ">") if cdr else "<"
        self.pos = 4 if cdr else 0
        self.base = 4 if cdr else 0

    def align(self, size: int) -> None:
        if self.cdr:
            self.pos += (-(self.pos - self.base)) % size

    def primitive(self, code: str) -> Any:
        size = int(code[1])
        self.align(size)
        (value,) = struct.unpack_from(self.order + _STRUCT[code], self.buf, self.pos)
        self.pos += size
        return value

    def string(self) -> str:
        n = self.primitive("u4")
        end = self.pos + n
        if end > len(self.buf):
            raise IndexError("string past the end")
        raw = bytes(self.buf[self.pos : end - (1 if self.cdr and n else 0)])
        self.pos = end
        return raw.decode("utf-8", errors="replace")


_STRUCT = {"u1": "B", "i1": "b", "u2": "H", "i2": "h", "u4": "I", "i4": "i", "u8": "Q", "i8": "q",
           "f4": "f", "f8": "d"}


class PointMessageParser:
    """Parses one message type in one encoding ("cdr" or "ros1") from its field definitions."""

    def __init__(self, fielddefs: dict[str, Any], msgtype: str, encoding: str, where: str) -> None:
        if encoding not in ("cdr", "ros1"):
            raise DecodeError(f"cannot parse {msgtype} in encoding '{encoding}'", where)
        self.fielddefs = fielddefs
        self.msgtype = msgtype
        self.cdr = encoding == "cdr"
        self.where = where
        self.points_field = self._points_field()
        self._element = self._flat_fields(self._sequence_struct(self.points_field))
        names = [n for n, _ in self._element]
        if not {"x", "y", "z"} <= set(names):
            raise DecodeError(f"{msgtype}: its points ({self.points_field}) have no x, y, z", where)

    def _fields(self, msgtype: str) -> list[tuple[str, Any]]:
        entry = self.fielddefs.get(msgtype)
        if entry is None:
            raise DecodeError(f"{self.msgtype}: no definition of '{msgtype}' in the log", self.where)
        return list(entry[1])

    def _sequence_struct(self, name: str) -> str:
        for field, (_kind, desc) in self._fields(self.msgtype):
            if field == name:
                return str(desc[0][1])
        raise AssertionError(name)

    def _points_field(self) -> str:
        """The message's sequence of point structs (the one holding x, y, z)."""
        for field, (kind, desc) in self._fields(self.msgtype):
            if int(kind) == _SEQUENCE and int(desc[0][0]) == _NAME:
                members = {n for n, _ in self._fields(str(desc[0][1]))}
                if {"x", "y", "z"} <= members:
                    return str(field)
        raise DecodeError(f"{self.msgtype} has no sequence of points with x, y, z", self.where)

    def _flat_fields(self, msgtype: str) -> list[tuple[str, str]]:
        """(name, numpy code) of a struct made of primitives only."""
        out = []
        for field, (kind, desc) in self._fields(msgtype):
            if int(kind) != _BASE or desc[0] not in _PRIMITIVES:
                raise DecodeError(
                    f"{self.msgtype}: point field '{field}' is not a plain number", self.where)
            out.append((str(field), _PRIMITIVES[desc[0]]))
        return out

    def parse(self, data: bytes | memoryview) -> PointMessage:
        buf = memoryview(data).cast("B")
        try:
            if self.cdr and len(buf) < 4:
                raise IndexError("shorter than the CDR header")
            c = _Cursor(buf, self.cdr)
            scalars: dict[str, Any] = {}
            points = self._walk(c, self.msgtype, "", scalars)
        except (IndexError, struct.error, ValueError) as err:
            raise DecodeError(f"truncated or corrupt {self.msgtype} message ({err})", self.where) from err
        assert points is not None
        return PointMessage(scalars, points)

    def _walk(self, c: _Cursor, msgtype: str, prefix: str,
              scalars: dict[str, Any]) -> np.ndarray[Any, Any] | None:
        points = None
        for field, (kind, desc) in self._fields(msgtype):
            path = prefix + str(field)
            kind = int(kind)
            if kind == _BASE:
                scalars[path] = c.string() if desc[0] == "string" else c.primitive(_PRIMITIVES[desc[0]])
            elif kind == _NAME:
                self._walk(c, str(desc), path + ".", scalars)
            elif kind in (_ARRAY, _SEQUENCE):
                sub_kind, sub = int(desc[0][0]), desc[0][1]
                count = int(desc[1]) if kind == _ARRAY else c.primitive("u4")
                if prefix == "" and field == self.points_field:
                    points = self._points(c, count)
                elif sub_kind == _BASE and sub[0] in _PRIMITIVES:
                    size = int(_PRIMITIVES[sub[0]][1])
                    c.align(size)
                    if c.pos + count * size > len(c.buf):
                        raise IndexError(f"{path} runs past the end")
                    c.pos += count * size
                else:
                    for k in range(count):
                        if sub_kind == _BASE:
                            c.string()
                        else:
                            self._walk(c, str(sub), f"{path}[{k}].", {})
        return points

    def _points(self, c: _Cursor, count: int) -> np.ndarray[Any, Any]:
        """The point sequence as a structured view of the bytes (CDR aligns each field to its
        size, counted from the stream's start; ROS 1 packs)."""
        if count == 0:
            return np.zeros(0, self._dtype(c, 0)[0])
        dtype, first, stride = self._dtype(c, c.pos)
        end = first + (count - 1) * stride + dtype.itemsize
        if end > len(c.buf):
            raise IndexError(f"{count} points run past the end of the message")
        view = np.ndarray((count,), dtype=dtype, buffer=c.buf, offset=first, strides=(stride,))
        c.pos = end
        return view

    def _dtype(self, c: _Cursor, pos: int) -> tuple[np.dtype[Any], int, int]:
        """Dtype of one point (itemsize to its last field), its first byte and the stride."""

        def layout(start: int) -> tuple[list[int], int]:
            offsets, p = [], start
            for _, code in self._element:
                size = int(code[1])
                if self.cdr:
                    p += (-(p - c.base)) % size
                offsets.append(p)
                p += size
            return offsets, p

        offsets0, end0 = layout(pos)
        first_size = int(self._element[0][1][1])
        nxt = end0 + ((-(end0 - c.base)) % first_size if self.cdr else 0)
        offsets1, _ = layout(nxt)
        rel0 = [o - offsets0[0] for o in offsets0]
        rel1 = [o - offsets1[0] for o in offsets1]
        if rel0 != rel1:
            # The struct's padding changes from point to point (a float64 behind an odd
            # offset): not one view. No lidar driver's points are laid out so.
            raise DecodeError(f"{self.msgtype}: its points are not evenly laid out in CDR", self.where)
        order = c.order
        dtype = np.dtype({"names": [n for n, _ in self._element],
                          "formats": [order + code for _, code in self._element],
                          "offsets": rel0, "itemsize": end0 - offsets0[0]})
        return dtype, offsets0[0], offsets1[0] - offsets0[0]


def stamp_ns_of_scalars(scalars: dict[str, Any]) -> int:
    sec = scalars.get("header.stamp.sec", 0)
    nanosec = scalars.get("header.stamp.nanosec", scalars.get("header.stamp.nsec", 0))
    return int(sec) * 1_000_000_000 + int(nanosec)


def points_of(msg: PointMessage, drop_zero: bool = True) -> DecodedPoints:
    """The kept points (finite, and not exactly at the origin with `drop_zero`) and the raw
    values of each candidate time field, the time base plus offset included."""
    pts = msg.points
    names = pts.dtype.names or ()
    x = pts["x"].astype(np.float32)
    y = pts["y"].astype(np.float32)
    z = pts["z"].astype(np.float32)
    r2 = x * x + y * y + z * z
    keep = (r2 < np.inf) & (r2 > 0) if drop_zero else np.isfinite(r2)
    idx = np.flatnonzero(keep)
    xyz = np.empty((len(idx), 3), np.float32)
    xyz[:, 0], xyz[:, 1], xyz[:, 2] = x[idx], y[idx], z[idx]
    intensity = next((pts[n][idx].astype(np.float32) for n in INTENSITY_FIELDS if n in names), None)
    ring = next((pts[n][idx].astype(np.uint16) for n in RING_FIELDS if n in names), None)
    times: dict[str, np.ndarray[Any, Any]] = {}
    timebase = msg.scalars.get("timebase")
    if timebase is not None and "offset_time" in names:
        times[TIMEBASE_FIELD] = np.uint64(timebase) + pts["offset_time"][idx].astype(np.uint64)
    for name in TIME_FIELDS:
        if name in names:
            times[name] = pts[name][idx].astype(pts[name].dtype.newbyteorder("="))
    return DecodedPoints(xyz, intensity, ring, times)


def frame_of(msg: PointMessage) -> str:
    return str(msg.scalars.get("header.frame_id", ""))
