"""MCAP reader: one or several `.mcap` files (a single log, a ROS 2 bag with mcap storage, or a
folder of `.mcap` files), ROS 2 CDR or ROS 1 message encodings.

Two ways through a file, chosen at open:
- indexed: the summary has every channel and chunk indexes with message indexes. Counts and
  first/last times come from the message indexes (checked against the statistics), a query for
  one topic and time window only maps (and decompresses) the chunks that hold it, and hands out
  each message as a zero-copy view into its chunk, in the order mcap's SeekingReader gives.
- sequential: anything else (no summary, channels defined only inside chunks, unindexed,
  truncated or corrupt). The file is scanned once at open, as far as it is intact, and queries
  read it front to back again, stopping at the damage.
"""

from __future__ import annotations

import heapq
import io
import logging
import os
import struct
from array import array
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import SeekingReader
from mcap.records import (
    Channel,
    ChunkIndex,
    DataEnd,
    Footer,
    Message,
    MessageIndex,
    Schema,
)
from mcap.stream_reader import StreamReader
from mcap.summary import Summary
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from mfmap.errors import DecodeError, LogError
from mfmap.ingest.backend import RawMessage, RawTopic, map_file_range, normalise_msgtype

logger = logging.getLogger(__name__)

MCAP_MAGIC = b"\x89MCAP0\r\n"
# Records larger than this are corrupt lengths, not data (mcap's own default is 4 GiB, which a
# damaged length field would make us try to allocate).
RECORD_SIZE_LIMIT = 1 << 30


def _size_limit(f: Any) -> int:
    """No record is longer than the file that holds it: a damaged length field must not make a
    read allocate up to the limit (420 MB for a 90-byte file)."""
    try:
        return max(1, min(RECORD_SIZE_LIMIT, os.fstat(f.fileno()).st_size))
    except (OSError, AttributeError, io.UnsupportedOperation):
        return RECORD_SIZE_LIMIT


def check_mcap_file(path: Path) -> None:
    """Reject a missing, empty or non-MCAP file with one clear line."""
    if not path.exists():
        raise LogError("no such file", path)
    size = path.stat().st_size
    if size == 0:
        raise LogError("empty file (0 bytes), not an MCAP log", path)
    with path.open("rb") as f:
        head = f.read(len(MCAP_MAGIC))
    if head != MCAP_MAGIC:
        raise LogError("not an MCAP file (the file does not start with the MCAP magic bytes)", path)


@dataclass
class _FileIndex:
    """What the open-time pass learned about one file."""

    path: Path
    indexed: bool
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    chunk_indexes: list[ChunkIndex] = field(default_factory=list)
    counts: dict[int, int] = field(default_factory=dict)
    first_ns: dict[int, int] = field(default_factory=dict)
    last_ns: dict[int, int] = field(default_factory=dict)
    in_order: bool = True
    damaged: str | None = None  # what went wrong, for the warning
    recovered: int = 0  # messages read before the damage
    # Per channel, blocks of (chunk offset, offset in the chunk, log time): recording order.
    times: dict[int, list[np.ndarray[Any, np.dtype[np.int64]]]] = field(default_factory=dict)


class _Decoders:
    """rosbags typestores built from the schemas in the log, one per message encoding."""

    def __init__(self, path: Path, ros2_fallback: bool) -> None:
        self.path = path
        self.stores: dict[str, Typestore] = {}
        self.registered: dict[tuple[str, str], Callable[[Any], Any]] = {}
        self.store_of: dict[tuple[str, str], Typestore] = {}
        self.ros2_fallback = ros2_fallback

    def get(self, schema: Schema | None, channel: Channel) -> Callable[[Any], Any]:
        encoding = channel.message_encoding
        name = normalise_msgtype(schema.name) if schema is not None else ""
        key = (encoding, name)
        fn = self.registered.get(key)
        if fn is not None:
            return fn
        where = f"{self.path} topic {channel.topic}"
        if encoding not in ("cdr", "ros1"):
            raise DecodeError(f"message encoding '{encoding}' is not ROS 1 or ROS 2 CDR", where)
        store = self.stores.get(encoding)
        if store is None:
            store = get_typestore(Stores.EMPTY)
            self.stores[encoding] = store
        if schema is None or not schema.data:
            fallback = get_typestore(Stores.LATEST) if encoding == "cdr" else None
            if fallback is None or not name or name not in fallback.fielddefs:
                raise DecodeError(f"message type '{name or '?'}' has no definition", where)
            store = fallback
        elif name not in store.fielddefs:
            if schema.encoding not in ("ros2msg", "ros1msg"):
                raise DecodeError(
                    f"schema encoding '{schema.encoding}' is not supported (need ros2msg/ros1msg)",
                    where,
                )
            try:
                store.register(get_types_from_msg(schema.data.decode("utf-8"), name))
            except Exception as err:
                raise DecodeError(
                    f"cannot parse the message definition of '{name}': {_first_line(err)}", where
                ) from err
        deser = store.deserialize_cdr if encoding == "cdr" else store.deserialize_ros1

        def decode(data: Any) -> Any:
            try:
                return deser(data, name)
            except Exception as err:
                raise DecodeError(f"cannot deserialise a '{name}' message: {_first_line(err)}", where) from err

        self.registered[key] = decode
        self.store_of[key] = store
        return decode


