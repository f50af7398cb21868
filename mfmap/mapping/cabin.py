"""Dropping returns from inside an elevator cabin while the robot enters or leaves it, in the
lidar odometry (`CabinFilter`) and in the maps (`CabinBox`).

The LeGO-LOAM elevator paper (section III-C): cabins are small, often reflective boxes; their walls dominate a scan
taken at the door and give registration a structure that is not part of the floor (and mirror
ghosts). The cabin is where the robot stood during the ride: a box around the base pose there.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from mfmap.mapping.config import MappingConfig
from mfmap.mapping.geometry import inverse, transform
from mfmap.types import F64, I64, Transition, TransitionKind


class _Relative(Protocol):
    def relative(self, from_ns: int, to_ns: int) -> F64 | None: ...


def through_box(points_base: F64, origin_base: F64, box_in_base: F64,
                half_xy_m: tuple[float, float]) -> np.ndarray:
    """Mask of points whose ray from the sensor enters the box (in x, y): the cabin's own
    returns and whatever appears behind its walls (mirror ghosts, too-long ranges).

    Liang-Barsky clipping of each segment origin -> point against the box.
    """
    to_box = inverse(box_in_base)
    start = transform(origin_base[None, :], to_box)[0, :2]
    end = transform(points_base, to_box)[:, :2]
    d = end - start
    t_in = np.zeros(len(end))
    t_out = np.ones(len(end))
    for axis in (0, 1):
        half = half_xy_m[axis]
        with np.errstate(divide="ignore", invalid="ignore"):
            t0 = (-half - start[axis]) / d[:, axis]
            t1 = (half - start[axis]) / d[:, axis]
        parallel = d[:, axis] == 0
        lo, hi = np.minimum(t0, t1), np.maximum(t0, t1)
        outside = parallel & (abs(start[axis]) >= half)
        lo = np.where(parallel, -np.inf, lo)
        hi = np.where(parallel, np.inf, hi)
        t_in = np.maximum(t_in, lo)
        t_out = np.minimum(t_out, hi)
        t_out = np.where(outside, -1.0, t_out)
    return t_in < t_out


class CabinFilter:
    """Finds the cabin in each scan's base frame near a ride and drops the points inside it."""

    def __init__(self, cfg: MappingConfig, transitions: list[Transition], motion: _Relative) -> None:
        self.rides = [tr for tr in transitions if tr.kind == TransitionKind.ELEVATOR]
        self.window_ns = int(cfg.cabin.window_s * 1e9)
        self.half_xy_m = (cfg.cabin.size_m[0] / 2.0, cfg.cabin.size_m[1] / 2.0)
        self.motion = motion
        self._visit_start_pose: F64 | None = None
        self.dropped = 0

    def visit_started(self, pose: F64) -> None:
        """The robot is in the cabin at the start of a visit after a ride: remember where."""
        self._visit_start_pose = pose.copy()

    def cabin_in_base(self, stamp_ns: int, predicted: F64) -> F64 | None:
        for tr in self.rides:
            if tr.start_ns - self.window_ns <= stamp_ns <= tr.end_ns:  # entering (or riding)
                return self.motion.relative(stamp_ns, tr.start_ns)
            if tr.end_ns < stamp_ns <= tr.end_ns + self.window_ns:  # leaving
                rel = self.motion.relative(stamp_ns, tr.end_ns)
                if rel is None and self._visit_start_pose is not None:
                    rel = inverse(predicted) @ self._visit_start_pose
                return rel
        return None

    def robot_inside(self, stamp_ns: int, predicted: F64) -> bool:
        """Whether the base is inside the cabin (entering or leaving): lidar is not trusted there."""
        box = self.cabin_in_base(stamp_ns, predicted)
        if box is None:
            return False
        base_in_box = inverse(box)[:3, 3]
        return bool(abs(base_in_box[0]) < self.half_xy_m[0]
                    and abs(base_in_box[1]) < self.half_xy_m[1])

    def apply(self, points_base: F64, stamp_ns: int, predicted: F64, origin_base: F64) -> F64:
        """Drop the cabin's returns and those behind its walls (rays through the cabin)."""
        box = self.cabin_in_base(stamp_ns, predicted)
        if box is None:
            return points_base
        inside = through_box(points_base, origin_base, box, self.half_xy_m)
        self.dropped += int(inside.sum())
        return points_base[~inside]


# ----- the cabin in the maps ------------------------------------------------------------------
# The maps (mfmap.export.scans) and the depth cameras drop the cabin again, from every scan at its
# optimised pose, with a second computation kept apart from `through_box` on purpose. Its cabin
# is fixed at the base pose the trajectory gives at the ride's start or end (CabinFilter moves it
# with the odometry, scan by scan); its rays start at the base origin (through_box: the lidar's
# origin); it turns points into the box with the yaw block of the pose alone (through_box: the
# whole 3D transform); and it tests only the points at least as far as the box. A lidar mounted
# off the base origin or a tilted pose gives the two different masks, so using one in place of
# the other would change the maps.


