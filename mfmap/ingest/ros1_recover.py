"""Front-to-back reading of a ROS 1 bag whose index is damaged or missing.

A recorder that dies (power cut, full disk, kill -9) leaves a bag without its index; rosbags,
like rosbag, then refuses it. The records before the damage are intact, so this reader walks
them in file order (decompressing bz2/lz4 chunks, one at a time), keeps a small in-memory index
of where each message sits, and serves messages from it, like `rosbag reindex` would after the
fact. Memory is bounded by one chunk plus the index, whatever the size of the bag.
"""

from __future__ import annotations

import bz2
import struct
from collections.abc import Collection, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from mfmap.errors import DecodeError, LogError
from mfmap.ingest.backend import RawMessage, RawTopic, normalise_msgtype

ROS1_MAGIC = b"#ROSBAG V2.0\n"
OP_MSG_DATA, OP_BAG_HEADER, OP_INDEX_DATA, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION = 2, 3, 4, 5, 6, 7
# A record claiming more than this is a damaged length field.
MAX_RECORD_BYTES = 1 << 30


@dataclass
class _Conn:
    topic: str
    msgtype: str
    msgdef: str


@dataclass
class _Scan:
    conns: dict[int, _Conn] = field(default_factory=dict)
    # (time_ns, order, conn, chunk file position or -1, offset of the data, length)
    messages: list[tuple[int, int, int, int, int, int]] = field(default_factory=list)
    chunks: dict[int, tuple[str, int, int]] = field(default_factory=dict)  # pos -> (compr, start, len)
    damage: str | None = None


def _fields(header: bytes) -> dict[str, bytes]:
    out: dict[str, bytes] = {}
    pos = 0
    while pos < len(header):
        (n,) = struct.unpack_from("<I", header, pos)
        pos += 4
        if pos + n > len(header):
            raise ValueError("header field runs past the header")
        name, _, value = header[pos : pos + n].partition(b"=")
        out[name.decode("ascii", errors="replace")] = value
        pos += n
    return out


def _records(data: bytes | memoryview, start: int, end: int) -> Iterator[tuple[dict[str, bytes], int, int]]:
    """(header fields, data offset, data length) of each record in data[start:end]."""
    pos = start
    while pos < end:
        if pos + 4 > end:
            raise ValueError(f"record header length cut off at byte {pos}")
        (hlen,) = struct.unpack_from("<I", data, pos)
        if hlen > MAX_RECORD_BYTES or pos + 4 + hlen + 4 > end:
            raise ValueError(f"record header cut off at byte {pos}")
        header = bytes(data[pos + 4 : pos + 4 + hlen])
        (dlen,) = struct.unpack_from("<I", data, pos + 4 + hlen)
        dstart = pos + 8 + hlen
        if dlen > MAX_RECORD_BYTES or dstart + dlen > end:
            raise ValueError(f"record data cut off at byte {pos}")
        yield _fields(header), dstart, dlen
        pos = dstart + dlen


def _decompress(compression: str, data: bytes) -> bytes:
    if compression == "none":
        return data
    if compression == "bz2":
        return bz2.decompress(data)
    if compression == "lz4":
        import lz4.frame

        return bytes(lz4.frame.decompress(data))
    raise ValueError(f"unknown chunk compression '{compression}'")


def _read_record(f: BinaryIO, pos: int, end: int) -> tuple[dict[str, bytes], int, int]:
    """(header fields, data offset, data length) of the top-level record at file offset `pos`."""
    f.seek(pos)
    head = f.read(4)
    if len(head) < 4:
        raise ValueError(f"record header length cut off at byte {pos}")
    (hlen,) = struct.unpack("<I", head)
    if hlen > MAX_RECORD_BYTES or pos + 4 + hlen + 4 > end:
        raise ValueError(f"record header cut off at byte {pos}")
    header = f.read(hlen)
    (dlen,) = struct.unpack("<I", f.read(4))
    dstart = pos + 8 + hlen
    if dlen > MAX_RECORD_BYTES or dstart + dlen > end:
        raise ValueError(f"record data cut off at byte {pos}")
    return _fields(header), dstart, dlen


def _scan(path: Path) -> _Scan:
    """Walk the bag record by record; only one chunk is in memory at a time."""
    out = _Scan()
    order = 0

    def add_record(fields: dict[str, bytes], buf: bytes | memoryview, dstart: int, dlen: int, chunk_pos: int) -> None:
        nonlocal order
        op = fields.get("op", b"\x00")[0]
        if op == OP_CONNECTION:
            conn = struct.unpack("<I", fields["conn"])[0]
            info = _fields(bytes(buf[dstart : dstart + dlen]))
            out.conns.setdefault(
                conn,
                _Conn(
                    topic=fields.get("topic", info.get("topic", b"")).decode(),
                    msgtype=info.get("type", b"").decode(),
                    msgdef=info.get("message_definition", b"").decode(),
                ),
            )
        elif op == OP_MSG_DATA:
            conn = struct.unpack("<I", fields["conn"])[0]
            sec, nsec = struct.unpack("<II", fields["time"])
            out.messages.append((sec * 1_000_000_000 + nsec, order, conn, chunk_pos, dstart, dlen))
            order += 1

    size = path.stat().st_size
    with path.open("rb") as f:
        pos = len(ROS1_MAGIC)
        try:
            while pos < size:
                fields, dstart, dlen = _read_record(f, pos, size)
                op = fields.get("op", b"\x00")[0]
                if op == OP_CHUNK:
                    compression = fields.get("compression", b"none").decode()
                    f.seek(dstart)
                    raw = _decompress(compression, f.read(dlen))
                    out.chunks[dstart] = (compression, dstart, dlen)
                    for inner, istart, ilen in _records(raw, 0, len(raw)):
                        add_record(inner, raw, istart, ilen, dstart)
                elif op == OP_CONNECTION:
                    f.seek(dstart)
                    add_record(fields, f.read(dlen), 0, dlen, -1)
                elif op == OP_MSG_DATA:
                    add_record(fields, b"", dstart, dlen, -1)
                pos = dstart + dlen
        except Exception as err:  # the readable part of the bag ends at the first damage
            out.damage = f"{err.__class__.__name__}: {err}"
    return out


