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
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, TypeVar

import numpy as np
import yaml

from mfmap.errors import ConfigError, DecodeError, LogError, MfmapError, MissingDataError
from mfmap.ingest.backend import Backend, RawMessage
from mfmap.ingest.config import IngestConfig
from mfmap.ingest.decode import (
    PressureUnit,
    decode_laserscan,
    decode_pointcloud2,
    parse_pointcloud2,
    parse_stamped_doubles,
    pressure_unit,
    stamp_ns_of,
    transform_matrix,
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
    TopicInfo,
)

logger = logging.getLogger(__name__)

ROLE_TYPE: dict[Role, str] = {role: msgtype for msgtype, role in ROLE_BY_TYPE.items()}


@dataclass(frozen=True)
class Record:
    """One decoded message: header stamp (log time if the header is zero), log time, topic."""

    stamp_ns: int
    log_time_ns: int
    topic: str
    msg: Any
    size_bytes: int = 0


_Stamped = TypeVar("_Stamped", Record, Cloud, Scan2D)


_SMALL_ROLES = (Role.BARO, Role.IMU, Role.ODOM, Role.TF_STATIC)
# Streams whose clock the time check follows (tf_static's messages hold whenever they came).
_TIMED_ROLES = (Role.LIDAR, Role.SCAN2D, Role.BARO, Role.IMU, Role.ODOM)


