"""ROS 1 `.bag` files (plain, bz2, lz4) and ROS 2 sqlite3 bag folders, read with rosbags."""

from __future__ import annotations

import heapq
import sqlite3
import struct
from collections.abc import Collection, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Reader as Reader1
from rosbags.rosbag1.reader import decompressors as rosbag1_decompressors
from rosbags.typesys import Stores, get_typestore

from mfmap.errors import DecodeError, LogError
from mfmap.ingest.backend import RawMessage, RawTopic, map_file_range, normalise_msgtype

ROS1_MAGIC = b"#ROSBAG V2.0\n"


def sqlite_files(folder: Path) -> list[Path]:
    """The .db3 files of an uncompressed sqlite3 bag in metadata order ([] otherwise)."""
    try:
        info = yaml.safe_load((folder / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    except Exception:  # rosbags reports a broken metadata.yaml at open
        return []
    if info.get("storage_identifier") != "sqlite3" or info.get("compression_mode"):
        return []
    files = [
        folder / str(f) if (folder / str(f)).is_file() else folder / Path(str(f)).name
        for f in info.get("relative_file_paths") or []
    ]
    return files if files and all(f.is_file() for f in files) else []


def check_bag_file(path: Path) -> None:
    if not path.exists():
        raise LogError("no such file", path)
    if path.stat().st_size == 0:
        raise LogError("empty file (0 bytes), not a ROS 1 bag", path)
    with path.open("rb") as f:
        head = f.read(len(ROS1_MAGIC))
    if head != ROS1_MAGIC:
        raise LogError("not a ROS 1 bag (missing the '#ROSBAG V2.0' header)", path)


def check_bag_index(path: Path) -> None:
    """Walk the records of a ROS 1 bag's index section, bounded by the file, before rosbags
    reads it: rosbags allocates whatever length a record claims, so a damaged index position
    once cost 1.7 GB for a 97 kB bag. A damaged index is a LogError with a cause (the caller
    then reads the bag front to back)."""
    from mfmap.ingest.ros1_recover import OP_BAG_HEADER, _read_record

    size = path.stat().st_size
    with path.open("rb") as f:
        try:
            fields, _, _ = _read_record(f, len(ROS1_MAGIC), size)
            if fields.get("op") != bytes([OP_BAG_HEADER]) or len(fields.get("index_pos", b"")) != 8:
                raise ValueError("no bag header record")
            (index_pos,) = struct.unpack("<Q", fields["index_pos"])
            if index_pos == 0:
                return  # not indexed: rosbags says so
            if index_pos > size:
                raise ValueError(f"index position {index_pos} beyond the file's {size} bytes")
            pos = index_pos
            while pos < size:
                _, start, length = _read_record(f, pos, size)
                pos = start + length
        except (ValueError, struct.error) as err:
            raise LogError(f"cannot read the bag: Bag index looks damaged: {err}", path) from err


class RosbagsBackend:
    """A ROS 1 bag or a ROS 2 sqlite3 bag folder via rosbags' AnyReader."""

    def __init__(self, path: Path, fmt: str) -> None:
        self.format = fmt
        self.path = path
        self.warnings: list[str] = []
        if fmt == "ros1":
            check_bag_file(path)
            check_bag_index(path)
        self._db_files = sqlite_files(path) if fmt == "ros2" else []
        # ROS 2 bags written before Iron carry no message definitions: fall back to the
        # standard definitions for the common types.
        default = get_typestore(Stores.LATEST) if fmt == "ros2" else None
        self.reader = AnyReader([path], default_typestore=default)
        try:
            self.reader.open()
        except Exception as err:
            raise LogError(f"cannot read the bag: {_first_line(err)}", path) from err
        try:
            self.topics = self._topics()
        except Exception:
            self.reader.close()
            raise

    def _topics(self) -> dict[str, RawTopic]:
        topics: dict[str, RawTopic] = {}
        for conn in self.reader.connections:
            t = topics.setdefault(conn.topic, RawTopic(conn.topic, normalise_msgtype(conn.msgtype), 0, None, None))
            t.count += int(conn.msgcount)
        first_last = self._first_last()
        for conn in self.reader.connections:
            fl = first_last.get(conn.topic)
            if fl is not None:
                t = topics[conn.topic]
                t.first_ns = fl[0] if t.first_ns is None else min(t.first_ns, fl[0])
                t.last_ns = fl[1] if t.last_ns is None else max(t.last_ns, fl[1])
        return topics

    def _first_last(self) -> dict[str, tuple[int, int]]:
        """Per-topic first/last log time from the bag's indexes (no message data read)."""
        out: dict[str, tuple[int, int]] = {}

        def add(topic: str, lo: int, hi: int) -> None:
            if topic in out:
                lo, hi = min(lo, out[topic][0]), max(hi, out[topic][1])
            out[topic] = (lo, hi)

        for sub in self.reader.readers:
            if isinstance(sub, Reader1):
                for conn in sub.connections:
                    index = sub.indexes.get(conn.id)
                    if index:
                        add(conn.topic, int(index[0].time), int(index[-1].time))
            else:
                for db in self._db_files:
                    try:
                        con = _connect(db)
                        rows = con.execute(
                            "SELECT topics.name, min(messages.timestamp), max(messages.timestamp) "
                            "FROM messages JOIN topics ON messages.topic_id = topics.id "
                            "GROUP BY topics.name"
                        ).fetchall()
                        con.close()
                    except sqlite3.Error as err:
                        raise LogError(f"cannot read sqlite3 storage: {err}", db) from err
                    for name, lo, hi in rows:
                        if lo is not None:
                            add(str(name), int(lo), int(hi))
        return out

    def log_times(self, topic: str) -> np.ndarray[Any, np.dtype[np.int64]] | None:
        """Log times of the topic's messages in recording order, from the indexes (None where
        only reading every message would tell)."""
        parts: list[np.ndarray[Any, np.dtype[np.int64]]] = []
        if self._db_files:
            for db in self._db_files:
                try:
                    con = _connect(db)
                    rows = con.execute(
                        "SELECT messages.timestamp FROM messages JOIN topics ON "
                        "messages.topic_id = topics.id WHERE topics.name = ? ORDER BY messages.id",
                        (topic,),
                    ).fetchall()
                    con.close()
                except sqlite3.Error as err:
                    raise LogError(f"cannot read sqlite3 storage: {err}", db) from err
                parts.append(np.array([r[0] for r in rows], dtype=np.int64))
            return np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)
        for sub in self.reader.readers:
            if not isinstance(sub, Reader1):
                return None
            entries = [e for c in sub.connections if c.topic == topic for e in sub.indexes.get(c.id, [])]
            if entries:
                table = np.array([(e.chunk_pos, e.offset, e.time) for e in entries], dtype=np.int64)
                parts.append(table[np.lexsort((table[:, 1], table[:, 0])), 2])
        return np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)

    def iter_raw(
        self, topics: Collection[str], start_ns: int | None, end_ns: int | None
    ) -> Iterator[RawMessage]:
        conns = [c for c in self.reader.connections if c.topic in topics]
        if not conns:
            return
        if self._db_files:
            yield from self._iter_sqlite(conns, start_ns, end_ns)
            return
        stop = None if end_ns is None else end_ns + 1
        subs = self.reader.readers
        messages = (
            _iter_ros1(subs[0], conns, start_ns, stop)
            if len(subs) == 1 and isinstance(subs[0], Reader1)
            else self.reader.messages(connections=conns, start=start_ns, stop=stop)
        )
        try:
            for conn, t, raw in messages:
                yield RawMessage(conn.topic, int(t), (conn, raw))
        except LogError:
            raise
        except Exception as err:
            raise LogError(f"cannot read messages: {_first_line(err)}", self.path) from err

    def _iter_sqlite(
        self, conns: list[Any], start_ns: int | None, end_ns: int | None
    ) -> Iterator[RawMessage]:
        """Read sqlite3 storage directly: rosbags matches connections by QoS profile too, and
        drops every message of a bag whose metadata.yaml and database disagree on QoS."""
        by_topic = {c.topic: c for c in conns}
        query = (
            "SELECT topics.name, messages.timestamp, messages.data FROM messages "
            "JOIN topics ON messages.topic_id = topics.id "
            f"WHERE topics.name IN ({','.join('?' for _ in by_topic)}) "
            "AND messages.timestamp >= ? AND messages.timestamp <= ? ORDER BY messages.timestamp"
        )
        args = [*by_topic, start_ns if start_ns is not None else -(2**63), end_ns if end_ns is not None else 2**63 - 1]

        def one(db: Path) -> Iterator[RawMessage]:
            con = _connect(db)
            try:
                for name, t, data in con.execute(query, args):
                    yield RawMessage(name, int(t), (by_topic[name], data))
            except sqlite3.Error as err:
                raise LogError(f"cannot read sqlite3 storage: {err}", db) from err
            finally:
                con.close()

        iters = [one(db) for db in self._db_files]
        yield from (iters[0] if len(iters) == 1 else heapq.merge(*iters, key=lambda m: m.log_time_ns))

    def deserialize(self, message: RawMessage) -> Any:
        conn, raw = message.payload
        try:
            return self.reader.deserialize(raw, conn.msgtype)
        except Exception as err:
            raise DecodeError(
                f"cannot deserialise a '{conn.msgtype}' message: {_first_line(err)}",
                f"{self.path} topic {conn.topic}",
            ) from err

    def typestore(self, message: RawMessage) -> Any:
        return self.reader.typestore

    def raw_size(self, message: RawMessage) -> int:
        return len(message.payload[1])

    def serialized(self, message: RawMessage) -> tuple[str, Any]:
        return ("ros1" if self.format == "ros1" else "cdr"), message.payload[1]

    def close(self) -> None:
        if self.reader.stack is not None:
            self.reader.close()