@dataclass(frozen=True)
class CabinBox:
    """An elevator cabin fixed in the world, with the window in which its walls are seen."""

    start_ns: int
    end_ns: int
    pose: F64  # base pose in the cabin (world)
    half_xy_m: tuple[float, float]


def cabin_boxes(transitions: Sequence[Transition], stamps_ns: I64, poses: F64,
                cfg: MappingConfig) -> list[CabinBox]:
    """Where the robot stood in each elevator, with the window in which its walls are seen."""
    if not cfg.cabin.filter or stamps_ns.shape[0] == 0:
        return []
    window = int(cfg.cabin.window_s * 1e9)
    half = (cfg.cabin.size_m[0] / 2, cfg.cabin.size_m[1] / 2)
    out = []
    for tr in transitions:
        if tr.kind != TransitionKind.ELEVATOR:
            continue
        for stamp in (tr.start_ns, tr.end_ns):
            i = int(np.clip(np.searchsorted(stamps_ns, stamp), 0, len(stamps_ns) - 1))
            lo = tr.start_ns - window if stamp == tr.start_ns else tr.end_ns
            hi = tr.start_ns if stamp == tr.start_ns else tr.end_ns + window
            out.append(CabinBox(lo, hi, poses[i], half))
    return out


def distinct_cabins(cabins: list[CabinBox], radius_m: float = 0.5) -> list[CabinBox]:
    """One cabin per elevator shaft (rides from the same spot share it), for the mirror filter."""
    out: list[CabinBox] = []
    for cabin in cabins:
        if all(np.hypot(*(cabin.pose[:2, 3] - c.pose[:2, 3])) > radius_m for c in out):
            out.append(cabin)
    return out


def in_cabin(pose: F64, stamp_ns: int, cabins: list[CabinBox], margin_m: float = 0.3) -> bool:
    """Is the base at `pose` inside one of the cabins (with a margin) while its walls are seen?"""
    for cabin in cabins:
        if cabin.start_ns <= stamp_ns <= cabin.end_ns:
            local = (pose[:3, 3] - cabin.pose[:3, 3]) @ cabin.pose[:3, :3]
            if abs(local[0]) < cabin.half_xy_m[0] + margin_m and abs(local[1]) < cabin.half_xy_m[1] + margin_m:
                return True
    return False


def drop_cabins(points_base: np.ndarray, pose: F64, stamp_ns: int, cabins: list[CabinBox]) -> np.ndarray:
    """Drop returns from each elevator cabin and from anything seen through it (see
    `outside_cabins`)."""
    if not cabins or points_base.shape[0] == 0:
        return points_base
    return points_base[outside_cabins(points_base, pose, stamp_ns, cabins)]


def outside_cabins(points_base: np.ndarray, pose: F64, stamp_ns: int, cabins: list[CabinBox]) -> np.ndarray:
    """Mask of the points that are not returns from an elevator cabin or seen through it.

    Cabin walls are often mirrors (the LeGO-LOAM elevator paper): what a ray shows after crossing the cabin is a
    reflection, not the building. In the base frame of the scan, per cabin: points inside the
    cabin box, and points whose ray from the sensor leaves the box before reaching them.
    """
    del stamp_ns  # the cabin stays where it is; its walls matter at any time
    keep = np.ones(points_base.shape[0], dtype=bool)
    range2 = np.einsum("ij,ij->i", points_base[:, :2], points_base[:, :2])
    for cabin in cabins:
        box_in_base = np.linalg.inv(pose) @ cabin.pose
        rot, origin = box_in_base[:3, :3], box_in_base[:3, 3]
        sensor = (-origin[:2]) @ rot[:2, :2]  # the base origin in the box frame
        half = np.array(cabin.half_xy_m)
        # Only points at least as far as the box (from the base origin) can be in it or behind it.
        gap = float(np.linalg.norm(np.maximum(np.abs(sensor) - half, 0.0)))
        near = np.flatnonzero(range2 >= (gap - 1e-6) ** 2) if gap > 0 else np.arange(len(range2))
        if near.shape[0] == 0:
            continue
        local = (points_base[near, :2] - origin[:2]) @ rot[:2, :2]
        d = local - sensor
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (-half - sensor) / d
            t2 = (half - sensor) / d
        # fmin/fmax skip the NaN of a ray parallel to a slab (faster than nanmin/nanmax).
        t_near = np.fmax(np.fmin(t1[:, 0], t2[:, 0]), np.fmin(t1[:, 1], t2[:, 1]))
        t_far = np.fmin(np.fmax(t1[:, 0], t2[:, 0]), np.fmax(t1[:, 1], t2[:, 1]))
        crosses = (t_near <= t_far) & (t_far > 0.0) & (t_near < 1.0)
        inside = np.all(np.abs(local) < half, axis=1)
        keep[near[inside | (crosses & (t_far < 1.0))]] = False
    return keep
