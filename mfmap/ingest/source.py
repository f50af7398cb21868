"""open_log(): one context-managed LogSource over MCAP, ROS 1 bag or ROS 2 bag logs.

LogSource assigns roles to topics by message type and hands out decoded streams. Every read asks
the backend for one topic and a time window only, so reading the barometer never decompresses
the lidar chunks of an indexed MCAP.
"""

from __future__ import annotations

import heapq
import logging
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from types import TracebackType
from typing import Any, TypeVar

import numpy as np
import yaml

from mfmap.errors import ConfigError, DecodeError, LogError, MfmapError, MissingDataError
from mfmap.ingest.backend import Backend, RawMessage
from mfmap.ingest.config import IngestConfig, LidarTimeConfig
from mfmap.ingest.decode import (
    DecodedPoints,
    PressureUnit,
    Timing,
    cloud_of,
    decode_laserscan,
    decode_points,
    parse_pointcloud2,
    parse_stamped_doubles,
    pointcloud2_layout,
    pressure_unit,
    stamp_ns_of,
    transform_matrix,
)
from mfmap.ingest.extrinsics import Edge, TfSeen, config_edges, connect, missing_message
from mfmap.ingest.lidartime import (
    TIME_FIELDS,
    AzimuthSpec,
    TimeSample,
    TimeSpec,
    decide_azimuth,
    decide_time,
    scan_period_ns,
)
from mfmap.ingest.pointmsg import (
    POINT_MESSAGE_TYPES,
    TIMEBASE_FIELD,
    PointMessage,
    PointMessageParser,
    points_of,
    stamp_ns_of_scalars,
)
from mfmap.ingest.timecheck import LogClock, StampGuard, series_order
from mfmap.types import (
    ROLE_BY_TYPE,
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

logger = logging.getLogger(__name__)

ROLE_TYPE: dict[Role, str] = {}
for _msgtype, _role in ROLE_BY_TYPE.items():
    ROLE_TYPE.setdefault(_role, _msgtype)  # the first (standard) type a role is named by


@dataclass(frozen=True)
class Record:
    """One decoded message: header stamp (log time if the header is zero), log time, topic."""

    stamp_ns: int
    log_time_ns: int
    topic: str
    msg: Any
    size_bytes: int = 0


_Stamped = TypeVar("_Stamped", Record, Cloud, Scan2D)


_SMALL_ROLES = (Role.BARO, Role.IMU, Role.ODOM)
_TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
# Sensors whose pose in the base a map cannot do without (the barometer's only shifts every
# pressure alike, which the floors stage does not see).
_NEEDED_FRAMES = (Role.LIDAR, Role.SCAN2D, Role.IMU)
# Scans sampled to decide how a lidar's per-point time reads.
TIME_SAMPLE_SCANS = 12
# Streams whose clock the time check follows (tf_static's messages hold whenever they came).
_TIMED_ROLES = (Role.LIDAR, Role.SCAN2D, Role.BARO, Role.IMU, Role.ODOM)


@dataclass
class _Rows:
    """One small stream as plain numbers: a stamp and a row of floats per message."""

    stamps: list[int] = field(default_factory=list)
    values: list[tuple[float, ...]] = field(default_factory=list)
    frame: str = ""
    child: str = ""
    error: MfmapError | None = None

    def add(self, role: Role, msg: Any, stamp_ns: int) -> None:
        """A message from the generic deserialiser."""
        frame = child = ""  # only the first message's are kept
        if not self.stamps:
            header = getattr(msg, "header", None)
            frame = str(header.frame_id) if header is not None else ""
            child = str(getattr(msg, "child_frame_id", ""))
        if role == Role.BARO:
            row: tuple[float, ...] = (float(msg.fluid_pressure),)
        elif role == Role.TEMPERATURE:
            row = (float(msg.temperature),)
        elif role == Role.IMU:
            w, a, q = msg.angular_velocity, msg.linear_acceleration, msg.orientation
            row = (w.x, w.y, w.z, a.x, a.y, a.z, q.x, q.y, q.z, q.w, float(msg.orientation_covariance[0]))
        else:
            p, q = msg.pose.pose.position, msg.pose.pose.orientation
            v, w = msg.twist.twist.linear, msg.twist.twist.angular
            row = (p.x, p.y, p.z, q.x, q.y, q.z, q.w, v.x, v.y, v.z, w.x, w.y, w.z)
        self.add_row(stamp_ns, row, frame, child)

    def add_row(self, stamp_ns: int, row: tuple[float, ...], frame: str, child: str) -> None:
        """A message as a row; the first message's frames are the stream's."""
        if not self.stamps:
            self.frame, self.child = frame, child
        self.stamps.append(stamp_ns)
        self.values.append(row)


# Small streams whose messages are a header (and odometry's child_frame_id) and then only
# float64 fields, read by the direct parser: role -> (number of doubles, has a child frame,
# `_Rows.add`'s row from the doubles). sensor_msgs/Imu: orientation (0-3), its covariance (4-12),
# angular velocity (13-15), ..., linear acceleration (25-27); nav_msgs/Odometry: pose (0-6),
# its covariance (7-42), twist (43-48).
_FLAT: dict[Role, tuple[int, bool, Callable[[tuple[float, ...]], tuple[float, ...]]]] = {
    Role.IMU: (37, False, lambda d: (d[13], d[14], d[15], d[25], d[26], d[27], d[0], d[1], d[2], d[3], d[4])),
    Role.BARO: (2, False, lambda d: (d[0],)),
    Role.TEMPERATURE: (2, False, lambda d: (d[0],)),
    Role.ODOM: (85, True, lambda d: d[0:7] + d[43:49]),
}


def _open_backend(path: Path) -> Backend:
    from mfmap.ingest.bag_backend import ROS1_MAGIC, RosbagsBackend
    from mfmap.ingest.mcap_backend import MCAP_MAGIC, McapBackend

    if not path.exists():
        raise LogError("no such file or folder", path)
    if path.is_dir():
        meta = path / "metadata.yaml"
        if meta.is_file():
            storage, files = _ros2_metadata(meta)
            if storage == "mcap" and files is not None:
                return McapBackend([path / f for f in files], fmt="ros2")
            return _open_ros2_bag(path)
        mcaps = sorted(p for p in path.glob("*.mcap") if p.is_file())
        if mcaps:
            return McapBackend(mcaps, fmt="mcap")
        dbs = sorted(p for p in path.glob("*.db3") if p.is_file())
        if dbs:
            # rosbag2 writes metadata.yaml when it closes the bag: a recorder that died left
            # only its database files.
            from mfmap.ingest.sqlite_recover import Ros2SqliteRecoveryBackend

            return Ros2SqliteRecoveryBackend(path, dbs, None, "no metadata.yaml: the recorder did not finish")
        raise LogError("folder holds neither a ROS 2 metadata.yaml nor .mcap or .db3 files", path)
    if path.stat().st_size == 0:
        raise LogError("empty file (0 bytes), not a log", path)
    with path.open("rb") as f:
        head = f.read(16)
    if head.startswith(MCAP_MAGIC):
        return McapBackend([path], fmt="mcap")
    if head.startswith(ROS1_MAGIC):
        try:
            return RosbagsBackend(path, "ros1")
        except LogError as err:
            if err.__cause__ is None:
                raise
            # A recorder that died leaves no (or a broken) index: read what is intact.
            from mfmap.ingest.ros1_recover import Ros1RecoveryBackend

            return Ros1RecoveryBackend(path, str(err).split(": ", 2)[-1])
    if path.name == "metadata.yaml":
        return _open_backend(path.parent)
    if path.suffix == ".db3":
        return _open_db3(path)
    kind = {".mcap": "an MCAP file", ".bag": "a ROS 1 bag"}.get(path.suffix, "a known log format")
    raise LogError(f"not {kind} (unrecognised content at the start of the file)", path)


def _open_db3(path: Path) -> Backend:
    """A .db3 file named on its own: its bag when the metadata.yaml beside it lists it, else
    that file alone (never another log that happens to lie in the same folder)."""
    from mfmap.ingest.sqlite_recover import Ros2SqliteRecoveryBackend

    meta = path.parent / "metadata.yaml"
    if meta.is_file() and path.name in _metadata_files(meta):
        return _open_backend(path.parent)
    return Ros2SqliteRecoveryBackend(path, [path], None,
                                     "a .db3 file on its own: no metadata.yaml lists it")


def _metadata_files(meta: Path) -> list[str]:
    """The file names metadata.yaml lists (also for storage `_ros2_metadata` does not open)."""
    try:
        info = yaml.safe_load(meta.read_text())["rosbag2_bagfile_information"]
        return [Path(str(p)).name for p in info.get("relative_file_paths") or []]
    except Exception:
        return []


def _open_ros2_bag(path: Path) -> Backend:
    """A ROS 2 bag folder through rosbags; a damaged sqlite3 one row by row instead."""
    from mfmap.ingest.bag_backend import RosbagsBackend, sqlite_files
    from mfmap.ingest.sqlite_recover import Ros2SqliteRecoveryBackend, cut_short, metadata_count

    dbs = sqlite_files(path)
    if any(cut_short(db) for db in dbs):
        # SQLite may open a file cut short and fail only on the first lost page, mid-read.
        return Ros2SqliteRecoveryBackend(path, dbs, metadata_count(path), None)
    try:
        return RosbagsBackend(path, "ros2")
    except LogError as err:
        if err.__cause__ is None or not dbs:
            raise
        recovered = Ros2SqliteRecoveryBackend(path, dbs, metadata_count(path), str(err).split(": ", 1)[-1])
        if not recovered.damaged:
            recovered.close()  # the storage is intact: the problem is elsewhere
            raise
        return recovered


def _ros2_metadata(meta: Path) -> tuple[str, list[str] | None]:
    """Storage id and, for mcap storage without file compression, the files in order.

    Rejects topics with a serialization format other than CDR.
    """
    try:
        doc = yaml.safe_load(meta.read_text())
        info = doc["rosbag2_bagfile_information"]
    except Exception as err:
        raise LogError(f"not a ROS 2 bag metadata file ({err.__class__.__name__})", meta) from err
    if not isinstance(info, dict):
        raise LogError("not a ROS 2 bag metadata file (rosbag2_bagfile_information is not a "
                       "mapping)", meta)
    entries = info.get("topics_with_message_count") or []
    paths = info.get("relative_file_paths") or []
    for key, value in (("topics_with_message_count", entries), ("relative_file_paths", paths)):
        if not isinstance(value, list):
            raise LogError(f"not a ROS 2 bag metadata file ({key} is not a list: {value!r:.40})",
                           meta)
    for entry in entries:
        topic = entry.get("topic_metadata", {}) if isinstance(entry, dict) else None
        if not isinstance(topic, dict):
            raise LogError("not a ROS 2 bag metadata file (an entry of topics_with_message_count "
                           f"without topic_metadata: {entry!r:.40})", meta)
        fmt = topic.get("serialization_format", "cdr")
        if fmt != "cdr":
            raise LogError(
                f"topic {topic.get('name')} has unknown serialization format '{fmt}' "
                "(only cdr is supported)",
                meta,
            )
    storage = str(info.get("storage_identifier", ""))
    if storage not in ("mcap", "sqlite3"):
        raise LogError(f"unknown storage '{storage}' (expected sqlite3 or mcap)", meta)
    # Early rosbag2 versions wrote the bag folder into the "relative" paths: keep the name only.
    files = [str(p) if (meta.parent / str(p)).is_file() else Path(str(p)).name for p in paths]
    if info.get("compression_mode") or not files:
        return storage, None
    missing = [f for f in files if not (meta.parent / f).is_file()]
    if missing:
        raise LogError(f"bag file {missing[0]} listed in metadata.yaml is missing", meta.parent)
    return storage, files


def assign_roles(
    topics: dict[str, tuple[str, int]], overrides: dict[str, str], path: Path
) -> tuple[dict[Role, str], list[str]]:
    """Pick one topic per role: config override, else the candidate with the most messages.

    `topics` maps name -> (msgtype, count). Returns the roles and notes for the user.
    """
    roles: dict[Role, str] = {}
    notes: list[str] = []
    for key, name in overrides.items():
        try:
            role = Role(key)
        except ValueError as err:
            valid = ", ".join(r.value for r in Role)
            raise ConfigError(f"ingest.topics: unknown role '{key}' (roles: {valid})") from err
        if name not in topics:
            known = ", ".join(sorted(topics)) or "none"
            raise LogError(f"topic '{name}' for role {role.value} is not in the log (topics: {known})", path)
        msgtype = topics[name][0]
        if ROLE_BY_TYPE.get(msgtype) != role:
            raise LogError(
                f"topic '{name}' has type {msgtype}; role {role.value} needs {ROLE_TYPE[role]}", path
            )
        roles[role] = name
    for role in Role:
        if role in roles:
            continue
        cands = [(n, c) for n, (t, c) in topics.items() if ROLE_BY_TYPE.get(t) == role and c > 0]
        if not cands:
            continue
        if role == Role.TF_STATIC:
            # /tf carries the same type with far more messages; the static tree is what we want.
            static = [nc for nc in cands if nc[0].rstrip("/").endswith("tf_static")]
            if not static:
                continue
            cands = static
        cands.sort(key=lambda nc: (-nc[1], nc[0]))
        roles[role] = cands[0][0]
        if len(cands) > 1:
            listed = ", ".join(f"{n} ({c} msgs)" for n, c in cands)
            notes.append(
                f"{role.value}: {len(cands)} candidate topics ({listed}); chose {cands[0][0]} "
                f"(most messages); override with --topic {role.value}=TOPIC"
            )
    return roles, notes


class LogSource:
    """An opened log: topics, roles, and decoded streams. Use through `open_log()`."""

    def __init__(self, path: Path, backend: Backend, config: IngestConfig) -> None:
        self.path = path
        self.config = config
        self._backend = backend
        self.format: str = backend.format
        raw = backend.topics
        self.roles, notes = assign_roles(
            {n: (t.msgtype, t.count) for n, t in raw.items()}, dict(config.topics), path
        )
        self.warnings: list[str] = [*backend.warnings, *notes]
        by_topic = {topic: role for role, topic in self.roles.items()}
        self._clock = LogClock(getattr(backend, "log_times", lambda _topic: None),
                               [t for r, t in self.roles.items() if r in _TIMED_ROLES],
                               config.max_gap_s, str(path))
        self.warnings += self._clock.warnings
        self.topics: list[TopicInfo] = []
        for t in sorted(raw.values(), key=lambda t: t.name):
            count, first, last = t.count, t.first_ns, t.last_ns
            if t.name in self._clock.kept:  # what the time check kept of it
                first, last, count = self._clock.kept[t.name]
            self.topics.append(TopicInfo(
                name=t.name, msgtype=t.msgtype, count=count,
                first_ns=first if count else None, last_ns=last if count else None,
                role=by_topic.get(t.name), candidate_for=ROLE_BY_TYPE.get(t.msgtype)))
        self._counts = {t.name: t.count for t in self.topics}
        spans = [(t.first_ns, t.last_ns) for t in self.topics
                 if t.first_ns is not None and t.last_ns is not None]
        if self._clock.span is not None:
            # Topics the check does not follow count only where they agree with the log's span.
            lo = self._clock.span[0] - self._clock.max_gap_ns
            hi = self._clock.span[1] + self._clock.max_gap_ns
            spans = [(a, b) for a, b in spans if a >= lo and b <= hi] or spans
        self.start_ns: int = min(a for a, _ in spans) if spans else 0
        self.end_ns: int = max(b for _, b in spans) if spans else 0
        self._guards: dict[str, StampGuard] = {}
        self._extrinsics: Extrinsics | None = None
        self._frame_sources: dict[str, str] = {}
        self._small: dict[Role, _Rows] | None = None
        self._tf: tuple[list[Edge], TfSeen] | None = None
        self._tf_read: _TfRead | None = None
        self._tf_topics = sorted(
            n for n, t in raw.items()
            if t.msgtype in _TF_TYPES and t.count > 0 and n != self.roles.get(Role.TF_STATIC)
        )
        self._timing: Timing = None
        self._timing_done = False
        self._lidar_report: dict[str, Any] = {}
        self._point_parser: PointMessageParser | None = None
        self._beam_time: str | None = None
        self._beam_report: dict[str, Any] = {}
        self._pressure_unit_seen: PressureUnit | None = None
        self._temps: dict[str, _Rows] = {}

    # ----- context manager ---------------------------------------------------------------

    def __enter__(self) -> LogSource:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        self._backend.close()

    def _iter_raw(self, topics: list[str], start_ns: int | None, end_ns: int | None
                  ) -> Iterator[RawMessage]:
        """The backend's messages less those the time check dropped."""
        return self._clock.filter(self._backend.iter_raw(topics, start_ns, end_ns))

    def _warn(self, text: str) -> None:
        # Reading a stream twice must not say the same thing twice.
        if text not in self.warnings:
            self.warnings.append(text)
            logger.info("%s", text)

    # ----- lookup --------------------------------------------------------------------------

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / 1e9

    def topic_of(self, role_or_topic: Role | str) -> str | None:
        """The topic a role is read from (None if the log has none), or the topic itself."""
        if isinstance(role_or_topic, Role):
            return self.roles.get(role_or_topic)
        if role_or_topic in self._backend.topics:
            return role_or_topic
        try:
            return self.roles.get(Role(role_or_topic))
        except ValueError:
            raise LogError(f"no topic or role '{role_or_topic}' in the log", self.path) from None

    def count(self, role: Role | str) -> int:
        """Message count of the topic chosen for a role (0 if none)."""
        topic = self.topic_of(role)
        return self._counts.get(topic, 0) if topic is not None else 0

    def _require(self, role: Role, what: str) -> str:
        topic = self.roles.get(role)
        if topic is None:
            raise MissingDataError(
                f"no {what}: the log has no {ROLE_TYPE[role]} topic with messages "
                f"(topics: {', '.join(t.name for t in self.topics) or 'none'})",
                self.path,
            )
        return topic

    # ----- streams -------------------------------------------------------------------------

    def messages(
        self,
        role_or_topic: Role | str,
        start_ns: int | None = None,
        end_ns: int | None = None,
    ) -> Iterator[Record]:
        """Decoded records of one role or topic with start_ns <= stamp <= end_ns, stamp order.

        The backend is asked for a log-time window widened by `window_margin_s`, so only that
        part of the log is read; records are then filtered and re-sorted by header stamp.
        """
        topic = self.topic_of(role_or_topic)
        if topic is None:
            return iter(())
        return self._reorder(self._records(topic, start_ns, end_ns, self._backend.deserialize))

    def _records(
        self,
        topic: str,
        start_ns: int | None,
        end_ns: int | None,
        parse: Callable[[RawMessage], Any],
    ) -> Iterator[Record]:
        margin = int(self.config.window_margin_s * 1e9)
        lo = None if start_ns is None else start_ns - margin
        hi = None if end_ns is None else end_ns + margin
        backend = self._backend
        for raw in self._iter_raw([topic], lo, hi):
            msg = parse(raw)
            stamp = stamp_ns_of(msg, raw.log_time_ns)
            if (start_ns is not None and stamp < start_ns) or (end_ns is not None and stamp > end_ns):
                continue
            yield Record(stamp, raw.log_time_ns, raw.topic, msg, backend.raw_size(raw))

    def _reorder(self, items: Iterator[_Stamped]) -> Iterator[_Stamped]:
        """Items sorted by stamp_ns, as long as none arrives more than reorder_depth late."""
        depth = max(1, self.config.reorder_depth)
        heap: list[tuple[int, int, _Stamped]] = []
        for i, rec in enumerate(items):
            heapq.heappush(heap, (rec.stamp_ns, i, rec))
            if len(heap) > depth:
                yield heapq.heappop(heap)[2]
        while heap:
            yield heapq.heappop(heap)[2]

    def raw_messages(
        self, role_or_topic: Role | str, start_ns: int | None = None, end_ns: int | None = None
    ) -> Iterator[RawMessage]:
        """Undecoded messages of one topic by log time (for benchmarks and counting)."""
        topic = self.topic_of(role_or_topic)
        if topic is None:
            return iter(())
        return self._iter_raw([topic], start_ns, end_ns)

    def clouds(self, start_ns: int | None = None, end_ns: int | None = None) -> Iterator[Cloud]:
        """Lidar scans in stamp order, decoded one at a time (never all in memory), each point's
        time read as `lidar_timing` decided.

        Raises MissingDataError at the call (not at the first scan) when the log has no lidar.
        """
        topic = self._require(Role.LIDAR, "lidar")
        timing = self.lidar_timing()
        wanted = (timing.field,) if isinstance(timing, TimeSpec) else ()
        start = timing.sweep_start_ns if timing is not None else 0
        guard = self._guard(topic)
        clouds: Iterator[Cloud]
        if not start:
            clouds = (cloud_of(pts, stamp, frame, timing)
                      for stamp, _log, frame, pts in self._points(topic, start_ns, end_ns, wanted, guard))
        else:
            # Each scan timed from its sweep's start (the window asked for is in those times too).
            lo = None if start_ns is None else start_ns - start
            hi = None if end_ns is None else end_ns - start
            clouds = (_from_sweep_start(cloud_of(pts, stamp, frame, timing), start)
                      for stamp, _log, frame, pts in self._points(topic, lo, hi, wanted, guard))
        return self._guarded(topic, guard.forwards(self._reorder(clouds), lambda c: c.stamp_ns))

    def _points(self, topic: str, start_ns: int | None, end_ns: int | None,
                time_fields: tuple[str, ...] | None, guard: StampGuard | None = None
                ) -> Iterator[tuple[int, int, str, DecodedPoints]]:
        """(stamp, log time, frame, kept points) of each scan in log order: a PointCloud2, or a
        point message parsed from the log's own definition (Livox CustomMsg). With `guard`, the
        scans whose header stamp jumped away from their log time are left out."""
        where = f"{self.path} topic {topic}"
        max_bytes = int(self.config.max_cloud_mb * 1e6)
        drop_zero = self.config.drop_zero_points
        backend = self._backend
        extra = (self.config.lidar_time.field,) if self.config.lidar_time.field not in (
            "auto", "none") else ()
        candidates = tuple(dict.fromkeys((*extra, *TIME_FIELDS)))
        if self._backend.topics[topic].msgtype in POINT_MESSAGE_TYPES:

            def parsed() -> Iterator[tuple[int, int, PointMessage]]:
                for raw in self._iter_raw([topic], *self._window(start_ns, end_ns)):
                    encoding, data = backend.serialized(raw)
                    parser = self._point_message_parser(raw, encoding, where)
                    msg = parser.parse(data)
                    stamp = stamp_ns_of_scalars(msg.scalars) or int(raw.log_time_ns)
                    if self._in_window(stamp, start_ns, end_ns):
                        yield stamp, int(raw.log_time_ns), msg

            messages = parsed()
            if guard is not None:
                messages = guard.by_offset(messages, lambda m: m[0], lambda m: m[1])
            for stamp, log_time, msg in messages:
                yield stamp, log_time, _frame(msg), points_of(msg, drop_zero)
            return

        def parse(raw: RawMessage) -> Any:
            # The direct parser is several times faster than the generic deserialiser.
            encoding, data = backend.serialized(raw)
            if encoding in ("cdr", "ros1"):
                return parse_pointcloud2(data, encoding, where)
            return backend.deserialize(raw)

        records = self._records(topic, start_ns, end_ns, parse)
        if guard is not None:
            # Checked before the decode: a scan whose stamp jumped is never decoded.
            records = guard.by_offset(records, lambda r: r.stamp_ns, lambda r: r.log_time_ns)
        for rec in records:
            layout, buf = pointcloud2_layout(rec.msg, where, max_bytes, candidates)
            pts = decode_points(layout, buf, drop_zero, time_fields)
            yield rec.stamp_ns, rec.log_time_ns, str(rec.msg.header.frame_id), pts

    def _window(self, start_ns: int | None, end_ns: int | None) -> tuple[int | None, int | None]:
        margin = int(self.config.window_margin_s * 1e9)
        return (None if start_ns is None else start_ns - margin,
                None if end_ns is None else end_ns + margin)

    @staticmethod
    def _in_window(stamp: int, start_ns: int | None, end_ns: int | None) -> bool:
        return not ((start_ns is not None and stamp < start_ns) or (end_ns is not None and stamp > end_ns))

    def _point_message_parser(self, raw: RawMessage, encoding: str, where: str) -> PointMessageParser:
        if self._point_parser is None:
            msgtype = self._backend.topics[raw.topic].msgtype
            generic = self._backend.deserialize(raw)  # registers the definition, or says why not
            store = self._backend.typestore(raw)
            parser = PointMessageParser(store.fielddefs, msgtype, encoding, where)
            # The parse must agree with rosbags' generic deserialiser on the first message.
            _check_point_parser(parser, generic, self._backend.serialized(raw)[1], where)
            self._point_parser = parser
        return self._point_parser

    # ----- per-point time ------------------------------------------------------------------

    def lidar_timing(self) -> Timing:
        """How each lidar point's time is found: a time field's decided reading, the azimuth of
        a spinning lidar without one, or None (no deskew). Decided once, from the first scans;
        each decision not taken by the config is a warning or in `report()`."""
        if self._timing_done:
            return self._timing
        topic = self._require(Role.LIDAR, "lidar")
        cfg = self.config.lidar_time
        where = f"{self.path} topic {topic}"
        samples: list[tuple[int, int, str, DecodedPoints]] = []
        # Through a guard of their own: a scan whose stamp jumped must not decide, nor be
        # counted twice in the warnings.
        sampling = StampGuard(int(self.config.max_gap_s * 1e9))
        for item in self._points(topic, None, None, None, sampling):
            if len(item[3].xyz) >= 10:
                samples.append(item)
            if len(samples) >= TIME_SAMPLE_SCANS:
                break
        info = next(t for t in self.topics if t.name == topic)  # what the time check kept
        fallback = (int((info.last_ns - info.first_ns) / (info.count - 1))
                    if info.count > 1 and info.first_ns is not None and info.last_ns is not None
                    and info.last_ns > info.first_ns else 100_000_000)
        period = scan_period_ns([s[0] for s in samples], fallback)
        present = list(dict.fromkeys(name for s in samples for name in s[3].times))
        timing: Timing = None
        constant: list[str] = []
        report: dict[str, Any] = {"topic": topic, "scan_period_ms": round(period / 1e6, 3),
                                  "time_fields": present}
        if cfg.field != "none" and samples:
            if cfg.field != "auto" and cfg.field not in present:
                fields = ", ".join(n for n, *_ in self._lidar_fields(topic)) or "none"
                raise DecodeError(
                    f"ingest.lidar_time.field '{cfg.field}' is not a field of the lidar's points "
                    f"(fields: {fields})", where)
            names = [cfg.field] if cfg.field != "auto" else [
                n for n in (TIMEBASE_FIELD, *TIME_FIELDS) if n in present]
            first_error: DecodeError | None = None
            for name in names:
                values = [TimeSample(st, lt, p.times[name]) for st, lt, _, p in samples
                          if name in p.times]
                dtype = str(values[0].values.dtype.name) if values else "?"
                try:
                    spec = decide_time(name, dtype, values, period, cfg, where)
                except DecodeError as err:
                    first_error = first_error or err
                    continue
                if spec is None:
                    constant.append(name)
                    continue
                timing = spec
                break
            if timing is None and first_error is not None:
                raise first_error
        if isinstance(timing, TimeSpec):
            report["deskew"] = "per-point time"
            report["time"] = timing.to_json()
            if timing.shift_ns:
                self._warn(f"{topic}: per-point time {timing.describe()}")
        else:
            why = ""
            if constant:
                why = f" (field{'s' if len(constant) > 1 else ''} {', '.join(constant)} the same for every point)"
            timing, report = self._without_time(topic, cfg, samples, period, why, report)
        self._timing, self._timing_done, self._lidar_report = timing, True, report
        return timing

    def _without_time(self, topic: str, cfg: LidarTimeConfig,
                      samples: list[tuple[int, int, str, DecodedPoints]], period: int, why: str,
                      report: dict[str, Any]) -> tuple[Timing, dict[str, Any]]:
        if cfg.without_time == "none":
            self._warn(f"{topic}: no per-point time{why}: mapped without deskew "
                       "(ingest.lidar_time.without_time: none)")
            report["deskew"] = "none"
            return None, report
        spec, reason = decide_azimuth([(st, lt, p.xyz) for st, lt, _, p in samples], period, cfg)
        if spec is None:
            self._warn(f"{topic}: no per-point time{why}, and {reason}: mapped without deskew; "
                       "walls seen while the robot moves are smeared by its motion over a scan")
            report["deskew"] = "none"
            report["reason"] = reason
            return None, report
        self._warn(f"{topic}: no per-point time{why}: deskewed by each point's azimuth, "
                   f"{spec.describe()}; the header stamp taken as the sweep's "
                   f"{'end' if spec.shift_ns else 'start'}")
        report["deskew"] = "azimuth"
        report["time"] = spec.to_json()
        return spec, report

    def _first_record(self, topic: str) -> Record | None:
        return next(iter(self.messages(topic)), None)

    def _lidar_fields(self, topic: str) -> list[tuple[str, int, str, int]]:
        """(name, offset, type, count) of the lidar's point fields, from its first message."""
        msgtype = self._backend.topics[topic].msgtype
        for raw in self._iter_raw([topic], None, None):
            encoding, data = self._backend.serialized(raw)
            if msgtype in POINT_MESSAGE_TYPES:
                parser = self._point_message_parser(raw, encoding, f"{self.path} topic {topic}")
                dtype = parser.parse(data).points.dtype
                return [(str(n), int(dtype.fields[n][1]), dtype.fields[n][0].name, 1)
                        for n in dtype.names or ()]
            msg = (parse_pointcloud2(data, encoding) if encoding in ("cdr", "ros1")
                   else self._backend.deserialize(raw))
            layout, _ = pointcloud2_layout(msg, f"{self.path} topic {topic}")
            return list(layout.fields)
        return []

    def scans2d(self, start_ns: int | None = None, end_ns: int | None = None) -> Iterator[Scan2D]:
        """2D laser scans in stamp order as points (MissingDataError at the call if none), each
        beam's time in the order `scan2d_beam_time` decided."""
        topic = self._require(Role.SCAN2D, "2D laser scanner")
        reverse = self.scan2d_beam_time() == "reversed"
        guard = self._guard(topic)
        records = guard.by_offset(self._records(topic, start_ns, end_ns, self._backend.deserialize),
                                  lambda r: r.stamp_ns, lambda r: r.log_time_ns)
        scans = guard.forwards(self._reorder(records), lambda r: r.stamp_ns)
        where = f"{self.path} topic {topic}"
        return self._guarded(topic, (decode_laserscan(r.msg, r.stamp_ns, reverse, where)
                                     for r in scans))

    def _guard(self, topic: str) -> StampGuard:
        guard = self._guards.get(topic)
        if guard is None:
            guard = self._guards[topic] = StampGuard(int(self.config.max_gap_s * 1e9))
        return guard

    def _guarded(self, topic: str, items: Iterator[_Stamped]) -> Iterator[_Stamped]:
        """`items`, and once they are read (or abandoned) the guard's count in the warnings."""
        try:
            yield from items
        finally:
            self._note_guard(topic)

    def _note_guard(self, topic: str) -> None:
        where = f"{self.path} topic {topic}"
        text = self._guards[topic].describe(where)
        if text is None:
            return
        # One line per topic, its counts growing as more of the stream is read.
        self.warnings[:] = [w for w in self.warnings if not w.startswith(f"{where}: dropped ")]
        self.warnings.append(text)

    def stream_warnings(self) -> list[str]:
        """What reading the streams found and dropped (for a worker to hand back)."""
        out = []
        for topic, guard in self._guards.items():
            text = guard.describe(f"{self.path} topic {topic}")
            if text is not None:
                out.append(text)
        return out

    def scan2d_beam_time(self) -> str:
        """"as_stated" or "reversed": which way the LaserScan's beams run in time (config, else
        checked against the robot's turns, `mfmap.ingest.sweep2d`)."""
        if self._beam_time is not None:
            return self._beam_time
        topic = self._require(Role.SCAN2D, "2D laser scanner")
        mode = self.config.scan2d_beam_time
        if mode != "auto":
            self._beam_time, self._beam_report = mode, {"topic": topic, "beam_time": mode,
                                                        "decided": "config"}
            return mode
        check = self._check_sweep(topic)
        self._beam_time = "reversed" if check.decision == "reversed" else "as_stated"
        self._beam_report = {"topic": topic, "beam_time": self._beam_time, "decided": "data",
                             "check": check.to_json()}
        if check.decision == "reversed":
            self._warn(
                f"{topic}: the LaserScan's beam times run against its sweep (time_increment "
                f"positive, but deskewed so the turning scans overlap {check.residual_stated_m * 100:.1f} "
                f"cm apart against {check.residual_reversed_m * 100:.1f} cm read the other way, "
                f"{check.reason}: the rplidar_ros convention); beam i taken at "
                "(n - 1 - i) * time_increment (ingest.scan2d_beam_time: reversed)")
        elif check.decision == "unknown":
            self._beam_report["note"] = f"beam order not checked: {check.reason}"
        return self._beam_time

    def _check_sweep(self, topic: str) -> Any:
        from mfmap.ingest.sweep2d import (
            PlanarOdometry,
            ScanPair,
            SweepCheck,
            YawTrack,
            check_sweep,
            half_turns,
        )

        first = next(iter(self.messages(topic)), None)
        if first is None:
            return SweepCheck("unknown", "no scans")
        if float(first.msg.time_increment) == 0.0:
            return SweepCheck("unknown", "time_increment is 0: the scans carry no beam times")
        to_base = self.extrinsics().get(str(first.msg.header.frame_id))
        laser_to_base = to_base if to_base is not None else np.eye(4)
        imu, odom = self.imu(), self.odometry()
        if imu is not None and len(imu) > 10:
            imu_to_base = self.extrinsics().get(imu.frame_id)
            rot = np.eye(3) if imu_to_base is None else imu_to_base[:3, :3]
            yaw = YawTrack(imu.stamp_ns, (imu.gyro_rad_s @ rot.T)[:, 2])
        elif odom is not None and len(odom) > 10:
            yaw = YawTrack(odom.stamp_ns, odom.angular_rad_s[:, 2])
        else:
            return SweepCheck("unknown", "no IMU or wheel odometry to check it against; set "
                              "ingest.scan2d_beam_time")
        period = max(int(float(first.msg.scan_time) * 1e9), 0) or int(
            abs(float(first.msg.time_increment)) * len(first.msg.ranges) * 1e9)
        period = max(period, 1_000_000)
        grid = np.arange(self.start_ns, self.end_ns, 50_000_000, dtype=np.int64)
        times = half_turns(yaw, grid, lambda t: yaw.rate_at(t, period))
        if not times:
            return SweepCheck("unknown", "the robot never turns half a turn fast enough to tell")
        velocity_of = None
        planar = None
        if odom is not None and len(odom) > 1:
            t_odom = odom.stamp_ns.astype(np.float64)
            planar = PlanarOdometry(odom.stamp_ns, odom.xyz, odom.quat_xyzw)

            def velocity_of(stamp_ns: int) -> np.ndarray[Any, Any]:
                return np.array([np.interp(stamp_ns, t_odom, odom.linear_m_s[:, 0]),
                                 np.interp(stamp_ns, t_odom, odom.linear_m_s[:, 1])])

        pairs = []
        for ta, tb in times:
            a = next(iter(self.messages(topic, ta, ta + 3 * period)), None)
            b = next(iter(self.messages(topic, tb, tb + 3 * period)), None)
            if a is None or b is None or b.stamp_ns <= a.stamp_ns:
                continue
            turn = float(yaw.at(np.array([float(b.stamp_ns)]))[0] - yaw.at(np.array([float(a.stamp_ns)]))[0])
            shift = planar.shift(a.stamp_ns, b.stamp_ns) if planar is not None else np.zeros(2)
            pairs.append(ScanPair(a.msg, a.stamp_ns, b.msg, b.stamp_ns, turn, shift))
        try:
            return check_sweep(pairs, laser_to_base, yaw, velocity_of)
        except DecodeError as err:
            if err.path is not None:
                raise
            raise DecodeError(err.message, f"{self.path} topic {topic}") from err

    # ----- small series ----------------------------------------------------------------------

    def _small_streams(self) -> dict[Role, _Rows]:
        """Barometer, IMU, odometry and /tf_static, read together in ONE pass over the log.

        Kept as compact rows (floats per message), not message objects, so an hour of IMU
        costs tens of MB. A message that cannot be decoded marks its role only; the error is
        raised when that role is asked for.
        """
        if self._small is not None:
            return self._small
        topics = {self.roles[r]: r for r in _SMALL_ROLES if r in self.roles}
        out: dict[Role, _Rows] = {role: _Rows() for role in topics.values()}
        # Every Temperature topic (unless one is chosen): the barometer's is found by its frame.
        temps = self._temperature_topics()
        self._temps = {name: _Rows() for name in temps}
        topics.update({name: Role.TEMPERATURE for name in temps})
        direct: dict[str, bool] = {}  # topic -> the direct parser agreed on its first message
        tf_topics = self._tf_topics_all() if self._tf is None and self._tf_read is None else []
        tf = _TfRead(self)
        for raw in self._iter_raw([*topics, *tf_topics], None, None):
            if raw.topic not in topics:
                tf.add(raw)
                continue
            role = topics[raw.topic]
            rows = self._temps[raw.topic] if role == Role.TEMPERATURE else out[role]
            if rows.error is not None:
                continue
            try:
                if role in _FLAT:
                    if raw.topic not in direct:
                        direct[raw.topic] = self._direct_agrees(raw, role)
                    if direct[raw.topic]:
                        rows.add_row(*self._read_direct(raw, role))
                        continue
                msg = self._backend.deserialize(raw)
                rows.add(role, msg, stamp_ns_of(msg, raw.log_time_ns))
            except DecodeError as err:
                rows.error = err
            except (AttributeError, TypeError, ValueError, IndexError, struct.error) as err:
                rows.error = DecodeError(
                    f"unexpected {ROLE_TYPE[role]} layout ({err})", f"{self.path} topic {raw.topic}"
                )
        self._small = out
        if tf_topics:
            self._tf_read = tf
        return out

    def _read_direct(self, raw: RawMessage, role: Role) -> tuple[int, tuple[float, ...], str, str]:
        """One `_FLAT` message by the direct parser: `_Rows.add_row`'s stamp, row and frames
        (the log time when the header's stamp is zero, as `stamp_ns_of`)."""
        n_doubles, child_frame, pick = _FLAT[role]
        encoding, data = self._backend.serialized(raw)
        stamp_ns, frame, child, doubles = parse_stamped_doubles(data, encoding, n_doubles, child_frame)
        return stamp_ns or int(raw.log_time_ns), pick(doubles), frame, child

    def _direct_agrees(self, raw: RawMessage, role: Role) -> bool:
        """Does the direct parser read this message exactly as the generic deserialiser does?
        (Not for a message type of the same name with other fields: then the generic one.)"""
        try:
            direct, reference = _Rows(), _Rows()
            direct.add_row(*self._read_direct(raw, role))
            msg = self._backend.deserialize(raw)
            reference.add(role, msg, stamp_ns_of(msg, raw.log_time_ns))
        except Exception:  # any failure: the generic path decides (and reports it)
            return False
        return (direct.stamps, direct.values, direct.frame, direct.child) == (
            reference.stamps, reference.values, reference.frame, reference.child)

    def _rows(self, role: Role) -> _Rows | None:
        rows = self._small_streams().get(role)
        if rows is not None and rows.error is not None:
            raise rows.error
        return rows

    def pressure(self) -> PressureSeries:
        """Barometer trace in Pa, sorted by stamp. hPa/kPa publishers are converted."""
        topic = self._require(Role.BARO, "barometer")
        rows = self._rows(Role.BARO)
        if rows is None or not rows.stamps:
            raise MissingDataError(f"no barometer messages on {topic}", self.path)
        stamps = np.array(rows.stamps, dtype=np.int64)
        values = np.array(rows.values, dtype=np.float64).reshape(-1)
        order = self._series_order(topic, stamps)
        stamps, values = stamps[order], values[order]
        finite = np.isfinite(values)
        if not finite.all():
            self._warn(f"{topic}: dropped {int((~finite).sum())} non-finite pressure readings")
            stamps, values = stamps[finite], values[finite]
        if stamps.shape[0] == 0:
            raise DecodeError(f"every barometer reading is NaN or infinite ({len(rows.stamps)} "
                              "messages): the sensor gave no pressure", f"{self.path} topic {topic}")
        unit = self._pressure_unit(values, topic)
        self._pressure_unit_seen = unit
        if unit.to_pa != 1.0:
            values = values * unit.to_pa
            self._warn(
                f"{topic}: pressure published in {unit.name} (median {np.median(values) / unit.to_pa:.2f}),"
                f" not Pa as sensor_msgs/FluidPressure specifies; converted to Pa"
            )
        return PressureSeries(stamp_ns=stamps, pressure_pa=values, frame_id=rows.frame)

    def _series_order(self, topic: str, stamps: np.ndarray[Any, Any]) -> np.ndarray[Any, Any]:
        """Indices that sort a small stream by header stamp, its inconsistent stamps and
        repeated ones left out (with a warning)."""
        order, check, repeats = series_order(stamps, int(self.config.max_gap_s * 1e9))
        where = f"{self.path} topic {topic}"
        if check.dropped:
            self._warn(check.describe(f"{where} (header stamps)", int(stamps.min()),
                                      self.config.max_gap_s))
        if repeats:
            self._warn(f"{where}: dropped {repeats} messages stamped like the one before them")
        return order

    def _pressure_unit(self, values: np.ndarray[Any, Any], topic: str) -> PressureUnit:
        fixed = {"Pa": 1.0, "hPa": 100.0, "kPa": 1000.0}
        if self.config.pressure_unit != "auto":
            return PressureUnit(self.config.pressure_unit, fixed[self.config.pressure_unit])
        unit = pressure_unit(values)
        if unit is None:
            raise DecodeError(
                f"barometer readings (median {float(np.median(values)):.3g}) are not a plausible "
                "air pressure in Pa, hPa or kPa; set ingest.pressure_unit",
                f"{self.path} topic {topic}",
            )
        return unit

    def _temperature_topics(self) -> list[str]:
        """The chosen Temperature topic when one is set in the config, else every one with messages."""
        if Role.TEMPERATURE.value in self.config.topics:
            return [self.roles[Role.TEMPERATURE]]
        return sorted(t.name for t in self.topics if t.candidate_for == Role.TEMPERATURE and t.count > 0)

    def temperature(self) -> TemperatureSeries | None:
        """The barometer's air temperature: the sensor_msgs/Temperature topic in the barometer's
        frame (most barometer drivers publish one), or the configured one; None when there is
        none. Temperatures of other frames (a CPU, a motor) say nothing about the air."""
        self._small_streams()
        baro = self._first_frame(Role.BARO) if Role.BARO in self.roles else None
        chosen = Role.TEMPERATURE.value in self.config.topics
        found = []
        for name, rows in sorted(self._temps.items()):
            if rows.error is not None:
                if chosen:
                    raise rows.error
                self._warn(f"{name}: {rows.error}; not used for the barometer's scale")
                continue
            if rows.stamps and (chosen or (baro is not None and rows.frame.lstrip("/") == baro.lstrip("/"))):
                found.append((len(rows.stamps), name, rows))
        if not found:
            if self._temps and baro is not None and not chosen:
                frames = ", ".join(f"{n} ('{r.frame}')" for n, r in sorted(self._temps.items()))
                self._warn(f"no Temperature topic in the barometer's frame '{baro}' ({frames}): the "
                           "barometer's scale is not taken from a temperature")
            return None
        _, name, rows = max(found, key=lambda f: (f[0], f[1]))
        stamps = np.array(rows.stamps, dtype=np.int64)
        values = np.array(rows.values, dtype=np.float64).reshape(-1)
        order = np.argsort(stamps, kind="stable")
        finite = np.isfinite(values[order])
        return TemperatureSeries(stamps[order][finite], values[order][finite], rows.frame, name)

    def imu(self) -> ImuSeries | None:
        """IMU samples sorted by stamp, or None when the log has no IMU."""
        rows = self._rows(Role.IMU)
        if rows is None or not rows.stamps:
            return None
        stamps = np.array(rows.stamps, dtype=np.int64)
        v = np.array(rows.values, dtype=np.float64)
        order = self._series_order(self.roles[Role.IMU], stamps)
        v = v[order]
        quat = v[:, 6:10].copy()
        # orientation_covariance[0] == -1 means "no orientation estimate" (sensor_msgs/Imu).
        quat[v[:, 10] == -1.0] = np.nan
        return ImuSeries(
            stamp_ns=stamps[order],
            gyro_rad_s=v[:, 0:3].copy(),
            accel_m_s2=v[:, 3:6].copy(),
            orientation_xyzw=quat,
            frame_id=rows.frame,
        )

    def odometry(self) -> OdomSeries | None:
        """Odometry sorted by stamp, or None when the log has none."""
        rows = self._rows(Role.ODOM)
        if rows is None or not rows.stamps:
            return None
        stamps = np.array(rows.stamps, dtype=np.int64)
        order = self._series_order(self.roles[Role.ODOM], stamps)
        v = np.array(rows.values, dtype=np.float64)[order]
        return OdomSeries(
            stamp_ns=stamps[order],
            xyz=v[:, 0:3].copy(),
            quat_xyzw=v[:, 3:7].copy(),
            linear_m_s=v[:, 7:10].copy(),
            angular_rad_s=v[:, 10:13].copy(),
            frame_id=rows.frame,
            child_frame_id=rows.child,
        )

    def _tf_topics_all(self) -> list[str]:
        static = self.roles.get(Role.TF_STATIC)
        return [t for t in (static, *self._tf_topics) if t is not None]

    def _transforms(self, alone: bool = False) -> tuple[list[Edge], TfSeen]:
        """The transforms of /tf_static, and what /tf holds: read with the other small streams
        in their one pass, or with `alone` by themselves (a few messages, or for /tf one entry
        per frame pair however long the log)."""
        if self._tf is None and not alone:
            self._small_streams()
        if self._tf is None and self._tf_read is not None:
            self._tf = self._tf_read.result()  # a transform message that failed raises here
        if self._tf is None:
            tf = _TfRead(self)
            topics = self._tf_topics_all()
            for raw in self._iter_raw(topics, None, None) if topics else iter(()):
                tf.add(raw)
            self._tf = tf.result()
        return self._tf

    def _sensor_frames(self) -> dict[str, list[str]]:
        """Frame of each sensor the build uses -> its roles (a 2D laser only without a 3D one)."""
        out: dict[str, list[str]] = {}
        for role in (Role.LIDAR, Role.SCAN2D, Role.IMU, Role.BARO):
            if role == Role.SCAN2D and Role.LIDAR in self.roles:
                continue
            frame = self._first_frame(role)
            if frame is None:
                continue
            out.setdefault(frame.lstrip("/"), []).append(role.value)
        return out

    def frame_status(self, alone: bool = False) -> tuple[Extrinsics, dict[str, str], list[str]]:
        """(extrinsics, where each sensor frame's transform comes from, problems): a problem is
        the one-line reason a needed sensor frame has no transform to the base. `alone` reads
        the transforms by themselves, not in the small streams' pass."""
        base = self.config.base_frame.lstrip("/")
        log_edges, seen = self._transforms(alone)
        edges = [*log_edges, *seen.static_edges(), *config_edges(self.config.extrinsics)]
        tree = connect(base, edges)
        poses = {f: p for f, p in tree.poses.items() if f != base}
        sources: dict[str, str] = {}
        missing: dict[str, list[str]] = {}
        optional: dict[str, list[str]] = {}
        for frame, roles in self._sensor_frames().items():
            if frame in ("", base):
                sources[frame or base] = "base"
                continue
            if frame in tree.poses:
                sources[frame] = tree.sources[frame]
                continue
            needed = any(Role(r) in _NEEDED_FRAMES for r in roles)
            (missing if needed else optional)[frame] = roles
        problems: list[str] = []
        searched = " and ".join(
            t for t in ([self.roles[Role.TF_STATIC]] if Role.TF_STATIC in self.roles else [])
            + self._tf_topics) or "the log (it has no /tf_static or /tf)"
        if missing:
            message = missing_message(base, missing, tree, searched, edges, seen.moving())
            if self.config.assume_identity_extrinsics:
                self._warn(f"{message.split(': give')[0]}: placed at the base with no rotation "
                           "(--assume-identity-extrinsics)")
                for frame in missing:
                    sources[frame] = "identity (assumed)"
                    poses[frame] = np.eye(4)
            else:
                problems.append(message)
                for frame in missing:
                    sources[frame] = "missing"
        for frame, roles in optional.items():
            self._warn(
                f"no transform from '{base}' to frame '{frame}' ({', '.join(roles)}): placed at "
                "the base (a barometer's offset shifts every pressure alike, which the floors do "
                "not see)")
            sources[frame] = "identity (not needed)"
            poses[frame] = np.eye(4)
        self._frame_sources = sources
        return Extrinsics(base_frame=self.config.base_frame, sensor_to_base=poses), sources, problems

    def extrinsics(self) -> Extrinsics:
        """Pose in `config.base_frame` of every frame the log's static transforms (/tf_static,
        and pairs that never change on /tf) and `config.extrinsics` connect to it.

        A lidar, 2D laser or IMU frame left unconnected raises MissingDataError naming the
        frames and the ways out, unless `assume_identity_extrinsics` (then identity, a warning).
        """
        if self._extrinsics is not None:
            return self._extrinsics
        extrinsics, _, problems = self.frame_status()
        if problems:
            raise MissingDataError(problems[0], self.path)
        self._extrinsics = extrinsics
        return extrinsics

    def _first_frame(self, role: Role) -> str | None:
        topic = self.roles.get(role)
        if topic is None:
            return None
        if role in _SMALL_ROLES and self._small is not None:
            rows = self._small.get(role)
            return rows.frame if rows is not None and rows.stamps else None
        for raw in self._iter_raw([topic], None, None):
            if self._backend.topics[topic].msgtype in POINT_MESSAGE_TYPES:
                encoding, data = self._backend.serialized(raw)
                parser = self._point_message_parser(raw, encoding, f"{self.path} topic {topic}")
                return _frame(parser.parse(data))
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
        rows: list[dict[str, Any]] = []
        problems: list[str] = []

        def attempt(fn: Callable[[], Any]) -> Any:
            try:
                return fn()
            except MfmapError as err:
                problems.append(str(err))
                return None

        status = attempt(partial(self.frame_status, not check))
        sources: dict[str, str] = status[1] if status is not None else {}
        if status is not None:
            problems += [f"{self.path}: {p}" for p in status[2]]
        extrinsics = status[0] if status is not None else None
        for role in (Role.LIDAR, Role.SCAN2D, Role.IMU, Role.BARO):
            topic = self.roles.get(role)
            if topic is None:
                continue
            frame = (attempt(partial(self._first_frame, role)) or "").lstrip("/")
            row: dict[str, Any] = {"topic": topic, "role": role.value,
                                   "type": self._backend.topics[topic].msgtype, "frame": frame,
                                   "transform": sources.get(frame, "base" if frame in ("", self.config.base_frame) else "-")}
            pose = extrinsics.get(frame) if extrinsics is not None else None
            if pose is not None and row["transform"] not in ("base", "missing"):
                angle = float(np.degrees(np.arccos(np.clip((np.trace(pose[:3, :3]) - 1) / 2, -1, 1))))
                row["mount"] = (f"xyz {pose[0, 3]:+.3f} {pose[1, 3]:+.3f} {pose[2, 3]:+.3f} m, "
                                f"turned {angle:.1f} deg")
            if role == Role.LIDAR:
                fields = attempt(partial(self._lidar_fields, topic)) or []
                row["fields"] = " ".join(f"{n}:{t}" + (f"[{c}]" if c > 1 else "") for n, _, t, c in fields)
                timing = attempt(self.lidar_timing)
                if self._timing_done:
                    row["time"] = ("none" if timing is None else timing.describe()
                                   if isinstance(timing, TimeSpec) else f"from azimuth: {timing.describe()}")
                    row["deskew"] = self._lidar_report.get("deskew", "none")
            elif role == Role.SCAN2D:
                first = attempt(partial(self._first_record, topic))
                if first is not None:
                    m = first.msg
                    row["fields"] = (f"{len(m.ranges)} beams from {np.degrees(float(m.angle_min)):.1f} deg "
                                     f"by {np.degrees(float(m.angle_increment)):+.3f} deg")
                    row["time"] = f"time_increment {float(m.time_increment) * 1e6:+.2f} us"
                if check and Role.LIDAR not in self.roles and self.config.scan2d_beam_time == "auto":
                    order = attempt(self.scan2d_beam_time)
                    if order is not None:
                        row["deskew"] = f"beams {order.replace('_', ' ')}"
                        note = self._beam_report.get("note")
                        if note:
                            row["deskew"] += f" ({note})"
                else:
                    row["deskew"] = f"beams {self.config.scan2d_beam_time.replace('_', ' ')}"
            elif role == Role.IMU:
                first = attempt(partial(self._first_record, topic))
                if first is not None:
                    cov0 = float(first.msg.orientation_covariance[0])
                    row["fields"] = "gyro, accel" + (", no orientation (covariance[0] = -1)"
                                                     if cov0 == -1.0 else ", orientation")
            elif role == Role.BARO and check:
                series = attempt(self.pressure)
                if series is not None and self._pressure_unit_seen is not None:
                    row["fields"] = f"pressure in {self._pressure_unit_seen.name}"
            rows.append(row)
        if Role.LIDAR not in self.roles and Role.SCAN2D not in self.roles:
            problems.append(f"{self.path}: the log has no lidar (neither PointCloud2 nor LaserScan)")
        return rows, problems

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
        if self._lidar_report:
            out["lidar"] = dict(self._lidar_report)
        if self._beam_report:
            out["scan2d"] = dict(self._beam_report)
        if self._frame_sources:
            out["frames"] = dict(sorted(self._frame_sources.items()))
        if self._pressure_unit_seen is not None:
            out["pressure_unit"] = self._pressure_unit_seen.name
        return out


class _TfRead:
    """Collects transform messages: /tf_static's as edges, /tf's per frame pair."""

    def __init__(self, src: LogSource) -> None:
        self.src = src
        self.static = src.roles.get(Role.TF_STATIC)
        self.edges: list[Edge] = []
        self.seen = TfSeen()
        self.error: DecodeError | None = None

    def add(self, raw: RawMessage) -> None:
        if self.error is not None:
            return
        try:
            msg = self.src._backend.deserialize(raw)
            for tf in msg.transforms:
                parent = str(tf.header.frame_id).lstrip("/")
                child = str(tf.child_frame_id).lstrip("/")
                matrix = transform_matrix(tf.transform)
                if raw.topic == self.static:
                    self.edges.append(Edge(parent, child, matrix, "/tf_static"))
                else:
                    self.seen.add(parent, child, matrix)
        except DecodeError as err:
            self.error = err
        except (AttributeError, TypeError, ValueError) as err:
            self.error = DecodeError(f"unexpected transform message layout ({err})",
                                     f"{self.src.path} topic {raw.topic}")

    def result(self) -> tuple[list[Edge], TfSeen]:
        if self.error is not None:
            raise self.error
        return self.edges, self.seen


def _from_sweep_start(cloud: Cloud, start_ns: int) -> Cloud:
    """The scan stamped at its sweep's start, `start_ns` from its header stamp."""
    offsets = None if cloud.t_offset_ns is None else cloud.t_offset_ns - np.int64(start_ns)
    return replace(cloud, stamp_ns=cloud.stamp_ns + start_ns, t_offset_ns=offsets)


def _frame(msg: PointMessage) -> str:
    return str(msg.scalars.get("header.frame_id", ""))


def _check_point_parser(parser: PointMessageParser, generic: Any, data: Any, where: str) -> None:
    """The schema-driven parse of a message must read what rosbags' deserialiser reads."""
    parsed = parser.parse(data)
    points = list(getattr(generic, parser.points_field))
    ok = len(points) == len(parsed.points)
    for k in ([0, len(points) - 1] if points and ok else []):
        for name in parsed.points.dtype.names or ():
            a, b = float(getattr(points[k], name)), float(parsed.points[name][k])
            ok &= (a == b) or (a != a and b != b)
    if not ok:
        raise DecodeError(f"{parser.msgtype}: the points read from its definition disagree with "
                          "the generic deserialiser's", where)


def open_log(path: Path | str, config: IngestConfig | None = None) -> LogSource:
    """Open a log: a `.mcap` file, a ROS 1 `.bag`, a ROS 2 bag folder or a folder of `.mcap`."""
    path = Path(path)
    config = config or IngestConfig()
    backend = _open_backend(path)
    try:
        _check_one_recording(backend, path, config.max_gap_s)
        return LogSource(path, backend, config)
    except BaseException:
        backend.close()
        raise


def _check_one_recording(backend: Backend, path: Path, max_gap_s: float) -> None:
    """Several .mcap files are one log only when they follow on from (or overlap) each other:
    two unrelated recordings in one folder must not become one log years long."""
    spans = []
    for fi in getattr(backend, "files", []):
        if fi.first_ns:
            spans.append((min(fi.first_ns.values()), max(fi.last_ns.values()), fi.path.name))
    spans.sort()
    end, last_name = None, ""
    for first, last, name in spans:
        if end is not None and first - end > max_gap_s * 1e9:
            raise LogError(
                f"holds .mcap files of different recordings: {name} starts "
                f"{(first - end) / 1e9:.0f} s after {last_name} ends (more than ingest.max_gap_s, "
                f"{max_gap_s:g} s); build each recording on its own", path)
        if end is None or last > end:
            end, last_name = last, name


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
