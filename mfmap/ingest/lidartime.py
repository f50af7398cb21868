"""Per-point lidar time, decided from the values rather than from the field's name.

Drivers disagree on almost everything about a point's time: Ouster sends uint32 nanoseconds
from the header stamp, Velodyne float32 seconds relative to a stamp at the sweep's end, Hesai and
Robosense float64 epoch seconds, Livox float64 epoch *nanoseconds* (or, in its own CustomMsg, a
uint32 offset from a uint64 time base). A field called `timestamp` can hold any of these. What
does not vary is the physics: one scan lasts about one scan period and happens around its header
stamp. So each reading (relative or absolute; s, ms, us or ns) is tried against the header
stamps and the period of the first scans, and the one under which every scan spans about a
period next to its stamp is taken. Units are a factor of 1000 apart, far more than a scan's
span can vary, so at most one reading fits.

A lidar without per-point time that spins (the points of each scan sweep round in azimuth in
their storage order) gets each point's time from its azimuth; the sweep's direction and start
angle come from the data too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from mfmap.errors import DecodeError
from mfmap.ingest.config import LidarTimeConfig
from mfmap.types import I64

UNIT_NS: dict[str, int] = {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "ns": 1}
# Field names drivers use for a point's time (Ouster `t`, Velodyne `time`, Hesai/Robosense/Livox
# `timestamp`, Livox CustomMsg `offset_time`, ...). Only where to look: the values decide.
TIME_FIELDS = ("t", "time", "timestamp", "time_stamp", "offset_time", "ts", "time_offset")

# A scan of a spinning lidar spans one period (a cropped sweep less); 0.05 to 1.5 periods keeps
# the readings a factor 1000 apart from overlapping.
_MIN_SPAN, _MAX_SPAN = 0.05, 1.5
_FIT_SHARE = 0.8  # share of the sampled scans a reading must fit


@dataclass(frozen=True)
class TimeSample:
    """One sampled scan: its header stamp, its log time, and the raw time values of its points."""

    stamp_ns: int
    log_time_ns: int
    values: np.ndarray[Any, Any]


@dataclass(frozen=True)
class TimeSpec:
    """How one time field reads: offset of a point from its scan's header stamp, in ns, is
    value * unit (- the stamp, when absolute) + shift_ns."""

    field: str
    dtype: str  # numpy name of the field's type, e.g. "uint32", "float64"
    unit: str  # s | ms | us | ns
    reference: str  # relative | absolute
    shift_ns: int  # -sweep for relative values counted from the sweep start with a stamp at its end
    stamp: str  # where the header stamp sits in the sweep: start | end | middle
    decided: str  # "data" or "config", and what decided the stamp's place
    span_ms: float  # median span of the sampled scans
    # Where the sweep starts from the header stamp (0 when the stamp is the start): a scan is
    # timed from its sweep's start, so a driver that stamps the end maps as one that stamps
    # the start.
    sweep_start_ns: int = 0

    kind = "time"

    def offsets_ns(self, values: np.ndarray[Any, Any], stamp_ns: int) -> I64:
        """Exact int64 ns offsets from the stamp (no rounding beyond what the field's type holds)."""
        factor = UNIT_NS[self.unit]
        absolute = self.reference == "absolute"
        if values.dtype.kind in "iu":
            out = values.astype(np.int64)
            if factor != 1:
                out = out * np.int64(factor)
            if absolute:
                out = out - np.int64(stamp_ns)
        else:
            v = values.astype(np.float64)
            finite = np.isfinite(v)
            if not bool(finite.all()):
                # A point with no time of its own is placed at its scan's middle time.
                v = np.where(finite, v, np.median(v[finite]) if finite.any() else 0.0)
            if absolute:
                # Whole units and the fraction apart: both exact in float64, so the offset is
                # the value's own, to the nanosecond (an epoch in float64 seconds resolves
                # 0.24 us, which must not be rounded a second time).
                whole = np.floor(v)
                frac_ns = np.round((v - whole) * factor).astype(np.int64)
                out = whole.astype(np.int64) * np.int64(factor) - np.int64(stamp_ns) + frac_ns
            else:
                out = np.round(v * factor).astype(np.int64)
        if self.shift_ns:
            out = out + np.int64(self.shift_ns)
        return out

    def describe(self) -> str:
        base = f"'{self.field}' {self.dtype} {self.reference} {self.unit}"
        if self.shift_ns:
            base += f" from the sweep start ({-self.shift_ns / 1e6:.1f} ms before the stamp)"
        base += f", header stamp at the sweep's {self.stamp}"
        if self.sweep_start_ns:
            base += f" (scans timed from their start, {self.sweep_start_ns / 1e6:+.1f} ms)"
        return f"{base} (by {self.decided})"

    def to_json(self) -> dict[str, Any]:
        return {"source": "field", "field": self.field, "dtype": self.dtype, "unit": self.unit,
                "reference": self.reference, "shift_ns": self.shift_ns, "stamp": self.stamp,
                "sweep_start_ns": self.sweep_start_ns, "decided": self.decided,
                "span_ms": round(self.span_ms, 3)}


@dataclass(frozen=True)
class AzimuthSpec:
    """Point times of a spinning lidar from their azimuth in the sensor frame."""

    direction: int  # +1 counter-clockwise seen from above, -1 clockwise
    start_rad: float | None  # the sweep's fixed start angle; None: each scan's first point
    margin_rad: float  # a point this far before the start is late in the sweep's first column
    period_ns: int
    shift_ns: int
    decided: str

    kind = "azimuth"

    @property
    def sweep_start_ns(self) -> int:
        return self.shift_ns

    def offsets_ns(self, xyz: np.ndarray[Any, Any]) -> I64:
        if len(xyz) == 0:
            return np.zeros(0, np.int64)
        az = np.arctan2(xyz[:, 1].astype(np.float64), xyz[:, 0].astype(np.float64))
        start = float(az[0]) if self.start_rad is None else self.start_rad
        turned = np.mod(self.direction * (az - start) + self.margin_rad, 2 * math.pi) - self.margin_rad
        out = np.round(np.clip(turned, 0.0, None) / (2 * math.pi) * self.period_ns).astype(np.int64)
        if self.shift_ns:
            out += np.int64(self.shift_ns)
        return out

    def describe(self) -> str:
        spin = "counter-clockwise" if self.direction > 0 else "clockwise"
        start = ("from each scan's first point" if self.start_rad is None
                 else f"from {math.degrees(self.start_rad):.1f} deg")
        return f"{spin} {start}, {self.period_ns / 1e6:.1f} ms per turn (by {self.decided})"

    def to_json(self) -> dict[str, Any]:
        return {"source": "azimuth", "spin": "ccw" if self.direction > 0 else "cw",
                "start_deg": None if self.start_rad is None else round(math.degrees(self.start_rad), 3),
                "period_ms": round(self.period_ns / 1e6, 3), "shift_ns": self.shift_ns,
                "decided": self.decided}


def scan_period_ns(stamps_ns: list[int], fallback_ns: int) -> int:
    """Median spacing of the sampled scans' header stamps (dropped scans do not move it)."""
    diffs = np.diff(np.sort(np.array(stamps_ns, dtype=np.int64)))
    diffs = diffs[diffs > 0]
    return int(np.median(diffs)) if len(diffs) else fallback_ns


def _spans_s(samples: list[TimeSample], unit: str, reference: str) -> np.ndarray[Any, Any]:
    """(scans, 2): first and last point time of each scan relative to its stamp, in seconds,
    under one reading (float64: a decision needs microseconds, not nanoseconds)."""
    out = np.full((len(samples), 2), np.nan)
    scale = UNIT_NS[unit] / 1e9
    for k, s in enumerate(samples):
        v = s.values.astype(np.float64)
        v = v[np.isfinite(v)]
        if len(v) == 0:
            continue
        lo, hi = float(v.min()) * scale, float(v.max()) * scale
        if reference == "absolute":
            stamp_s = s.stamp_ns / 1e9
            lo, hi = lo - stamp_s, hi - stamp_s
        out[k] = (lo, hi)
    return out


def _fits(spans: np.ndarray[Any, Any], period_s: float) -> bool:
    lo, hi = spans[:, 0], spans[:, 1]
    ok = np.isfinite(lo) & np.isfinite(hi)
    span = hi - lo
    good = ok & (span >= _MIN_SPAN * period_s) & (span <= _MAX_SPAN * period_s)
    good &= (lo >= -_MAX_SPAN * period_s) & (hi <= _MAX_SPAN * period_s)
    return bool(ok.sum() > 0 and good.sum() >= _FIT_SHARE * ok.sum())


def stamp_at_end_evidence(samples: list[TimeSample], sweep_ns: float) -> bool:
    """Did the recorder log the scans before their sweep, counted from the stamp, was over?

    A driver can publish a scan only after its last point: a stamp at the sweep's start is
    logged at least a sweep later. Scans logged within half a sweep of their stamp are stamped
    at the end. No evidence when the log times equal the stamps (re-stamped logs, simulators)
    or run on another clock (negative or far-off latencies).
    """
    latency = np.array([s.log_time_ns - s.stamp_ns for s in samples], dtype=np.int64)
    if len(latency) == 0 or not np.any(latency != 0):
        return False
    median = float(np.median(latency))
    return 0.0 <= median < 0.5 * sweep_ns and int(latency.min()) >= 0


def decide_time(
    field: str,
    dtype: str,
    samples: list[TimeSample],
    period_ns: int,
    cfg: LidarTimeConfig,
    where: str,
) -> TimeSpec | None:
    """The reading of one time field, or None when its values are the same in every scan (a
    field the driver leaves at zero carries no time). Raises DecodeError when no reading fits,
    naming the field and `ingest.lidar_time`."""
    usable = [s for s in samples if s.values.size > 0]
    if not usable:
        return None
    raw = _spans_s(usable, "s", "relative")
    if not np.any(raw[:, 1] - raw[:, 0] > 0):  # NaN (no finite value) compares False too
        return None
    period_s = period_ns / 1e9
    units = list(UNIT_NS) if cfg.unit == "auto" else [cfg.unit]
    references = ["relative", "absolute"] if cfg.reference == "auto" else [cfg.reference]
    by_config = cfg.unit != "auto" and cfg.reference != "auto"
    fits = []
    for reference in references:
        for unit in units:
            spans = _spans_s(usable, unit, reference)
            if by_config or _fits(spans, period_s):
                fits.append((reference, unit, spans))
    if len(fits) != 1:
        first = usable[0].values.astype(np.float64)
        seen = f"{np.nanmin(first):.10g} .. {np.nanmax(first):.10g}"
        problem = ("fit no reading" if not fits else
                   "fit " + " and ".join(f"{r} {u}" for r, u, _ in fits) + " alike")
        raise DecodeError(
            f"per-point time field '{field}' ({dtype}): its values ({seen} in the first scan, "
            f"header stamp {usable[0].stamp_ns / 1e9:.6f} s, scans {period_s * 1e3:.1f} ms apart) "
            f"{problem} (relative or absolute; s, ms, us or ns); set ingest.lidar_time "
            "(field, unit, reference), or ingest.lidar_time.field: none to map without it",
            where,
        )
    reference, unit, spans = fits[0]
    lo = float(np.nanmedian(spans[:, 0])) * 1e9
    hi = float(np.nanmedian(spans[:, 1])) * 1e9
    span = hi - lo
    shift_ns, decided = 0, "config" if by_config else "data"
    starts_at_stamp = abs(lo) <= 0.05 * max(span, 1.0)
    if reference == "relative" and starts_at_stamp:
        end = (cfg.stamp == "end" or (cfg.stamp == "auto"
                                      and stamp_at_end_evidence(usable, span)))
        if end:
            shift_ns = -round(hi)
            decided += ", config" if cfg.stamp == "end" else ", the recorder's clock"
    lo, hi = lo + shift_ns, hi + shift_ns
    tolerance = 0.05 * max(span, 1.0)
    stamp = "start" if abs(lo) <= tolerance else "end" if abs(hi) <= tolerance else "middle"
    start = 0 if stamp == "start" else round(lo)
    return TimeSpec(field, dtype, unit, reference, shift_ns, stamp, decided, span / 1e6, start)


@dataclass(frozen=True)
class SweepEvidence:
    """What the storage order of one scan's points says about a spinning sweep."""

    direction: int  # sign of the azimuth's progression, 0 when none
    consistency: float  # |net progression| / total progression, 1 for a clean sweep
    turns: float  # net progression in turns
    first_rad: float  # azimuth of the first point
    step_rad: float  # typical azimuth step between consecutive points that move


def sweep_evidence(xyz: np.ndarray[Any, Any]) -> SweepEvidence | None:
    if len(xyz) < 100:
        return None
    az = np.arctan2(xyz[:, 1].astype(np.float64), xyz[:, 0].astype(np.float64))
    d = np.mod(np.diff(az) + math.pi, 2 * math.pi) - math.pi
    total, absolute = float(d.sum()), float(np.abs(d).sum())
    moving = np.abs(d)[np.abs(d) > 1e-6]
    step = float(np.median(moving)) if len(moving) else 0.0
    if absolute <= 0:
        return SweepEvidence(0, 0.0, 0.0, float(az[0]), step)
    return SweepEvidence(int(np.sign(total)), abs(total) / absolute, abs(total) / (2 * math.pi),
                         float(az[0]), step)


def decide_azimuth(
    clouds: list[tuple[int, int, np.ndarray[Any, Any]]], period_ns: int, cfg: LidarTimeConfig
) -> tuple[AzimuthSpec | None, str]:
    """A spinning lidar's point times from azimuth, from sampled scans (stamp, log time, xyz in
    storage order). Returns the spec, or None and why the scans do not sweep."""
    evidence = [(s, lt, e) for s, lt, xyz in clouds if (e := sweep_evidence(xyz)) is not None]
    if not evidence:
        return None, "too few points to see a sweep"
    spinning = [e for _, _, e in evidence if e.consistency > 0.8 and e.turns >= 0.9]
    forced = cfg.without_time == "azimuth"
    if len(spinning) < _FIT_SHARE * len(evidence) and not forced:
        share = len(spinning) / len(evidence)
        return None, (f"the points of only {share:.0%} of the sampled scans sweep round in "
                      "azimuth in their storage order (a non-repetitive or solid-state pattern)")
    if cfg.spin != "auto":
        direction = 1 if cfg.spin == "ccw" else -1
    else:
        votes = sum(e.direction for e in spinning)
        if votes == 0:
            return None, "the sampled scans sweep both ways; set ingest.lidar_time.spin"
        direction = 1 if votes > 0 else -1
    firsts = np.array([e.first_rad for e in (spinning or [e for _, _, e in evidence])])
    step = float(np.median([e.step_rad for e in (spinning or [e for _, _, e in evidence])]))
    # A fixed start angle (an encoder-triggered sweep) shows as first points within a few
    # columns of each other; a missing first column only makes a scan start later, so the
    # earliest one in the sweep's direction is the start.
    centre = math.atan2(float(np.sin(firsts).mean()), float(np.cos(firsts).mean()))
    rel = np.mod(firsts - centre + math.pi, 2 * math.pi) - math.pi
    start: float | None = None
    if float(np.abs(rel).max()) <= max(8 * step, math.radians(2.0)):
        earliest = float(rel.min()) if direction > 0 else float(rel.max())
        start = math.atan2(math.sin(centre + earliest), math.cos(centre + earliest))
    samples = [TimeSample(s, lt, np.zeros(1)) for s, lt, _ in evidence]
    shift = -period_ns if stamp_at_end_evidence(samples, period_ns) else 0
    decided = "config" if cfg.spin != "auto" else "data"
    if shift:
        decided += ", the recorder's clock"
    return AzimuthSpec(direction, start, 0.5 * step, period_ns, shift, decided), ""
