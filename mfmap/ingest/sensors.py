"""Per sensor of a log: how it reads, its frame and mount, and what would stop a build."""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np

from mfmap.errors import MfmapError
from mfmap.ingest.lidartime import TimeSpec
from mfmap.types import Extrinsics, Role

if TYPE_CHECKING:
    from mfmap.ingest.source import LogSource


class _Attempt:
    """Runs a step, keeping an error a user can act on as a problem instead of raising it."""

    def __init__(self) -> None:
        self.problems: list[str] = []

    def __call__(self, fn: Callable[[], Any]) -> Any:
        try:
            return fn()
        except MfmapError as err:
            self.problems.append(str(err))
            return None


def sensor_table(src: LogSource, check: bool) -> tuple[list[dict[str, Any]], list[str]]:
    """`LogSource.sensors`: a row per sensor topic, and the problems found."""
    rows: list[dict[str, Any]] = []
    attempt = _Attempt()
    problems = attempt.problems
    status = attempt(partial(src.frame_status, not check))
    sources: dict[str, str] = status[1] if status is not None else {}
    if status is not None:
        problems += [f"{src.path}: {p}" for p in status[2]]
    extrinsics = status[0] if status is not None else None
    for role in (Role.LIDAR, Role.SCAN2D, Role.IMU, Role.BARO):
        topic = src.roles.get(role)
        if topic is None:
            continue
        row = _frame_row(src, role, topic, sources, extrinsics, attempt)
        if role == Role.LIDAR:
            _lidar_row(src, row, topic, attempt)
        elif role == Role.SCAN2D:
            _scan2d_row(src, row, topic, check, attempt)
        elif role == Role.IMU:
            first = attempt(partial(src._first_record, topic))
            if first is not None:
                cov0 = float(first.msg.orientation_covariance[0])
                row["fields"] = "gyro, accel" + (", no orientation (covariance[0] = -1)"
                                                 if cov0 == -1.0 else ", orientation")
        elif role == Role.BARO and check:
            series = attempt(src.pressure)
            if series is not None and src._series.pressure_unit_seen is not None:
                row["fields"] = f"pressure in {src._series.pressure_unit_seen.name}"
        rows.append(row)
    if Role.LIDAR not in src.roles and Role.SCAN2D not in src.roles:
        problems.append(f"{src.path}: the log has no lidar (neither PointCloud2 nor LaserScan)")
    return rows, problems


def _frame_row(src: LogSource, role: Role, topic: str, sources: dict[str, str],
               extrinsics: Extrinsics | None, attempt: _Attempt) -> dict[str, Any]:
    """A sensor's topic, type, frame, where its transform comes from and its mount."""
    frame = (attempt(partial(src._first_frame, role)) or "").lstrip("/")
    row: dict[str, Any] = {"topic": topic, "role": role.value,
                           "type": src._backend.topics[topic].msgtype, "frame": frame,
                           "transform": sources.get(frame, "base" if frame in ("", src.config.base_frame) else "-")}
    pose = extrinsics.get(frame) if extrinsics is not None else None
    if pose is not None and row["transform"] not in ("base", "missing"):
        angle = float(np.degrees(np.arccos(np.clip((np.trace(pose[:3, :3]) - 1) / 2, -1, 1))))
        row["mount"] = (f"xyz {pose[0, 3]:+.3f} {pose[1, 3]:+.3f} {pose[2, 3]:+.3f} m, "
                        f"turned {angle:.1f} deg")
    return row


def _lidar_row(src: LogSource, row: dict[str, Any], topic: str, attempt: _Attempt) -> None:
    fields = attempt(partial(src._lidar.fields, topic)) or []
    row["fields"] = " ".join(f"{n}:{t}" + (f"[{c}]" if c > 1 else "") for n, _, t, c in fields)
    timing = attempt(src.lidar_timing)
    if src._lidar.timing_done:
        row["time"] = ("none" if timing is None else timing.describe()
                       if isinstance(timing, TimeSpec) else f"from azimuth: {timing.describe()}")
        row["deskew"] = src._lidar.report.get("deskew", "none")


def _scan2d_row(src: LogSource, row: dict[str, Any], topic: str, check: bool,
                attempt: _Attempt) -> None:
    first = attempt(partial(src._first_record, topic))
    if first is not None:
        m = first.msg
        row["fields"] = (f"{len(m.ranges)} beams from {np.degrees(float(m.angle_min)):.1f} deg "
                         f"by {np.degrees(float(m.angle_increment)):+.3f} deg")
        row["time"] = f"time_increment {float(m.time_increment) * 1e6:+.2f} us"
    if check and Role.LIDAR not in src.roles and src.config.scan2d_beam_time == "auto":
        order = attempt(src.scan2d_beam_time)
        if order is not None:
            row["deskew"] = f"beams {order.replace('_', ' ')}"
            note = src._scan2d.report.get("note")
            if note:
                row["deskew"] += f" ({note})"
    else:
        row["deskew"] = f"beams {src.config.scan2d_beam_time.replace('_', ' ')}"
