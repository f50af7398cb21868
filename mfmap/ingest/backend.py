"""What every log reader (MCAP, rosbags) provides to LogSource: topics and raw records."""

from __future__ import annotations

import mmap
from collections.abc import Collection, Iterator
from dataclasses import dataclass
from typing import Any, BinaryIO, Protocol

import numpy as np


@dataclass
class RawTopic:
    """A topic as the reader found it, before roles are assigned."""

    name: str
    msgtype: str
    count: int
    first_ns: int | None  # log time of the first message
    last_ns: int | None


@dataclass(frozen=True)
class RawMessage:
    """One undecoded message; `payload` is whatever the backend needs to deserialise it."""

    topic: str
    log_time_ns: int
    payload: Any


class Backend(Protocol):
    format: str
    topics: dict[str, RawTopic]
    warnings: list[str]

    def iter_raw(
        self, topics: Collection[str], start_ns: int | None, end_ns: int | None
    ) -> Iterator[RawMessage]:
        """Messages of `topics` with start_ns <= log time <= end_ns, in log-time order."""
        ...

    def deserialize(self, message: RawMessage) -> Any:
        """The decoded message object (attribute access like rosbags' message classes)."""
        ...

    def typestore(self, message: RawMessage) -> Any:
        """The rosbags typestore `deserialize` uses for this message (its field definitions)."""
        ...

    def raw_size(self, message: RawMessage) -> int:
        """Bytes of serialised data."""
        ...

    def serialized(self, message: RawMessage) -> tuple[str, Any]:
        """(message encoding "cdr" | "ros1" | other, serialised bytes)."""
        ...

    def log_times(self, topic: str) -> np.ndarray[Any, np.dtype[np.int64]] | None:
        """Log times of the topic's messages in recording order (the order they were
        written), from the indexes; None when only reading every message would tell."""
        ...

    def close(self) -> None: ...


def normalise_msgtype(name: str) -> str:
    """'sensor_msgs/PointCloud2' (ROS 1) -> 'sensor_msgs/msg/PointCloud2'; others unchanged.

    Names that are already three-part ('pkg/msg/Name', 'pkg/srv/Name_Event') or not ROS types
    at all are returned as they are.
    """
    parts = name.split("/")
    if len(parts) == 2 and all(parts):
        return f"{parts[0]}/msg/{parts[1]}"
    return name


def map_file_range(f: BinaryIO, offset: int, length: int) -> memoryview:
    """`length` bytes of the file at `offset`, memory-mapped (read() where mmap is refused).

    A read() copies the chunk out of the page cache, and that copy costs about as much as
    decoding the scans in it. The mapping is unmapped when the last view of it is dropped.
    The file must not shrink while it is read (a log that is finished and indexed does not).
    """
    base = offset - offset % mmap.ALLOCATIONGRANULARITY
    try:
        mapped = mmap.mmap(
            f.fileno(),
            offset + length - base,
            flags=mmap.MAP_SHARED | getattr(mmap, "MAP_POPULATE", 0),
            prot=mmap.PROT_READ,
            offset=base,
        )
    except (OSError, ValueError, AttributeError):  # AttributeError: no MAP_SHARED (Windows)
        f.seek(offset)
        data = f.read(length)
        if len(data) != length:
            raise OSError(f"cannot read {length} bytes at offset {offset}") from None
        return memoryview(data)
    return memoryview(mapped)[offset - base :]
