"""Time sanity of a log's streams: the consistent part of each stream's stamps.

A clock that is reset (NTP, a dead RTC battery, a driver stamping with the wrong clock) makes
a stream's stamps step backwards or jump ahead. Everything downstream sizes arrays and loops by
time (the barometer's uniform grid, the gyro's bias windows), so one stamp a year ahead once cost
12 GB. Each stream, in recording order, is cut into runs at every step back or jump ahead. Runs
that fill each other's holes are one stream (a recorder may write a buffer late); where runs
cover the same time (a clock set back) the earlier-starting one keeps it and the other loses
that part; and of what is left, the stretch without a gap longer than `max_gap_s` that holds
the most messages is kept. What is left out is dropped, with a warning that says how many
messages and where. Memory and time stay bounded by the number of messages.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
import numpy.typing as npt

from mfmap.ingest.backend import RawMessage
from mfmap.types import I64

Mask = npt.NDArray[np.bool_]

# Steps back this small are a recorder's jitter, left to the readers' sorting.
BACK_TOLERANCE_NS = 1_000_000_000
# A step ahead of more than this many median steps (and a second) starts a run of its own, so
# that one stamp off in the future cannot claim the time after it.
JUMP_STEPS = 20


@dataclass(frozen=True)
class StreamCheck:
    """What the check kept of one stream (stamps in recording order)."""

    keep: Mask
    backward: int  # steps back (beyond the jitter) between consecutive messages
    gaps: int  # forward steps longer than the limit
    first_bad_ns: int | None  # stamp of the first dropped message

    @property
    def dropped(self) -> int:
        return int(self.keep.size - np.count_nonzero(self.keep))

    def describe(self, what: str, start_ns: int, max_gap_s: float) -> str:
        """One warning line: how many of `what` were dropped, why and from where."""
        reasons = []
        if self.backward:
            reasons.append(f"{self.backward} step(s) back in time")
        if self.gaps:
            reasons.append(f"{self.gaps} jump(s) ahead of more than {max_gap_s:g} s")
        at = ""
        if self.first_bad_ns is not None:
            at = f", the first {(self.first_bad_ns - start_ns) / 1e9:+.1f} s from the log's start"
        kept = int(np.count_nonzero(self.keep))
        return (f"{what}: its clock is not consistent ({', '.join(reasons) or 'stamps out of range'})"
                f"; dropped {self.dropped} of {self.keep.size} messages{at}, kept {kept}")


def consistent(stamps_ns: Sequence[int] | I64, max_gap_ns: int) -> StreamCheck:
    """The messages to keep of a stream whose stamps are given in recording order."""
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    n = stamps.shape[0]
    if n < 2:
        return StreamCheck(np.ones(n, dtype=bool), 0, 0, None)
    step = np.diff(stamps)
    back = step < -BACK_TOLERANCE_NS
    ahead = step > max(BACK_TOLERANCE_NS, JUMP_STEPS * int(np.median(np.abs(step))))
    backward, gaps = int(back.sum()), int((step > max_gap_ns).sum())
    if not back.any() and not gaps:
        return StreamCheck(np.ones(n, dtype=bool), 0, 0, None)
    starts = np.concatenate(([0], np.flatnonzero(back | ahead) + 1)).astype(np.int64)
    ends = np.concatenate((starts[1:], [n]))
    lows = np.minimum.reduceat(stamps, starts)
    highs = np.maximum.reduceat(stamps, starts)
    keep = np.ones(n, dtype=bool)
    covered: int | None = None
    # Time goes to the run that starts first; a later-starting run keeps what lies after it.
    for r in np.argsort(lows, kind="stable").tolist():
        if covered is not None and lows[r] <= covered:
            a, b = int(starts[r]), int(ends[r])
            keep[a:b] = stamps[a:b] > covered
        covered = int(highs[r]) if covered is None else max(covered, int(highs[r]))
    # Of what is left, the stretch without a gap longer than the limit holding the most.
    idx = np.flatnonzero(keep)
    idx = idx[np.argsort(stamps[idx], kind="stable")]
    breaks = np.flatnonzero(np.diff(stamps[idx]) > max_gap_ns) + 1
    bounds = np.concatenate(([0], breaks, [idx.shape[0]]))
    best = int(np.argmax(np.diff(bounds)))  # the first of equals: the earliest stretch
    keep = np.zeros(n, dtype=bool)
    keep[idx[bounds[best]:bounds[best + 1]]] = True
    bad = np.flatnonzero(~keep)
    return StreamCheck(keep, backward, gaps, int(stamps[bad[0]]) if bad.size else None)


def log_span(spans: dict[str, tuple[int, int, int]], max_gap_ns: int) -> tuple[int, int] | None:
    """The log's span from its streams' kept (first, last, count): the group of streams whose
    spans overlap (within max_gap) that holds the most messages. Streams outside it are ones
    whose clock disagrees with the others'."""
    if not spans:
        return None
    items = sorted(spans.values())
    groups: list[list[int]] = []
    for lo, hi, count in items:
        if groups and lo - groups[-1][1] <= max_gap_ns:
            groups[-1][1] = max(groups[-1][1], hi)
            groups[-1][2] += count
        else:
            groups.append([lo, hi, count])
    lo, hi, _ = max(groups, key=lambda g: (g[2], -g[0]))
    return lo, hi


