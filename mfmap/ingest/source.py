"""open_log(): one context-managed LogSource over MCAP, ROS 1 bag or ROS 2 bag logs.

LogSource assigns roles to topics by message type and hands out decoded streams: the lidar's
(`mfmap.ingest.lidar`), the 2D laser's (`laserscan`), the small series (`series`) and the
sensors' poses (`frames`), each read from `LogCore`'s records. Every read asks the backend for
one topic and a time window only, so reading the barometer never decompresses the lidar chunks
of an indexed MCAP.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

from mfmap.ingest.backend import Backend
from mfmap.ingest.config import IngestConfig
from mfmap.ingest.core import LogCore, Record
from mfmap.ingest.decode import Timing
from mfmap.ingest.frames import Frames
from mfmap.ingest.laserscan import LaserScanReader
from mfmap.ingest.lidar import LidarReader, point_frame
from mfmap.ingest.lidartime import AzimuthSpec, TimeSpec
from mfmap.ingest.opener import check_one_recording, open_backend
from mfmap.ingest.pointmsg import POINT_MESSAGE_TYPES
from mfmap.ingest.sensors import sensor_table
from mfmap.ingest.series import SMALL_ROLES, SeriesReader
from mfmap.ingest.tfread import TfStore
from mfmap.ingest.wire import parse_pointcloud2
from mfmap.types import (
    Cloud,
    Extrinsics,
    ImuSeries,
    OdomSeries,
    PressureSeries,
    Role,
    Scan2D,
    TemperatureSeries,
    TopicInfo,
)

__all__ = ["LogSource", "LogSummary", "Record", "describe_log", "open_log"]


class LogSource(LogCore):
    """An opened log: topics, roles, and decoded streams. Use through `open_log()`."""

    def __init__(self, path: Path, backend: Backend, config: IngestConfig) -> None:
        super().__init__(path, backend, config)
        tf = TfStore(backend, self.roles, path)
        self._series = SeriesReader(self, tf)
        self._frames = Frames(self, self._series, tf, self._first_frame)
        self._lidar = LidarReader(self)
        self._scan2d = LaserScanReader(self, self._series, self.extrinsics)

    def __enter__(self) -> LogSource:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # ----- lidar and 2D laser -------------------------------------------------------------

    def clouds(self, start_ns: int | None = None, end_ns: int | None = None) -> Iterator[Cloud]:
        """Lidar scans in stamp order, decoded one at a time (never all in memory), each point's
        time read as `lidar_timing` decided.

        Raises MissingDataError at the call (not at the first scan) when the log has no lidar.
        """
        return self._lidar.clouds(start_ns, end_ns)

    def lidar_timing(self) -> Timing:
        """How each lidar point's time is found: a time field's decided reading, the azimuth of
        a spinning lidar without one, or None (no deskew). Decided once, from the first scans;
        each decision not taken by the config is a warning or in `report()`."""
        return self._lidar.decide_timing()

    def scans2d(self, start_ns: int | None = None, end_ns: int | None = None) -> Iterator[Scan2D]:
        """2D laser scans in stamp order as points (MissingDataError at the call if none), each
        beam's time in the order `scan2d_beam_time` decided."""
        return self._scan2d.scans(start_ns, end_ns)

    def scan2d_beam_time(self) -> str:
        """"as_stated" or "reversed": which way the LaserScan's beams run in time (config, else
        checked against the robot's turns, `mfmap.ingest.sweep2d`)."""
        return self._scan2d.decide_beam_time()

    # ----- small series -------------------------------------------------------------------

    def pressure(self) -> PressureSeries:
        """Barometer trace in Pa, sorted by stamp. hPa/kPa publishers are converted."""
        return self._series.pressure()

    def temperature(self) -> TemperatureSeries | None:
        """The barometer's air temperature: the sensor_msgs/Temperature topic in the barometer's
        frame (most barometer drivers publish one), or the configured one; None when there is
        none. Temperatures of other frames (a CPU, a motor) say nothing about the air."""
        return self._series.temperature()

    def imu(self) -> ImuSeries | None:
        """IMU samples sorted by stamp, or None when the log has no IMU."""
        return self._series.imu()

    def odometry(self) -> OdomSeries | None:
        """Odometry sorted by stamp, or None when the log has none."""
        return self._series.odometry()

    # ----- frames ---------------------------------------------------------------------------

    def frame_status(self, alone: bool = False) -> tuple[Extrinsics, dict[str, str], list[str]]:
        """(extrinsics, where each sensor frame's transform comes from, problems): a problem is
        the one-line reason a needed sensor frame has no transform to the base. `alone` reads
        the transforms by themselves, not in the small streams' pass."""
        return self._frames.frame_status(alone)

    def extrinsics(self) -> Extrinsics:
        """Pose in `config.base_frame` of every frame the log's static transforms (/tf_static,
        and pairs that never change on /tf) and `config.extrinsics` connect to it.

        A lidar, 2D laser or IMU frame left unconnected raises MissingDataError naming the
        frames and the ways out, unless `assume_identity_extrinsics` (then identity, a warning).
        """
        return self._frames.extrinsics()

    def _first_frame(self, role: Role) -> str | None:
        topic = self.roles.get(role)
        if topic is None:
            return None
        if role in SMALL_ROLES and self._series.rows is not None:
            return self._series.first_frame(role)
        for raw in self._iter_raw([topic], None, None):
            if self._backend.topics[topic].msgtype in POINT_MESSAGE_TYPES:
                encoding, data = self._backend.serialized(raw)
                parser = self._lidar.point_message_parser(raw, encoding, f"{self.path} topic {topic}")
                return point_frame(parser.parse(data))
            encoding, data = self._backend.serialized(raw)
            if role == Role.LIDAR and encoding in ("cdr", "ros1"):
                return str(parse_pointcloud2(data, encoding).header.frame_id)
            msg = self._backend.deserialize(raw)
            header = getattr(msg, "header", None)
            return str(header.frame_id) if header is not None else None
        return None

    # ----- what was decided -------------------------------------------------------------------

    def sensors(self, check: bool = False) -> tuple[list[dict[str, Any]], list[str]]:
        """Per sensor topic: its fields, how its time reads, its frame and whether the frame's
        transform is known; and the problems that would stop a build or make it wrong. With
        `check` also what needs the whole log read (the barometer's unit, the 2D beam order)."""
        return sensor_table(self, check)

    def resolve(self) -> IngestConfig:
        """Take every decision a build needs from the data now (per-point time, the 2D beam
        order, the extrinsics) and return the config with them filled in, so worker processes
        that re-open the log need not decide again. This source then uses it too."""
        self.extrinsics()
        update: dict[str, Any] = {}
        if Role.LIDAR in self.roles:
            timing = self.lidar_timing()
            lt = self.config.lidar_time
            if isinstance(timing, TimeSpec):
                update["lidar_time"] = lt.model_copy(update={
                    "field": timing.field, "unit": timing.unit, "reference": timing.reference,
                    "stamp": "end" if timing.shift_ns else "start" if timing.reference == "relative"
                    and timing.stamp == "start" else lt.stamp})
            elif isinstance(timing, AzimuthSpec):
                update["lidar_time"] = lt.model_copy(update={
                    "field": "none", "without_time": "azimuth",
                    "spin": "ccw" if timing.direction > 0 else "cw"})
            else:
                update["lidar_time"] = lt.model_copy(update={"field": "none", "without_time": "none"})
        elif Role.SCAN2D in self.roles:
            update["scan2d_beam_time"] = self.scan2d_beam_time()
        if update:
            self.config = self.config.model_copy(update=update)
        return self.config

    def report(self) -> dict[str, Any]:
        """The ingest decisions for report.json: per sensor how it is read and deskewed."""
        out: dict[str, Any] = {"format": self.format, "roles": {r.value: t for r, t in self.roles.items()}}
        if self._lidar.report:
            out["lidar"] = dict(self._lidar.report)
        if self._scan2d.report:
            out["scan2d"] = dict(self._scan2d.report)
        if self._frames.sources:
            out["frames"] = dict(sorted(self._frames.sources.items()))
        if self._series.pressure_unit_seen is not None:
            out["pressure_unit"] = self._series.pressure_unit_seen.name
        return out