class Ros1RecoveryBackend:
    """A ROS 1 bag read front to back, for bags whose index rosbags cannot read."""

    def __init__(self, path: Path, reason: str) -> None:
        self.format = "ros1"
        self.path = path
        scan = _scan(path)
        if not scan.conns and not scan.messages:
            raise LogError(f"cannot read the bag: {reason}; no intact records before the damage", path)
        self._scan = scan
        self._chunk_cache: tuple[int, bytes] | None = None
        self._store = get_typestore(Stores.EMPTY)
        self._registered: set[str] = set()
        self.topics: dict[str, RawTopic] = {}
        for c in scan.conns.values():
            self.topics.setdefault(c.topic, RawTopic(c.topic, normalise_msgtype(c.msgtype), 0, None, None))
        for t, _order, cid, *_ in scan.messages:
            conn = scan.conns.get(cid)
            if conn is None:
                continue
            topic = self.topics[conn.topic]
            topic.count += 1
            topic.first_ns = t if topic.first_ns is None else min(topic.first_ns, t)
            topic.last_ns = t if topic.last_ns is None else max(topic.last_ns, t)
        times = [m[0] for m in scan.messages]
        covered = (max(times) - min(times)) / 1e9 if times else 0.0
        self.warnings = [
            f"{path}: bag index unreadable ({reason}); read front to back: recovered "
            f"{len(scan.messages)} messages covering {covered:.1f} s of log time"
            + (f" before the damage ({scan.damage})" if scan.damage else "")
        ]

    def _data(self, chunk_pos: int, start: int, length: int) -> bytes:
        if chunk_pos < 0:
            with self.path.open("rb") as f:
                f.seek(start)
                return f.read(length)
        if self._chunk_cache is None or self._chunk_cache[0] != chunk_pos:
            compression, cstart, clen = self._scan.chunks[chunk_pos]
            with self.path.open("rb") as f:
                f.seek(cstart)
                self._chunk_cache = (chunk_pos, _decompress(compression, f.read(clen)))
        return self._chunk_cache[1][start : start + length]

    def log_times(self, topic: str) -> np.ndarray[Any, np.dtype[np.int64]]:
        """Log times of the topic's messages in recording order."""
        wanted = {cid for cid, c in self._scan.conns.items() if c.topic == topic}
        return np.array([m[0] for m in self._scan.messages if m[2] in wanted], dtype=np.int64)

    def iter_raw(
        self, topics: Collection[str], start_ns: int | None, end_ns: int | None
    ) -> Iterator[RawMessage]:
        wanted = {cid for cid, c in self._scan.conns.items() if c.topic in topics}
        selected = [
            m
            for m in self._scan.messages
            if m[2] in wanted
            and (start_ns is None or m[0] >= start_ns)
            and (end_ns is None or m[0] <= end_ns)
        ]
        for t, _order, cid, chunk_pos, start, length in sorted(selected):
            conn = self._scan.conns[cid]
            yield RawMessage(conn.topic, t, (conn, self._data(chunk_pos, start, length)))

    def typestore(self, message: RawMessage) -> Any:
        self._register(message)
        return self._store

    def _register(self, message: RawMessage) -> str:
        conn, _raw = message.payload
        name = normalise_msgtype(conn.msgtype)
        where = f"{self.path} topic {conn.topic}"
        if name not in self._registered:
            if not conn.msgdef:
                raise DecodeError(f"message type '{name}' has no definition", where)
            try:
                self._store.register(get_types_from_msg(conn.msgdef, name))
            except Exception as err:
                raise DecodeError(f"cannot parse the message definition of '{name}': {err}", where) from err
            self._registered.add(name)
        return name

    def deserialize(self, message: RawMessage) -> Any:
        conn, raw = message.payload
        where = f"{self.path} topic {conn.topic}"
        name = self._register(message)
        try:
            return self._store.deserialize_ros1(raw, name)
        except Exception as err:
            raise DecodeError(f"cannot deserialise a '{name}' message: {err}", where) from err

    def raw_size(self, message: RawMessage) -> int:
        return len(message.payload[1])

    def serialized(self, message: RawMessage) -> tuple[str, Any]:
        return "ros1", message.payload[1]

    def close(self) -> None:
        self._chunk_cache = None
