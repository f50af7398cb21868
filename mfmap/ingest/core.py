"""LogCore: an opened log's topics, roles, time check and decoded records.

The stream readers (lidar, 2D laser, the small series, the transforms) build on it. Every read
asks the backend for one topic and a time window only, so reading the barometer never
decompresses the lidar chunks of an indexed MCAP.
"""

from __future__ import annotations

import heapq
import logging
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from mfmap.errors import LogError, MissingDataError
from mfmap.ingest.backend import Backend, RawMessage
from mfmap.ingest.config import IngestConfig
from mfmap.ingest.decode import stamp_ns_of
from mfmap.ingest.roles import ROLE_TYPE, assign_roles
from mfmap.ingest.timecheck import LogClock, StampGuard
from mfmap.types import ROLE_BY_TYPE, Cloud, Role, Scan2D, TopicInfo

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Record:
    """One decoded message: header stamp (log time if the header is zero), log time, topic."""

    stamp_ns: int
    log_time_ns: int
    topic: str
    msg: Any
    size_bytes: int = 0


_Stamped = TypeVar("_Stamped", Record, Cloud, Scan2D)

# Streams whose clock the time check follows (tf_static's messages hold whenever they came).
_TIMED_ROLES = (Role.LIDAR, Role.SCAN2D, Role.BARO, Role.IMU, Role.ODOM)


class LogCore:
    """An opened log's topics and roles, and its records read through the time check."""

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

    def _window(self, start_ns: int | None, end_ns: int | None) -> tuple[int | None, int | None]:
        margin = int(self.config.window_margin_s * 1e9)
        return (None if start_ns is None else start_ns - margin,
                None if end_ns is None else end_ns + margin)

    @staticmethod
    def _in_window(stamp: int, start_ns: int | None, end_ns: int | None) -> bool:
        return not ((start_ns is not None and stamp < start_ns) or (end_ns is not None and stamp > end_ns))

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

    def _first_record(self, topic: str) -> Record | None:
        return next(iter(self.messages(topic)), None)