class McapBackend:
    """One log made of one or more MCAP files, merged in log-time order."""

    def __init__(self, paths: list[Path], fmt: str = "mcap") -> None:
        self.format = fmt
        self.paths = paths
        self.warnings: list[str] = []
        self.files: list[_FileIndex] = []
        for p in paths:
            check_mcap_file(p)
            self.files.append(_index_file(p))
        self._decoders = _Decoders(paths[0], ros2_fallback=True)
        self.topics: dict[str, RawTopic] = {}
        for fi in self.files:
            for cid, ch in fi.channels.items():
                schema = fi.schemas.get(ch.schema_id)
                msgtype = normalise_msgtype(schema.name) if schema is not None else ""
                topic = self.topics.setdefault(ch.topic, RawTopic(ch.topic, msgtype, 0, None, None))
                if not topic.msgtype:
                    topic.msgtype = msgtype
                topic.count += fi.counts.get(cid, 0)
                if cid in fi.first_ns:
                    f, last = fi.first_ns[cid], fi.last_ns[cid]
                    topic.first_ns = f if topic.first_ns is None else min(topic.first_ns, f)
                    topic.last_ns = last if topic.last_ns is None else max(topic.last_ns, last)
            if fi.damaged is not None:
                covered = _span_s(fi)
                self.warnings.append(
                    f"{fi.path}: damaged or truncated ({fi.damaged}); recovered {fi.recovered} "
                    f"messages covering {covered:.1f} s of log time before the damage"
                )

    def iter_raw(
        self, topics: Collection[str], start_ns: int | None, end_ns: int | None
    ) -> Iterator[RawMessage]:
        iters = [_iter_file(fi, set(topics), start_ns, end_ns) for fi in self.files]
        if len(iters) == 1:
            return iters[0]
        return heapq.merge(*iters, key=lambda m: m.log_time_ns)

    def log_times(self, topic: str) -> np.ndarray[Any, np.dtype[np.int64]] | None:
        """Log times of the topic's messages in recording order (file, then place in it)."""
        parts = []
        for fi in self.files:
            blocks = [b for cid, ch in fi.channels.items() if ch.topic == topic
                      for b in fi.times.get(cid, [])]
            if blocks:
                rows = np.concatenate(blocks)
                parts.append(rows[np.lexsort((rows[:, 1], rows[:, 0])), 2])
        return np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)

    def deserialize(self, message: RawMessage) -> Any:
        schema, channel, data = message.payload
        return self._decoders.get(schema, channel)(data)

    def typestore(self, message: RawMessage) -> Typestore:
        schema, channel, _data = message.payload
        self._decoders.get(schema, channel)
        name = normalise_msgtype(schema.name) if schema is not None else ""
        return self._decoders.store_of[(channel.message_encoding, name)]

    def raw_size(self, message: RawMessage) -> int:
        return len(message.payload[2])

    def serialized(self, message: RawMessage) -> tuple[str, Any]:
        _schema, channel, data = message.payload
        return channel.message_encoding, data

    def close(self) -> None:
        pass


def _first_line(err: BaseException) -> str:
    text = str(err).strip() or err.__class__.__name__
    return text.splitlines()[0]


def _span_s(fi: _FileIndex) -> float:
    if not fi.first_ns:
        return 0.0
    return (max(fi.last_ns.values()) - min(fi.first_ns.values())) / 1e9


def _index_file(path: Path) -> _FileIndex:
    with path.open("rb") as f:
        summary = _usable_summary(f)
        if summary is not None:
            fi = _FileIndex(path, indexed=True, schemas=dict(summary.schemas),
                            channels=dict(summary.channels),
                            chunk_indexes=list(summary.chunk_indexes))
            if _read_message_indexes(f, summary, fi):
                return fi
        f.seek(0)
        return _scan_file(f, path)


def _usable_summary(f: io.BufferedReader) -> Summary | None:
    """The summary, if it is complete enough to answer queries without a full scan."""
    try:
        summary = SeekingReader(f, record_size_limit=_size_limit(f)).get_summary()
    except Exception:  # no readable footer/summary: scan the file instead
        return None
    if summary is None or not summary.chunk_indexes:
        return None
    for ci in summary.chunk_indexes:
        if not ci.message_index_offsets or ci.compression not in _DECOMPRESS:
            return None
        if any(cid not in summary.channels for cid in ci.message_index_offsets):
            return None
    if summary.statistics is not None and any(
        cid not in summary.channels for cid in summary.statistics.channel_message_counts
    ):
        return None
    for ch in summary.channels.values():
        if ch.schema_id != 0 and ch.schema_id not in summary.schemas:
            return None
    return summary


