"""Floors in a log without a barometer: from the IMU's elevator rides and the lidar odometry's
stair climbs (docs/heights.md, "A log without a barometer")."""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence

import numpy as np

from mfmap.floors.climbs import stair_walks
from mfmap.floors.config import FloorsConfig
from mfmap.floors.imu import ImuTiming
from mfmap.floors.rides import segment_transitions
from mfmap.types import Floor, FloorSegmentation, ImuSeries, Keyframe, TransitionKind

logger = logging.getLogger(__name__)


def floors_from_rides(rides: Sequence[tuple[int, int, float]], start_ns: int, end_ns: int,
                      cfg: FloorsConfig) -> FloorSegmentation:
    """The floors of the elevator rides the IMU felt, (start_ns, end_ns, height change m) in
    time order, or one floor without any; with a warning either way (the lidar's stair walks
    come after the mapping, `floors_with_walks`)."""
    if rides:
        logger.warning(
            "no barometer in the log: floors from the IMU's %d elevator ride(s); a floor "
            "revisited is recognised by the transitions' heights only",
            len(rides), extra={"stage": ""})
        changes = [(a, b, dz, TransitionKind.ELEVATOR) for a, b, dz in rides]
        return segment_transitions(changes, start_ns, end_ns, cfg)
    logger.warning("no barometer in the log and no elevator ride felt: one floor, unless the "
                   "lidar odometry climbs stairs",
                   extra={"stage": ""})
    return single_floor(start_ns, end_ns)


def floors_with_walks(seg: FloorSegmentation, keyframes: Sequence[Keyframe], imu: ImuSeries | None,
                      cfg: FloorsConfig, start_ns: int, end_ns: int) -> FloorSegmentation:
    """Without a barometer: the floors of `seg` (the IMU's rides) and the stair walks the lidar
    odometry climbed within its visits (`mfmap.floors.climbs`), clustered again; `seg` itself
    when there is no walk. The IMU's flights, where it has them, time each walk."""
    timing = ImuTiming.of(imu)
    walks = []
    for kfs in by_visit(keyframes):
        stamps = np.array([k.stamp_ns for k in kfs], dtype=np.int64)
        xyz = np.array([k.pose[:3, 3] for k in kfs], dtype=np.float64)
        for a, b, dz in stair_walks(stamps, xyz, cfg.min_floor_height_m,
                                    cfg.transitions.landing_max_path_m):
            span = timing.flight_span(a, b) if timing is not None else None
            # The flights within the keyframes either side: a span beyond them is not this walk's.
            a, b = (max(a, span[0]), min(b, span[1])) if span is not None else (a, b)
            walks.append((a, b, dz, TransitionKind.STAIRS))
    if not walks:
        return seg
    rides = [(tr.start_ns, tr.end_ns, tr.height_change_m, tr.kind) for tr in seg.transitions]
    changes = sorted(rides + walks, key=lambda c: c[0])
    logger.warning("no barometer in the log: %d stair walk(s) from the lidar odometry's climbs "
                   "make the floors; a floor revisited is recognised by the transitions' heights "
                   "only", len(walks), extra={"stage": ""})
    return segment_transitions(changes, start_ns, end_ns, cfg)


def by_visit(keyframes: Sequence[Keyframe]) -> list[list[Keyframe]]:
    """The keyframes of each visit in time order, the visits in their order."""
    visits: dict[int, list[Keyframe]] = {}
    for k in sorted(keyframes, key=lambda k: k.stamp_ns):
        visits.setdefault(k.visit, []).append(k)
    return [visits[v] for v in sorted(visits)]


def climb_left(keyframes: Sequence[Keyframe], min_floor_height_m: float) -> str | None:
    """What the lidar odometry says about a change of floor left within one visit of a log
    without barometer: stairs show up as a climb (z is free there), and a visit is one floor
    only when no climb is left in it. A phrase describing the first visit's largest climb or
    descent of at least `min_floor_height_m` (times from the first keyframe), else None."""
    if not keyframes:
        return None
    origin = min(k.stamp_ns for k in keyframes)
    for kfs in by_visit(keyframes):
        z = np.array([k.pose[2, 3] for k in kfs], dtype=np.float64)
        lo, hi = int(np.argmin(z)), int(np.argmax(z))
        if z[hi] - z[lo] < min_floor_height_m:
            continue
        first, last = sorted((lo, hi))
        verb = "climbs" if z[last] > z[first] else "descends"
        t0_s = (kfs[first].stamp_ns - origin) / 1e9
        t1_s = (kfs[last].stamp_ns - origin) / 1e9
        return f"{verb} {abs(z[last] - z[first]):.1f} m between {t0_s:.0f} s and {t1_s:.0f} s"
    return None


def single_floor(start_ns: int, end_ns: int) -> FloorSegmentation:
    """One floor spanning the whole log (no barometer)."""
    stamps = np.array([start_ns, end_ns], dtype=np.int64)
    zeros = np.zeros(2)
    return FloorSegmentation(
        floors=(Floor(0, 0.0, math.nan, ((start_ns, end_ns),)),),
        transitions=(),
        stamp_ns=stamps,
        height_raw_m=zeros,
        height_filtered_m=zeros,
        floor_of_sample=np.zeros(2, dtype=np.int32),
    )