# ----- a log's clock: which messages of which streams are kept ---------------------------------


class LogClock:
    """The consistent part of every checked stream of a log, by log time (the recorder's
    clock), from the backend's indexes: no message is read.

    `checked` are the streams whose stamps matter (the sensors); each is cut to its consistent
    part, and then to the span that most of the log's messages agree on, so that one stream with
    a clock of its own (a year ahead) cannot stretch the log.
    """

    def __init__(self, log_times: Callable[[str], I64 | None], checked: Iterable[str],
                 max_gap_s: float, where: str) -> None:
        self.max_gap_ns = int(max_gap_s * 1e9)
        self.warnings: list[str] = []
        self.kept: dict[str, tuple[int, int, int]] = {}  # topic -> (first, last, count) kept
        self._dropped: dict[str, _Dropped] = {}
        times: dict[str, I64] = {}
        checks: dict[str, StreamCheck] = {}
        for topic in sorted(set(checked)):
            stamps = log_times(topic)
            if stamps is None or stamps.shape[0] == 0:
                continue
            times[topic] = stamps
            checks[topic] = consistent(stamps, self.max_gap_ns)
        spans = {t: _span(times[t], c.keep) for t, c in checks.items() if c.keep.any()}
        span = log_span(spans, self.max_gap_ns)
        if span is not None:
            lo, hi = span[0] - self.max_gap_ns, span[1] + self.max_gap_ns
            for topic, stamps in times.items():
                first, last, _ = spans.get(topic, (lo, hi, 0))
                if first >= lo and last <= hi:
                    continue
                inside = (stamps >= lo) & (stamps <= hi)
                sub = consistent(stamps[inside], self.max_gap_ns)
                keep = np.zeros(stamps.shape[0], dtype=bool)
                keep[inside] = sub.keep
                bad = np.flatnonzero(~keep)
                checks[topic] = StreamCheck(keep, checks[topic].backward, checks[topic].gaps,
                                            int(stamps[bad[0]]) if bad.size else None)
        start = min((int(s.min()) for s in times.values()), default=0)
        if span is not None:
            start = span[0]
        for topic, check in checks.items():
            stamps = times[topic]
            if check.keep.any():
                self.kept[topic] = _span(stamps, check.keep)
            else:
                self.kept[topic] = (0, 0, 0)
            if check.dropped:
                self._dropped[topic] = _Dropped.of(stamps, check.keep)
                self.warnings.append(check.describe(f"{where} topic {topic}", start,
                                                    self.max_gap_ns / 1e9))
        self.span = span

    @property
    def dropping(self) -> bool:
        return bool(self._dropped)

    def filter(self, messages: Iterator[RawMessage]) -> Iterator[RawMessage]:
        """The messages the check kept (all of them when it dropped none)."""
        if not self._dropped:
            yield from messages
            return
        dropped = self._dropped
        seen: dict[tuple[str, int], int] = {}
        for message in messages:
            bad = dropped.get(message.topic)
            if bad is not None:
                t = message.log_time_ns
                if t in bad.every:
                    continue
                ranks = bad.some.get(t)
                if ranks is not None:
                    key = (message.topic, t)
                    rank = seen.get(key, 0)
                    seen[key] = rank + 1
                    if rank in ranks:
                        continue
            yield message