def _read_message_indexes(f: io.BufferedReader, summary: Summary, fi: _FileIndex) -> bool:
    """Per-channel counts and first/last log time from the message index records."""
    try:
        for ci in summary.chunk_indexes:
            for cid, offset in ci.message_index_offsets.items():
                f.seek(offset)
                record = next(StreamReader(f, skip_magic=True,
                                           record_size_limit=_size_limit(f)).records)
                if not isinstance(record, MessageIndex) or record.channel_id != cid:
                    return False
                if not record.records:
                    continue
                times = [t for t, _ in record.records]
                fi.counts[cid] = fi.counts.get(cid, 0) + len(times)
                lo, hi = min(times), max(times)
                block = np.empty((len(times), 3), dtype=np.int64)
                block[:, 0] = ci.chunk_start_offset
                block[:, 1:] = np.array(record.records, dtype=np.uint64).astype(np.int64)[:, ::-1]
                fi.times.setdefault(cid, []).append(block)
                fi.first_ns[cid] = min(fi.first_ns.get(cid, lo), lo)
                fi.last_ns[cid] = max(fi.last_ns.get(cid, hi), hi)
    except Exception:  # a broken index: fall back to a sequential scan
        return False
    if summary.statistics is None:
        return True  # nothing to check the indexes against
    stats = summary.statistics.channel_message_counts
    # Messages outside chunks are invisible to the indexes; then only a scan gives the truth.
    return all(fi.counts.get(cid, 0) == n for cid, n in stats.items()) and sum(
        fi.counts.values()
    ) == summary.statistics.message_count


def _records(f: Any) -> Iterator[Any]:
    return StreamReader(f, skip_magic=False, record_size_limit=_size_limit(f)).records


def _scan_file(f: io.BufferedReader, path: Path) -> _FileIndex:
    fi = _FileIndex(path, indexed=False)
    last_time = -1
    seen: dict[int, array[int]] = {}
    try:
        for record in _records(f):
            if isinstance(record, Schema):
                fi.schemas[record.id] = record
            elif isinstance(record, Channel):
                fi.channels[record.id] = record
            elif isinstance(record, Message):
                cid = record.channel_id
                if cid not in fi.channels:
                    raise McapError(f"message on channel {cid} before its Channel record")
                t = record.log_time
                seen.setdefault(cid, array("q")).append(t)
                fi.counts[cid] = fi.counts.get(cid, 0) + 1
                fi.first_ns[cid] = min(fi.first_ns.get(cid, t), t)
                fi.last_ns[cid] = max(fi.last_ns.get(cid, t), t)
                if t < last_time:
                    fi.in_order = False
                last_time = max(last_time, t)
                fi.recovered += 1
            elif isinstance(record, (DataEnd, Footer)):
                break
    except Exception as err:  # any damage ends the readable part of the file
        fi.damaged = f"{err.__class__.__name__}: {err}".rstrip(": ")
        logger.debug("%s: sequential read stopped: %s", path, err)
    for cid, stamps in seen.items():
        block = np.zeros((len(stamps), 3), dtype=np.int64)
        block[:, 1] = np.arange(len(stamps))
        block[:, 2] = np.frombuffer(stamps, dtype=np.int64)
        fi.times[cid] = [block]
    return fi


def _iter_file(
    fi: _FileIndex, topics: set[str], start_ns: int | None, end_ns: int | None
) -> Iterator[RawMessage]:
    if fi.indexed:
        yield from _iter_indexed(fi, topics, start_ns, end_ns)
        return
    wanted = {cid for cid, ch in fi.channels.items() if ch.topic in topics}
    if not wanted:
        return
    found = _iter_sequential(fi, wanted, start_ns, end_ns)
    if fi.in_order:
        yield from found
    else:
        # Unindexed and out of order: only a sort gives log-time order (memory grows with the
        # selection, which is why indexed files never take this path).
        yield from sorted(found, key=lambda m: m.log_time_ns)