def open_log(path: Path | str, config: IngestConfig | None = None) -> LogSource:
    """Open a log: a `.mcap` file, a ROS 1 `.bag`, a ROS 2 bag folder or a folder of `.mcap`."""
    path = Path(path)
    config = config or IngestConfig()
    backend = open_backend(path)
    try:
        check_one_recording(backend, path, config.max_gap_s)
        return LogSource(path, backend, config)
    except BaseException:
        backend.close()
        raise


@dataclass
class LogSummary:
    """What `mfmap info` shows."""

    path: Path
    format: str
    topics: list[TopicInfo]
    roles: dict[Role, str]
    start_ns: int
    end_ns: int
    warnings: list[str] = field(default_factory=list)
    sensors: list[dict[str, Any]] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / 1e9

    @property
    def message_count(self) -> int:
        return sum(t.count for t in self.topics)

    def to_json(self) -> dict[str, Any]:
        def sec(ns: int | None) -> float | None:
            return None if ns is None else ns / 1e9

        return {
            "path": str(self.path),
            "format": self.format,
            "start": sec(self.start_ns),
            "end": sec(self.end_ns),
            "duration_s": self.duration_s,
            "message_count": self.message_count,
            "roles": {role.value: topic for role, topic in self.roles.items()},
            "topics": [
                {
                    "name": t.name,
                    "type": t.msgtype,
                    "role": t.role.value if t.role is not None else None,
                    "candidate_for": t.candidate_for.value if t.candidate_for is not None else None,
                    "count": t.count,
                    "rate_hz": round(t.rate_hz, 3),
                    "first": sec(t.first_ns),
                    "last": sec(t.last_ns),
                }
                for t in self.topics
            ],
            "sensors": [dict(s) for s in self.sensors],
            "problems": list(self.problems),
            "warnings": list(self.warnings),
        }


def describe_log(path: Path | str, config: IngestConfig | None = None,
                 check: bool = False) -> LogSummary:
    """Topics, types, roles, counts and times of a log, and per sensor how it reads (from its
    first scans and the transforms); with `check` also what needs the whole log."""
    with open_log(path, config) as src:
        sensors, problems = src.sensors(check)
        return LogSummary(
            path=src.path,
            format=src.format,
            topics=list(src.topics),
            roles=dict(src.roles),
            start_ns=src.start_ns,
            end_ns=src.end_ns,
            warnings=list(src.warnings),
            sensors=sensors,
            problems=problems,
        )
