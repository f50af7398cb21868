"""Which way a 2D scanner's beams run in time, checked against the robot's turns.

A LaserScan states beam i's time as i * time_increment, but not every driver's array runs the
way its sweep does: rplidar_ros reverses a clockwise scanner's ranges into counter-clockwise
order and keeps time_increment positive, so the stated times run against the real sweep. A
deskew with them twists each turning scan by the turn made over a sweep, the first beams one
way and the last the other, instead of untwisting it.

Two scans taken half a turn apart while the robot turns tell the two orders apart: a wall seen
early in one sweep is seen late in the other, so with the wrong order their twists do not
cancel and the aligned scans disagree by up to twice the turn over a sweep (at 0.6 rad/s and
10 Hz, 7 degrees: 60 cm at 5 m); with the right one they overlap to the scanner's noise. The
turn between them (the alignment's start) and during each sweep (the deskew) come from the IMU
gyro, else from the wheel odometry's turn rate.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from mfmap.ingest.decode import decode_laserscan
from mfmap.types import F64

MIN_TURN_RAD_S = 0.25  # scans taken turning at least this fast carry the evidence
MAX_PAIRS = 16
CLEAR_RATIO = 0.85  # one order's residual must be below this share of the other's
MAX_DISTANCE_M = 0.5


@dataclass
class SweepCheck:
    decision: str  # "as_stated" | "reversed" | "unknown"
    reason: str
    pairs: int = 0
    residual_stated_m: float = 0.0
    residual_reversed_m: float = 0.0
    votes: dict[str, int] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {"decision": self.decision, "reason": self.reason, "pairs": self.pairs,
                "median_residual_as_stated_m": round(self.residual_stated_m, 4),
                "median_residual_reversed_m": round(self.residual_reversed_m, 4),
                "votes": dict(self.votes)}


class YawTrack:
    """The base's yaw over time, integrated from the gyro (base frame)."""

    def __init__(self, stamp_ns: np.ndarray[Any, Any], rate_z: F64) -> None:
        order = np.argsort(stamp_ns, kind="stable")
        self.t = (stamp_ns[order] - stamp_ns[order][0]).astype(np.float64) / 1e9
        self.t0 = int(stamp_ns[order][0])
        rate = rate_z[order]
        steps = np.diff(self.t) * 0.5 * (rate[1:] + rate[:-1])
        self.yaw = np.concatenate([[0.0], np.cumsum(steps)])
        self.rate = rate

    def at(self, stamp_ns: F64) -> F64:
        return np.interp((np.asarray(stamp_ns, dtype=np.float64) - self.t0) / 1e9, self.t, self.yaw)

    def rate_at(self, stamp_ns: int, span_ns: int) -> float:
        """Mean yaw rate over [stamp, stamp + span]."""
        a, b = self.at(np.array([stamp_ns, stamp_ns + span_ns], dtype=np.float64))
        return float(b - a) / (span_ns / 1e9) if span_ns > 0 else 0.0


class PlanarOdometry:
    """Wheel odometry's x, y and heading over time."""

    def __init__(self, stamp_ns: np.ndarray[Any, Any], xyz: F64, quat_xyzw: F64) -> None:
        order = np.argsort(stamp_ns, kind="stable")
        self.t = stamp_ns[order].astype(np.float64)
        self.xy = xyz[order, :2]
        x, y, z, w = (quat_xyzw[order, k] for k in range(4))
        self.heading = np.unwrap(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))

    def shift(self, from_ns: int, to_ns: int) -> F64:
        """The travel from `from_ns` to `to_ns`, in the base frame at `from_ns`."""
        a = np.array([np.interp(from_ns, self.t, self.xy[:, k]) for k in range(2)])
        b = np.array([np.interp(to_ns, self.t, self.xy[:, k]) for k in range(2)])
        heading = float(np.interp(from_ns, self.t, self.heading))
        return _rot(-heading) @ (b - a)


def _rot(yaw: float | F64) -> F64:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s], [s, c]])