def _iter_indexed(
    fi: _FileIndex, topics: set[str], start_ns: int | None, end_ns: int | None
) -> Iterator[RawMessage]:
    """Messages of the chunks that hold `topics`, in log-time order.

    The same order as mcap's SeekingReader (log time, then chunk offset, then position in the
    chunk), but each message's data is a zero-copy view into its chunk: mcap copies every
    message out of the chunk again, which costs as much as reading the file.
    """
    wanted = {cid for cid, ch in fi.channels.items() if ch.topic in topics}
    heap: list[tuple[int, int, int, Any]] = [
        (ci.message_start_time, ci.chunk_start_offset, -1, ci)
        for ci in fi.chunk_indexes
        if not (start_ns is not None and ci.message_end_time < start_ns)
        and not (end_ns is not None and ci.message_start_time > end_ns)
        and not wanted.isdisjoint(ci.message_index_offsets)
    ]
    heapq.heapify(heap)
    with fi.path.open("rb") as f:
        while heap:
            _t, chunk_offset, position, item = heapq.heappop(heap)
            if position >= 0:
                yield item
                continue
            try:
                messages = list(_chunk_messages(f, item))
            except Exception as err:  # zstd's and lz4's errors on damaged data are their own
                # The index promised this chunk: damage here is not a clean end of the log.
                raise LogError(f"corrupt chunk at offset {chunk_offset}: {_first_line(err)}", fi.path) from err
            for pos, cid, log_time, data in messages:
                if cid not in wanted:
                    continue
                if (start_ns is not None and log_time < start_ns) or (
                    end_ns is not None and log_time > end_ns
                ):
                    continue
                ch = fi.channels[cid]
                message = RawMessage(ch.topic, log_time, (fi.schemas.get(ch.schema_id), ch, data))
                heapq.heappush(heap, (log_time, chunk_offset, pos, message))


def _no_compression(data: memoryview, _size: int) -> memoryview:
    return data


def _zstd(data: memoryview, size: int) -> memoryview:
    import zstandard

    return memoryview(zstandard.decompress(data, size))


def _lz4(data: memoryview, _size: int) -> memoryview:
    import lz4.frame

    return memoryview(lz4.frame.decompress(data))


_DECOMPRESS: dict[str, Callable[[memoryview, int], memoryview]] = {
    "": _no_compression,
    "zstd": _zstd,
    "lz4": _lz4,
}
_CHUNK_OPCODE = 0x06
_MESSAGE_OPCODE = 0x05
_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time


def _chunk_messages(f: io.BufferedReader, ci: ChunkIndex) -> Iterator[tuple[int, int, int, memoryview]]:
    """(position in the chunk, channel id, log time, data view) of every message in a chunk."""
    if not 0 < ci.chunk_length <= RECORD_SIZE_LIMIT:
        raise McapError(f"chunk at offset {ci.chunk_start_offset} has a corrupt length")
    end = ci.chunk_start_offset + ci.chunk_length
    if end > os.fstat(f.fileno()).st_size:
        raise McapError(f"chunk at offset {ci.chunk_start_offset} runs past the end of the file")
    view = map_file_range(f, ci.chunk_start_offset, ci.chunk_length)
    if view[0] != _CHUNK_OPCODE:
        raise McapError(f"no chunk record at offset {ci.chunk_start_offset}")
    # opcode, record length, start time, end time, uncompressed size, uncompressed crc
    pos = 1 + 8 + 8 + 8 + 8 + 4
    (name_len,) = struct.unpack_from("<I", view, pos)
    pos += 4 + name_len
    (records_len,) = struct.unpack_from("<Q", view, pos)
    pos += 8
    if pos + records_len > len(view):
        raise McapError(f"chunk at offset {ci.chunk_start_offset} is shorter than its records")
    records = _DECOMPRESS[ci.compression](view[pos : pos + records_len], ci.uncompressed_size)
    end = len(records)
    pos = 0
    while pos < end:
        opcode = records[pos]
        (length,) = struct.unpack_from("<Q", records, pos + 1)
        body = pos + 9
        if body + length > end:
            raise McapError(f"record runs past the end of the chunk at offset {ci.chunk_start_offset}")
        if opcode == _MESSAGE_OPCODE:
            cid, _seq, log_time, _publish = _MESSAGE_HEAD.unpack_from(records, body)
            yield pos, cid, log_time, records[body + _MESSAGE_HEAD.size : body + length]
        pos = body + length


def _iter_sequential(
    fi: _FileIndex, wanted: set[int], start_ns: int | None, end_ns: int | None
) -> Iterator[RawMessage]:
    seen = 0
    with fi.path.open("rb") as f:
        try:
            for record in _records(f):
                if not isinstance(record, Message):
                    if isinstance(record, (DataEnd, Footer)):
                        return
                    continue
                seen += 1
                if seen > fi.recovered:
                    return
                if record.channel_id not in wanted:
                    continue
                t = record.log_time
                if (start_ns is not None and t < start_ns) or (end_ns is not None and t > end_ns):
                    continue
                ch = fi.channels[record.channel_id]
                schema = fi.schemas.get(ch.schema_id)
                yield RawMessage(ch.topic, t, (schema, ch, record.data))
        except Exception:  # the damage was found and reported at open
            return
