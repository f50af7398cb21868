"""The lidar's scans: PointCloud2 or a point message of its own (Livox CustomMsg), each point's
time read as decided once from the first scans (a time field, the azimuth, or none)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from typing import Any

import numpy as np

from mfmap.errors import DecodeError
from mfmap.ingest.backend import RawMessage
from mfmap.ingest.config import LidarTimeConfig
from mfmap.ingest.core import LogCore
from mfmap.ingest.decode import (
    DecodedPoints,
    Timing,
    cloud_of,
    decode_points,
    pointcloud2_layout,
)
from mfmap.ingest.lidartime import (
    TIME_FIELDS,
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
from mfmap.ingest.timecheck import StampGuard
from mfmap.ingest.wire import parse_pointcloud2
from mfmap.types import Cloud, Role

# Scans sampled to decide how a lidar's per-point time reads.
TIME_SAMPLE_SCANS = 12
# Streams whose clock the time check follows (tf_static's messages hold whenever they came).


class LidarReader:
    """A log's lidar scans, and how each point's time is read."""

    def __init__(self, core: LogCore) -> None:
        self._core = core
        self.timing: Timing = None
        self.timing_done = False
        self.report: dict[str, Any] = {}
        self._point_parser: PointMessageParser | None = None

    def clouds(self, start_ns: int | None = None, end_ns: int | None = None) -> Iterator[Cloud]:
        """Lidar scans in stamp order, decoded one at a time (never all in memory), each point's
        time read as `lidar_timing` decided.

        Raises MissingDataError at the call (not at the first scan) when the log has no lidar.
        """
        topic = self._core._require(Role.LIDAR, "lidar")
        timing = self.decide_timing()
        wanted = (timing.field,) if isinstance(timing, TimeSpec) else ()
        start = timing.sweep_start_ns if timing is not None else 0
        guard = self._core._guard(topic)
        clouds: Iterator[Cloud]
        if not start:
            clouds = (cloud_of(pts, stamp, frame, timing)
                      for stamp, _log, frame, pts in self._points(topic, start_ns, end_ns, wanted, guard))
        else:
            # Each scan timed from its sweep's start (the window asked for is in those times too).
            lo = None if start_ns is None else start_ns - start
            hi = None if end_ns is None else end_ns - start
            clouds = (from_sweep_start(cloud_of(pts, stamp, frame, timing), start)
                      for stamp, _log, frame, pts in self._points(topic, lo, hi, wanted, guard))
        return self._core._guarded(topic, guard.forwards(self._core._reorder(clouds), lambda c: c.stamp_ns))

    def _points(self, topic: str, start_ns: int | None, end_ns: int | None,
                time_fields: tuple[str, ...] | None, guard: StampGuard | None = None
                ) -> Iterator[tuple[int, int, str, DecodedPoints]]:
        """(stamp, log time, frame, kept points) of each scan in log order: a PointCloud2, or a
        point message parsed from the log's own definition (Livox CustomMsg). With `guard`, the
        scans whose header stamp jumped away from their log time are left out."""
        where = f"{self._core.path} topic {topic}"
        max_bytes = int(self._core.config.max_cloud_mb * 1e6)
        drop_zero = self._core.config.drop_zero_points
        backend = self._core._backend
        extra = (self._core.config.lidar_time.field,) if self._core.config.lidar_time.field not in (
            "auto", "none") else ()
        candidates = tuple(dict.fromkeys((*extra, *TIME_FIELDS)))
        if self._core._backend.topics[topic].msgtype in POINT_MESSAGE_TYPES:

            def parsed() -> Iterator[tuple[int, int, PointMessage]]:
                for raw in self._core._iter_raw([topic], *self._core._window(start_ns, end_ns)):
                    encoding, data = backend.serialized(raw)
                    parser = self.point_message_parser(raw, encoding, where)
                    msg = parser.parse(data)
                    stamp = stamp_ns_of_scalars(msg.scalars) or int(raw.log_time_ns)
                    if self._core._in_window(stamp, start_ns, end_ns):
                        yield stamp, int(raw.log_time_ns), msg

            messages = parsed()
            if guard is not None:
                messages = guard.by_offset(messages, lambda m: m[0], lambda m: m[1])
            for stamp, log_time, msg in messages:
                yield stamp, log_time, point_frame(msg), points_of(msg, drop_zero)
            return

        def parse(raw: RawMessage) -> Any:
            # The direct parser is several times faster than the generic deserialiser.
            encoding, data = backend.serialized(raw)
            if encoding in ("cdr", "ros1"):
                return parse_pointcloud2(data, encoding, where)
            return backend.deserialize(raw)

        records = self._core._records(topic, start_ns, end_ns, parse)
        if guard is not None:
            # Checked before the decode: a scan whose stamp jumped is never decoded.
            records = guard.by_offset(records, lambda r: r.stamp_ns, lambda r: r.log_time_ns)
        for rec in records:
            layout, buf = pointcloud2_layout(rec.msg, where, max_bytes, candidates)
            pts = decode_points(layout, buf, drop_zero, time_fields)
            yield rec.stamp_ns, rec.log_time_ns, str(rec.msg.header.frame_id), pts

    def point_message_parser(self, raw: RawMessage, encoding: str, where: str) -> PointMessageParser:
        if self._point_parser is None:
            msgtype = self._core._backend.topics[raw.topic].msgtype
            generic = self._core._backend.deserialize(raw)  # registers the definition, or says why not
            store = self._core._backend.typestore(raw)
            parser = PointMessageParser(store.fielddefs, msgtype, encoding, where)
            # The parse must agree with rosbags' generic deserialiser on the first message.
            _check_point_parser(parser, generic, self._core._backend.serialized(raw)[1], where)
            self._point_parser = parser
        return self._point_parser

    # ----- per-point time ------------------------------------------------------------------

    def decide_timing(self) -> Timing:
        """How each lidar point's time is found (`LogSource.lidar_timing`), decided once."""
        if self.timing_done:
            return self.timing
        topic = self._core._require(Role.LIDAR, "lidar")
        cfg = self._core.config.lidar_time
        where = f"{self._core.path} topic {topic}"
        samples = self._samples(topic)
        period = self._scan_period(topic, samples)
        present = list(dict.fromkeys(name for s in samples for name in s[3].times))
        timing: Timing = None
        constant: list[str] = []
        report: dict[str, Any] = {"topic": topic, "scan_period_ms": round(period / 1e6, 3),
                                  "time_fields": present}
        if cfg.field != "none" and samples:
            timing = self._time_field(topic, cfg, samples, period, present, constant, where)
        if isinstance(timing, TimeSpec):
            report["deskew"] = "per-point time"
            report["time"] = timing.to_json()
            if timing.shift_ns:
                self._core._warn(f"{topic}: per-point time {timing.describe()}")
        else:
            why = ""
            if constant:
                why = f" (field{'s' if len(constant) > 1 else ''} {', '.join(constant)} the same for every point)"
            timing, report = self._without_time(topic, cfg, samples, period, why, report)
        self.timing, self.timing_done, self.report = timing, True, report
        return timing

    def _samples(self, topic: str) -> list[tuple[int, int, str, DecodedPoints]]:
        """The first scans with points enough to decide how their time reads."""
        samples: list[tuple[int, int, str, DecodedPoints]] = []
        # Through a guard of their own: a scan whose stamp jumped must not decide, nor be
        # counted twice in the warnings.
        sampling = StampGuard(int(self._core.config.max_gap_s * 1e9))
        for item in self._points(topic, None, None, None, sampling):
            if len(item[3].xyz) >= 10:
                samples.append(item)
            if len(samples) >= TIME_SAMPLE_SCANS:
                break
        return samples

    def _scan_period(self, topic: str, samples: list[tuple[int, int, str, DecodedPoints]]) -> int:
        info = next(t for t in self._core.topics if t.name == topic)  # what the time check kept
        fallback = (int((info.last_ns - info.first_ns) / (info.count - 1))
                    if info.count > 1 and info.first_ns is not None and info.last_ns is not None
                    and info.last_ns > info.first_ns else 100_000_000)
        return scan_period_ns([s[0] for s in samples], fallback)

    def _time_field(self, topic: str, cfg: LidarTimeConfig,
                    samples: list[tuple[int, int, str, DecodedPoints]], period: int,
                    present: list[str], constant: list[str], where: str) -> TimeSpec | None:
        """The first time field whose reading can be decided; the fields found the same for
        every point are added to `constant`."""
        if cfg.field != "auto" and cfg.field not in present:
            fields = ", ".join(n for n, *_ in self.fields(topic)) or "none"
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
            return spec
        if first_error is not None:
            raise first_error
        return None

    def _without_time(self, topic: str, cfg: LidarTimeConfig,
                      samples: list[tuple[int, int, str, DecodedPoints]], period: int, why: str,
                      report: dict[str, Any]) -> tuple[Timing, dict[str, Any]]:
        if cfg.without_time == "none":
            self._core._warn(f"{topic}: no per-point time{why}: mapped without deskew "
                       "(ingest.lidar_time.without_time: none)")
            report["deskew"] = "none"
            return None, report
        spec, reason = decide_azimuth([(st, lt, p.xyz) for st, lt, _, p in samples], period, cfg)
        if spec is None:
            self._core._warn(f"{topic}: no per-point time{why}, and {reason}: mapped without deskew; "
                       "walls seen while the robot moves are smeared by its motion over a scan")
            report["deskew"] = "none"
            report["reason"] = reason
            return None, report
        self._core._warn(f"{topic}: no per-point time{why}: deskewed by each point's azimuth, "
                   f"{spec.describe()}; the header stamp taken as the sweep's "
                   f"{'end' if spec.shift_ns else 'start'}")
        report["deskew"] = "azimuth"
        report["time"] = spec.to_json()
        return spec, report

    def fields(self, topic: str) -> list[tuple[str, int, str, int]]:
        """(name, offset, type, count) of the lidar's point fields, from its first message."""
        msgtype = self._core._backend.topics[topic].msgtype
        for raw in self._core._iter_raw([topic], None, None):
            encoding, data = self._core._backend.serialized(raw)
            if msgtype in POINT_MESSAGE_TYPES:
                parser = self.point_message_parser(raw, encoding, f"{self._core.path} topic {topic}")
                dtype = parser.parse(data).points.dtype
                return [(str(n), int(dtype.fields[n][1]), dtype.fields[n][0].name, 1)
                        for n in dtype.names or ()]
            msg = (parse_pointcloud2(data, encoding) if encoding in ("cdr", "ros1")
                   else self._core._backend.deserialize(raw))
            layout, _ = pointcloud2_layout(msg, f"{self._core.path} topic {topic}")
            return list(layout.fields)
        return []


def from_sweep_start(cloud: Cloud, start_ns: int) -> Cloud:
    """The scan stamped at its sweep's start, `start_ns` from its header stamp."""
    offsets = None if cloud.t_offset_ns is None else cloud.t_offset_ns - np.int64(start_ns)
    return replace(cloud, stamp_ns=cloud.stamp_ns + start_ns, t_offset_ns=offsets)


def point_frame(msg: PointMessage) -> str:
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