def _points_base(msg: Any, stamp_ns: int, reversed_time: bool, laser_to_base: F64
                 ) -> tuple[F64, np.ndarray[Any, Any]] | None:
    scan = decode_laserscan(msg, stamp_ns, reversed_time)
    if scan.t_offset_ns is None or len(scan.xy) < 50:
        return None
    xyz = np.column_stack([scan.xy.astype(np.float64), np.zeros(len(scan.xy))])
    base = xyz @ laser_to_base[:3, :3].T + laser_to_base[:3, 3]
    return base[:, :2], scan.t_offset_ns


def _deskew(xy: F64, t_ns: np.ndarray[Any, Any], stamp_ns: int, yaw_of: Callable[[F64], F64],
            velocity: F64) -> F64:
    """Points measured at stamp + t, in the base frame at the stamp (the base's turn over the
    sweep from `yaw_of`, its velocity constant)."""
    times = stamp_ns + t_ns.astype(np.float64)
    theta = yaw_of(times) - yaw_of(np.array([float(stamp_ns)]))[0]
    c, s = np.cos(theta), np.sin(theta)
    out = np.empty_like(xy)
    out[:, 0] = c * xy[:, 0] - s * xy[:, 1]
    out[:, 1] = s * xy[:, 0] + c * xy[:, 1]
    return out + (t_ns.astype(np.float64) / 1e9)[:, None] * velocity[None, :]


def _normals(xy: F64, tree: cKDTree, k: int = 7) -> tuple[F64, np.ndarray[Any, Any]]:
    """Unit normal of the line through each point's neighbours, and whether they make a line."""
    _, idx = tree.query(xy, k=min(k, len(xy)))
    nbrs = xy[idx]
    centred = nbrs - nbrs.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", centred, centred)
    evals, evecs = np.linalg.eigh(cov)
    return evecs[:, :, 0], evals[:, 0] < 0.1 * np.maximum(evals[:, 1], 1e-12)


def _align(src: F64, dst: F64, yaw: float, shift: F64, iterations: int = 30) -> tuple[float, float, F64]:
    """Point-to-line ICP in the plane from (yaw, shift): the median distance of the source
    points to the target's lines, and the yaw and shift found. Point-to-line, because a scan's
    points are centimetres apart along a wall: their distances to the nearest point measure
    the spacing, their distances to the wall the misfit."""
    tree = cKDTree(dst)
    normals, straight = _normals(dst, tree)
    x, y, th = float(shift[0]), float(shift[1]), float(yaw)
    residual = math.inf
    for _ in range(iterations):
        c, s = math.cos(th), math.sin(th)
        moved = src @ np.array([[c, s], [-s, c]]) + (x, y)
        d, j = tree.query(moved, distance_upper_bound=MAX_DISTANCE_M)
        ok = np.isfinite(d)
        ok[ok] &= straight[j[ok]]
        if ok.sum() < 20:
            return math.inf, th, np.array([x, y])
        n = normals[j[ok]]
        r = ((moved[ok] - dst[j[ok]]) * n).sum(axis=1)
        residual = float(np.median(np.abs(r)))
        p = src[ok]
        drot = np.stack([-s * p[:, 0] - c * p[:, 1], c * p[:, 0] - s * p[:, 1]], axis=1)
        jac = np.stack([n[:, 0], n[:, 1], (drot * n).sum(axis=1)], axis=1)
        kernel = max(3.0 * residual, 0.02)
        w = np.where(np.abs(r) < kernel, (1 - (r / kernel) ** 2) ** 2, 0.0)
        h = (jac * w[:, None]).T @ jac + 1e-9 * np.eye(3)
        step = -np.linalg.solve(h, (jac * w[:, None]).T @ r)
        x, y, th = x + float(step[0]), y + float(step[1]), th + float(step[2])
        if abs(step[2]) < 1e-6 and np.abs(step[:2]).max() < 1e-5:
            break
    return residual, th, np.array([x, y])


@dataclass(frozen=True)
class ScanPair:
    """Two scans half a turn apart, and the base's motion from the first to the second as
    the gyro and wheels measure it (the alignment's start)."""

    msg_a: Any
    stamp_a: int
    msg_b: Any
    stamp_b: int
    turn_rad: float
    shift: F64  # (2,) the base's travel, in the first scan's base frame