_ROS1_NO_COMPRESSION = rosbag1_decompressors["none"]
_OP_MSG_DATA, _OP_CONNECTION = 2, 7
_U32 = struct.Struct("<I")


def _iter_ros1(
    reader: Reader1, conns: list[Any], start_ns: int | None, stop_ns: int | None
) -> Iterator[tuple[Any, int, memoryview]]:
    """Reader1.messages() with each message a zero-copy view into its chunk.

    The same index walk and order as rosbags; an uncompressed chunk is memory-mapped instead of
    read, and no message is copied out of its chunk (rosbags copies every chunk twice).
    """
    connmap = {c.id: c for c in reader.connections}
    wanted = {c.id for c in conns}
    indexes = [reader.indexes[cid] for cid in sorted(wanted)]
    chunk_pos, chunk = -1, memoryview(b"")
    with reader.path.open("rb") as f:
        for entry in heapq.merge(*indexes):
            if start_ns is not None and entry.time < start_ns:
                continue
            if stop_ns is not None and entry.time >= stop_ns:
                return
            if entry.chunk_pos != chunk_pos:
                info = reader.chunks[entry.chunk_pos]
                if info.decompressor is _ROS1_NO_COMPRESSION:
                    chunk = map_file_range(f, info.datapos, info.datasize)
                else:
                    f.seek(info.datapos)
                    chunk = memoryview(info.decompressor(f.read(info.datasize)))
                chunk_pos = entry.chunk_pos
            pos = entry.offset
            while True:  # connection records may precede the message
                (hlen,) = _U32.unpack_from(chunk, pos)
                fields = _record_fields(chunk[pos + 4 : pos + 4 + hlen])
                (dlen,) = _U32.unpack_from(chunk, pos + 4 + hlen)
                data_at = pos + 8 + hlen
                if data_at + dlen > len(chunk):
                    raise ValueError(f"message record runs past the end of the chunk at {chunk_pos}")
                op = fields.get("op", b"\x00")[0]
                if op != _OP_CONNECTION:
                    break
                pos = data_at + dlen
            if op != _OP_MSG_DATA:
                raise ValueError(f"no message data at offset {entry.offset} of the chunk at {chunk_pos}")
            conn = connmap[_U32.unpack(fields["conn"])[0]]
            yield conn, entry.time, chunk[data_at : data_at + dlen]


def _record_fields(header: memoryview) -> dict[str, bytes]:
    out: dict[str, bytes] = {}
    pos = 0
    while pos < len(header):
        (n,) = _U32.unpack_from(header, pos)
        name, _, value = bytes(header[pos + 4 : pos + 4 + n]).partition(b"=")
        out[name.decode("ascii", errors="replace")] = value
        pos += 4 + n
    return out


def _connect(db: Path) -> sqlite3.Connection:
    # immutable: never touch the -wal/-shm files of a bag we only read (they may be read-only).
    return sqlite3.connect(f"file:{db}?immutable=1", uri=True)


def _first_line(err: BaseException) -> str:
    text = str(err).strip() or err.__class__.__name__
    return text.splitlines()[0]
