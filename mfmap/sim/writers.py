"""Log writers: MCAP (ROS 2 CDR), ROS 1 bag and ROS 2 bag, behind one small interface.

Messages are built as rosbags typestore classes and serialised by rosbags, so every byte on disk
comes from a real serialiser; the writers stream, nothing is held back in memory.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from mfmap.errors import OutputError

LOG_NAMES = {"mcap": "log.mcap", "ros1": "log.bag", "ros2": "log"}


class LogWriter:
    """Writes typed messages to one of the three log formats. Use as a context manager."""

    def __init__(self, out_dir: Path, fmt: str) -> None:
        from rosbags.typesys import Stores, get_typestore

        if fmt not in LOG_NAMES:
            raise OutputError(f"unknown log format '{fmt}' (expected mcap, ros1 or ros2)", out_dir)
        self.fmt = fmt
        self.path = out_dir / LOG_NAMES[fmt]
        # Written in a temporary folder and moved into place on close, so a crash leaves no log
        # that looks whole (a ROS 2 bag keeps its folder's name inside, hence the folder).
        self._tmp_dir = out_dir / f".{LOG_NAMES[fmt]}.partial"
        self._tmp = self._tmp_dir / LOG_NAMES[fmt]
        for p in (self.path, self._tmp_dir):
            if p.is_dir():
                shutil.rmtree(p)
            elif p.exists():
                p.unlink()
        self._tmp_dir.mkdir()
        self.typestore = get_typestore(Stores.ROS1_NOETIC if fmt == "ros1" else Stores.ROS2_HUMBLE)
        if "tf2_msgs/msg/TFMessage" not in self.typestore.types:
            # rosbags' Noetic store lacks tf2_msgs; its definition is one line.
            from rosbags.typesys import get_types_from_msg

            self.typestore.register(
                get_types_from_msg(
                    "geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"
                )
            )
        self.types = self.typestore.types
        self._channels: dict[str, Any] = {}
        self._seq: dict[str, int] = {}
        self.counts: dict[str, int] = {}
        if fmt == "mcap":
            from mcap.writer import CompressionType, Writer

            self._file = open(self._tmp, "wb")  # noqa: SIM115 - closed in close()
            # LZ4 chunks: a third of zstd's CPU time per scan; lidar floats compress poorly anyway.
            self._mcap = Writer(self._file, chunk_size=4 << 20, compression=CompressionType.LZ4)
            self._mcap.start(profile="ros2", library="mfmap-sim")
        elif fmt == "ros1":
            from rosbags.rosbag1 import Writer as Bag1Writer

            self._bag1 = Bag1Writer(self._tmp)
            self._bag1.set_compression(Bag1Writer.CompressionFormat.LZ4)
            self._bag1.open()
        else:
            from rosbags.rosbag2 import Writer as Bag2Writer

            self._bag2 = Bag2Writer(self._tmp, version=9)
            self._bag2.open()

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close(ok=exc[0] is None)

    def add_topic(self, topic: str, msgtype: str, latched: bool = False) -> None:
        self.counts[topic] = 0
        self._seq[topic] = 0
        if self.fmt == "mcap":
            text = self.typestore.generate_msgdef(msgtype, ros_version=2)[0]
            schema_id = self._mcap.register_schema(
                name=msgtype, encoding="ros2msg", data=text.encode()
            )
            meta = {"offered_qos_profiles": _LATCHED_QOS} if latched else {}
            self._channels[topic] = (
                self._mcap.register_channel(
                    topic=topic, message_encoding="cdr", schema_id=schema_id, metadata=meta
                ),
                msgtype,
            )
        elif self.fmt == "ros1":
            conn = self._bag1.add_connection(
                topic, msgtype, typestore=self.typestore, latching=1 if latched else None
            )
            self._channels[topic] = (conn, msgtype)
        else:
            from rosbags.rosbag2.metadata import parse_qos

            qos = parse_qos([_LATCHED_QOS_DICT]) if latched else []  # type: ignore[list-item]
            conn = self._bag2.add_connection(
                topic, msgtype, typestore=self.typestore, offered_qos_profiles=qos
            )
            self._channels[topic] = (conn, msgtype)

    def header(self, stamp_ns: int, frame_id: str, topic: str) -> Any:
        stamp = self.types["builtin_interfaces/msg/Time"](
            sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000
        )
        if self.fmt == "ros1":
            seq = self._seq[topic]
            return self.types["std_msgs/msg/Header"](seq=seq, stamp=stamp, frame_id=frame_id)
        return self.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)

    def write(self, topic: str, stamp_ns: int, msg: Any) -> None:
        channel, msgtype = self._channels[topic]
        if self.fmt == "ros1":
            data = self.typestore.serialize_ros1(msg, msgtype)
            self._bag1.write(channel, stamp_ns, data)
        else:
            data = self.typestore.serialize_cdr(msg, msgtype)
            if self.fmt == "mcap":
                self._mcap.add_message(channel, stamp_ns, bytes(data), stamp_ns, self._seq[topic])
            else:
                self._bag2.write(channel, stamp_ns, data)
        self._seq[topic] += 1
        self.counts[topic] += 1

    def close(self, ok: bool = True) -> None:
        if self.fmt == "mcap":
            self._mcap.finish()
            self._file.close()
        elif self.fmt == "ros1":
            self._bag1.close()
        else:
            self._bag2.close()
        if ok:
            os.replace(self._tmp, self.path)
        shutil.rmtree(self._tmp_dir, ignore_errors=True)


_LATCHED_QOS_DICT: dict[str, Any] = {
    "history": 1,
    "depth": 1,
    "reliability": 1,
    "durability": 1,
    "deadline": {"sec": 0, "nsec": 0},
    "lifespan": {"sec": 0, "nsec": 0},
    "liveliness": 1,
    "liveliness_lease_duration": {"sec": 0, "nsec": 0},
    "avoid_ros_namespace_conventions": False,
}
_LATCHED_QOS = (
    "- history: 1\n  depth: 1\n  reliability: 1\n  durability: 1\n"
    "  deadline:\n    sec: 0\n    nsec: 0\n  lifespan:\n    sec: 0\n    nsec: 0\n"
    "  liveliness: 1\n  liveliness_lease_duration:\n    sec: 0\n    nsec: 0\n"
    "  avoid_ros_namespace_conventions: false\n"
)


def u8(data: bytes | npt.NDArray[Any]) -> npt.NDArray[np.uint8]:
    """Bytes as the uint8 array rosbags expects for `uint8[]` fields."""
    if isinstance(data, np.ndarray):
        return data.view(np.uint8).reshape(-1)
    return np.frombuffer(data, dtype=np.uint8)