@dataclass(frozen=True)
class _Dropped:
    """The dropped messages of one stream by log time: `every` message at those times, or at
    the times of `some`, the ones of those ranks among the messages sharing the time (in
    recording order, as the readers hand out messages of one time). A clock set back by a
    whole number of periods repeats the very same stamps, kept and dropped side by side."""

    every: frozenset[int]
    some: dict[int, frozenset[int]]

    @classmethod
    def of(cls, stamps: I64, keep: Mask) -> _Dropped:
        order = np.argsort(stamps, kind="stable")
        ordered = stamps[order]
        first = np.concatenate(([True], ordered[1:] != ordered[:-1]))
        group = np.cumsum(first) - 1
        starts = np.flatnonzero(first)
        rank = np.empty(stamps.shape[0], dtype=np.int64)
        rank[order] = np.arange(stamps.shape[0]) - starts[group]
        kept_at = np.zeros(starts.shape[0], dtype=np.int64)
        np.add.at(kept_at, group, keep[order].astype(np.int64))
        kept_here = np.empty(stamps.shape[0], dtype=np.int64)
        kept_here[order] = kept_at[group]
        bad = np.flatnonzero(~keep)
        every = frozenset(stamps[bad[kept_here[bad] == 0]].tolist())
        some: dict[int, set[int]] = {}
        for i in bad[kept_here[bad] > 0].tolist():
            some.setdefault(int(stamps[i]), set()).add(int(rank[i]))
        return cls(every, {t: frozenset(r) for t, r in some.items()})


def _span(stamps: I64, keep: Mask) -> tuple[int, int, int]:
    kept = stamps[keep]
    return int(kept.min()), int(kept.max()), int(kept.shape[0])


# ----- header stamps of decoded streams --------------------------------------------------------


def series_order(stamps_ns: I64, max_gap_ns: int) -> tuple[npt.NDArray[np.intp], StreamCheck, int]:
    """The indices that make a decoded series (stamps in reading order) consistent and strictly
    increasing: the consistent part by `consistent`, sorted, a repeated stamp kept once.
    Returns the indices, the check and how many repeats were left out."""
    check = consistent(stamps_ns, max_gap_ns)
    idx = np.flatnonzero(check.keep)
    idx = idx[np.argsort(stamps_ns[idx], kind="stable")]
    if idx.shape[0] < 2:
        return idx, check, 0
    fresh = np.concatenate(([True], np.diff(stamps_ns[idx]) > 0))
    return idx[fresh], check, int(idx.shape[0] - np.count_nonzero(fresh))


_STAMPED = TypeVar("_STAMPED")


class StampGuard:
    """Header stamps of a streamed topic (lidar scans): a scan whose stamp leaves its log time
    by more than the gap limit beyond the stream's usual offset (a sensor clock that jumped),
    or that goes back past the scans already handed out, is left out and counted."""

    def __init__(self, max_gap_ns: int) -> None:
        self.max_gap_ns = max_gap_ns
        self.offset_ns: int | None = None  # the stream's usual header - log time
        self.jumped = 0
        self.backward = 0

    def by_offset(self, items: Iterable[_STAMPED], stamp: Callable[[_STAMPED], int],
                  log_time: Callable[[_STAMPED], int]) -> Iterator[_STAMPED]:
        buffer: list[_STAMPED] = []
        for item in items:
            if self.offset_ns is None:
                buffer.append(item)
                if len(buffer) < 16:
                    continue
                self.offset_ns = int(np.median([stamp(b) - log_time(b) for b in buffer]))
                yield from self._offset_ok(buffer, stamp, log_time)
                buffer = []
                continue
            if self._fits(stamp(item) - log_time(item)):
                yield item
            else:
                self.jumped += 1
        if buffer:
            self.offset_ns = int(np.median([stamp(b) - log_time(b) for b in buffer]))
            yield from self._offset_ok(buffer, stamp, log_time)

    def _fits(self, offset_ns: int) -> bool:
        return self.offset_ns is None or abs(offset_ns - self.offset_ns) <= self.max_gap_ns

    def _offset_ok(self, items: list[_STAMPED], stamp: Callable[[_STAMPED], int],
                   log_time: Callable[[_STAMPED], int]) -> Iterator[_STAMPED]:
        for item in items:
            if self._fits(stamp(item) - log_time(item)):
                yield item
            else:
                self.jumped += 1

    def forwards(self, items: Iterable[_STAMPED], stamp: Callable[[_STAMPED], int]) -> Iterator[_STAMPED]:
        last: int | None = None
        for item in items:
            t = stamp(item)
            if last is not None and t <= last:
                self.backward += 1
                continue
            last = t
            yield item

    def describe(self, where: str) -> str | None:
        if not self.jumped and not self.backward:
            return None
        parts = []
        if self.jumped:
            parts.append(f"{self.jumped} whose header stamp jumped more than "
                         f"{self.max_gap_ns / 1e9:g} s from their log time")
        if self.backward:
            parts.append(f"{self.backward} stamped at or before the message before them")
        return f"{where}: dropped {' and '.join(parts)}"


__all__ = ["LogClock", "StampGuard", "StreamCheck", "consistent", "log_span", "series_order"]
