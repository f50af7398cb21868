"""Helpers for the simulator tests: read logs back with third-party readers only, load GT files."""

from __future__ import annotations

import csv
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

LOG_NAMES = {"mcap": "log.mcap", "ros1": "log.bag", "ros2": "log"}


def iter_messages(folder: Path, fmt: str, topics: set[str] | None = None) -> Iterator[tuple[str, str, int, Any]]:
    """(topic, msgtype, log time ns, decoded message) in log-time order, via mcap_ros2 or rosbags."""
    path = folder / LOG_NAMES[fmt]
    if fmt == "mcap":
        from mcap.reader import make_reader
        from mcap_ros2.decoder import DecoderFactory

        with path.open("rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for schema, channel, message, msg in reader.iter_decoded_messages(topics=topics):
                yield channel.topic, schema.name, message.log_time, msg
    else:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore

        with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
            conns = [c for c in reader.connections if topics is None or c.topic in topics]
            for conn, stamp, raw in reader.messages(connections=conns):
                yield conn.topic, conn.msgtype, stamp, reader.deserialize(raw, conn.msgtype)


def load_tum(folder: Path) -> np.ndarray:
    return np.loadtxt(folder / "gt_trajectory.tum", dtype=np.float64)


def load_points(folder: Path) -> list[dict[str, str]]:
    with (folder / "gt_points.csv").open() as f:
        return list(csv.DictReader(f))


def load_floors(folder: Path) -> dict[str, Any]:
    return json.loads((folder / "gt_floors.json").read_text())


def stamp_ns(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


class GtPose:
    """GT base pose at any time, interpolated from gt_trajectory.tum (linear + slerp)."""

    def __init__(self, tum: np.ndarray, start_ns: int) -> None:
        from scipy.spatial.transform import Rotation, Slerp

        # Times relative to the start keep float64 precision at the nanosecond level.
        self.t = np.round((tum[:, 0] - start_ns / 1e9) * 1e4) / 1e4
        self.xyz = tum[:, 1:4]
        self.slerp = Slerp(self.t, Rotation.from_quat(tum[:, 4:8]))

    def at(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = np.clip(t_s, self.t[0], self.t[-1])
        xyz = np.column_stack([np.interp(t, self.t, self.xyz[:, i]) for i in range(3)])
        return xyz, self.slerp(t).as_matrix()


def tf_static(folder: Path, fmt: str) -> dict[str, np.ndarray]:
    """child frame -> 4x4 pose in base_link, read from /tf_static."""
    from scipy.spatial.transform import Rotation

    out: dict[str, np.ndarray] = {}
    for _, _, _, msg in iter_messages(folder, fmt, {"/tf_static"}):
        for tr in msg.transforms:
            assert tr.header.frame_id == "base_link"
            m = np.eye(4)
            q = tr.transform.rotation
            m[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
            v = tr.transform.translation
            m[:3, 3] = [v.x, v.y, v.z]
            out[tr.child_frame_id] = m
    return out