def check_sweep(
    pairs: list[ScanPair],
    laser_to_base: F64,
    yaw: YawTrack,
    velocity_of: Callable[[int], F64] | None,
) -> SweepCheck:
    """Decide the beam order from scan pairs taken half a turn apart while turning; `yaw` the
    base's heading over time (gyro or wheels), `velocity_of` its planar velocity in its own
    frame at a stamp (None: 0)."""
    votes = {"as_stated": 0, "reversed": 0, "unclear": 0}
    residuals: dict[bool, list[float]] = {False: [], True: []}
    used = 0
    for pair in pairs:
        scores: dict[bool, float] = {}
        for reversed_time in (False, True):
            a = _points_base(pair.msg_a, pair.stamp_a, reversed_time, laser_to_base)
            b = _points_base(pair.msg_b, pair.stamp_b, reversed_time, laser_to_base)
            if a is None or b is None:
                break
            va = velocity_of(pair.stamp_a) if velocity_of is not None else np.zeros(2)
            vb = velocity_of(pair.stamp_b) if velocity_of is not None else np.zeros(2)
            pa = _deskew(a[0], a[1], pair.stamp_a, yaw.at, va)
            pb = _deskew(b[0], b[1], pair.stamp_b, yaw.at, vb)
            residual, _, _ = _align(pb, pa, pair.turn_rad, pair.shift)
            scores[reversed_time] = residual
        if len(scores) < 2 or not all(math.isfinite(v) for v in scores.values()):
            continue
        used += 1
        residuals[False].append(scores[False])
        residuals[True].append(scores[True])
        if scores[True] < CLEAR_RATIO * scores[False]:
            votes["reversed"] += 1
        elif scores[False] < CLEAR_RATIO * scores[True]:
            votes["as_stated"] += 1
        else:
            votes["unclear"] += 1
    stated = float(np.median(residuals[False])) if used else 0.0
    rev = float(np.median(residuals[True])) if used else 0.0
    if used < 3:
        return SweepCheck("unknown", f"only {used} usable pairs of turning scans", used, stated, rev, votes)
    decided = max(("as_stated", "reversed"), key=lambda k: votes[k])
    other = "reversed" if decided == "as_stated" else "as_stated"
    if votes[decided] < 0.6 * used or votes[other] > 0.2 * used:
        return SweepCheck("unknown", f"the turning scans disagree ({votes})", used, stated, rev, votes)
    return SweepCheck(decided, f"{votes[decided]} of {used} pairs of turning scans", used, stated,
                      rev, votes)


def half_turns(yaw: YawTrack, stamps_ns: np.ndarray[Any, Any], rate_of: Callable[[int], float],
               max_pairs: int = MAX_PAIRS, max_gap_s: float = 12.0) -> list[tuple[int, int]]:
    """Times (a, b) at which the base turns at least MIN_TURN_RAD_S and between which it has
    turned a third to two thirds of a turn (nearest half a turn), spread over the log, none
    overlapping."""
    t = np.asarray(stamps_ns, dtype=np.int64)
    heading = yaw.at(t.astype(np.float64))
    turning = np.array([abs(rate_of(int(x))) >= MIN_TURN_RAD_S for x in t])
    out: list[tuple[int, int]] = []
    candidates = np.flatnonzero(turning)
    if len(candidates) == 0:
        return out
    busy_until = -1
    for i in candidates[np.unique(np.linspace(0, len(candidates) - 1, 20 * max_pairs).astype(int))]:
        if t[i] <= busy_until:
            continue
        hi = int(np.searchsorted(t, t[i] + int(max_gap_s * 1e9), side="right"))
        turned = np.abs(heading[i:hi] - heading[i])
        # Half a turn apart shifts each wall by half a sweep, where the two orders' twists
        # differ most; a third of a turn still tells them apart.
        near = np.flatnonzero((np.abs(turned - math.pi) < 2 * math.pi / 3) & turning[i:hi])
        if len(near) == 0:
            continue
        j = i + int(near[np.argmin(np.abs(turned[near] - math.pi))])
        out.append((int(t[i]), int(t[j])))
        busy_until = int(t[j])
        if len(out) >= max_pairs:
            break
    return out