@dataclass
class _Rows:
    """One small stream as plain numbers: a stamp and a row of floats per message."""

    stamps: list[int] = field(default_factory=list)
    values: list[tuple[float, ...]] = field(default_factory=list)
    transforms: list[tuple[str, str, np.ndarray[Any, Any]]] = field(default_factory=list)
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
        elif role == Role.IMU:
            w, a, q = msg.angular_velocity, msg.linear_acceleration, msg.orientation
            row = (w.x, w.y, w.z, a.x, a.y, a.z, q.x, q.y, q.z, q.w, float(msg.orientation_covariance[0]))
        elif role == Role.ODOM:
            p, q = msg.pose.pose.position, msg.pose.pose.orientation
            v, w = msg.twist.twist.linear, msg.twist.twist.angular
            row = (p.x, p.y, p.z, q.x, q.y, q.z, q.w, v.x, v.y, v.z, w.x, w.y, w.z)
        else:
            for tf in msg.transforms:
                self.transforms.append(
                    (
                        str(tf.header.frame_id).lstrip("/"),
                        str(tf.child_frame_id).lstrip("/"),
                        transform_matrix(tf.transform),
                    )
                )
            row = ()
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
        self._small: dict[Role, _Rows] | None = None

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
        """Lidar scans in stamp order, decoded one at a time (never all in memory).

        Raises MissingDataError at the call (not at the first scan) when the log has no lidar.
        """
        topic = self._require(Role.LIDAR, "lidar")
        where = f"{self.path} topic {topic}"
        max_bytes = int(self.config.max_cloud_mb * 1e6)
        backend = self._backend

        def parse(raw: RawMessage) -> Any:
            # The direct parser is several times faster than the generic deserialiser.
            encoding, data = backend.serialized(raw)
            if encoding in ("cdr", "ros1"):
                return parse_pointcloud2(data, encoding, where)
            return backend.deserialize(raw)

        # Decode each scan while its bytes are still in cache, then restore stamp order.
        guard = self._guard(topic)
        records = guard.by_offset(self._records(topic, start_ns, end_ns, parse),
                                  lambda r: r.stamp_ns, lambda r: r.log_time_ns)
        clouds = (
            decode_pointcloud2(rec.msg, rec.stamp_ns, where, max_bytes, self.config.drop_zero_points)
            for rec in records
        )
        return self._guarded(topic, guard.forwards(self._reorder(clouds), lambda c: c.stamp_ns))

    def scans2d(self, start_ns: int | None = None, end_ns: int | None = None) -> Iterator[Scan2D]:
        """2D laser scans in stamp order as points (MissingDataError at the call if none)."""
        topic = self._require(Role.SCAN2D, "2D laser scanner")
        guard = self._guard(topic)
        records = guard.by_offset(self._records(topic, start_ns, end_ns, self._backend.deserialize),
                                  lambda r: r.stamp_ns, lambda r: r.log_time_ns)
        scans = guard.forwards(self._reorder(records), lambda r: r.stamp_ns)
        where = f"{self.path} topic {topic}"
        return self._guarded(topic, (decode_laserscan(r.msg, r.stamp_ns, where) for r in scans))

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
        direct: dict[str, bool] = {}  # topic -> the direct parser agreed on its first message
        for raw in self._iter_raw(list(topics), None, None):
            role = topics[raw.topic]
            rows = out[role]
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

    def extrinsics(self) -> Extrinsics:
        """Pose of every static frame in `config.base_frame`, from /tf_static.

        Sensor frames (lidar, IMU, barometer, 2D laser) that the tree does not connect to the
        base get identity, with a warning.
        """
        if self._extrinsics is not None:
            return self._extrinsics
        base = self.config.base_frame.lstrip("/")
        edges: dict[str, list[tuple[str, np.ndarray[Any, Any]]]] = {}
        topic = self.roles.get(Role.TF_STATIC)
        if topic is None:
            self._warn("no /tf_static in the log: sensor extrinsics taken as identity")
        else:
            rows = self._rows(Role.TF_STATIC)
            for parent, child, t_parent_child in rows.transforms if rows is not None else []:
                edges.setdefault(parent, []).append((child, t_parent_child))
                edges.setdefault(child, []).append((parent, np.linalg.inv(t_parent_child)))
        poses: dict[str, np.ndarray[Any, Any]] = {base: np.eye(4)}
        queue = [base]
        while queue:
            frame = queue.pop(0)
            for other, t_frame_other in edges.get(frame, []):
                if other not in poses:
                    poses[other] = poses[frame] @ t_frame_other
                    queue.append(other)
        if edges and len(poses) == 1:
            self._warn(
                f"/tf_static does not reach base frame '{base}' (frames: {', '.join(sorted(edges))})"
            )
        sensor_to_base = {f: p for f, p in poses.items() if f != base}
        unresolved: dict[str, list[str]] = {}
        for role in (Role.LIDAR, Role.SCAN2D, Role.IMU, Role.BARO):
            sensor_frame = self._first_frame(role)
            if sensor_frame is None or sensor_frame.lstrip("/") == base:
                continue
            pose = poses.get(sensor_frame.lstrip("/"))
            if pose is None:
                unresolved.setdefault(sensor_frame, []).append(role.value)
                pose = np.eye(4)
            sensor_to_base[sensor_frame] = pose
        for sensor_frame, roles in unresolved.items():
            self._warn(
                f"no static transform from '{base}' to frame '{sensor_frame}' "
                f"({', '.join(roles)}): using identity"
            )
        self._extrinsics = Extrinsics(base_frame=self.config.base_frame, sensor_to_base=sensor_to_base)
        return self._extrinsics

    def _first_frame(self, role: Role) -> str | None:
        topic = self.roles.get(role)
        if topic is None:
            return None
        if role in _SMALL_ROLES:
            rows = self._small_streams().get(role)
            return rows.frame if rows is not None and rows.stamps else None
        for raw in self._iter_raw([topic], None, None):
            msg = self._backend.deserialize(raw)
            header = getattr(msg, "header", None)
            return str(header.frame_id) if header is not None else None
        return None


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
            "warnings": list(self.warnings),
        }


def describe_log(path: Path | str, config: IngestConfig | None = None) -> LogSummary:
    """Topics, types, roles, counts and times of a log, without decoding any message."""
    with open_log(path, config) as src:
        return LogSummary(
            path=src.path,
            format=src.format,
            topics=list(src.topics),
            roles=dict(src.roles),
            start_ns=src.start_ns,
            end_ns=src.end_ns,
            warnings=list(src.warnings),
        )
