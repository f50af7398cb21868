"""Dropping returns from inside an elevator cabin while the robot enters or leaves it.

The LeGO-LOAM elevator paper (section III-C): cabins are small, often reflective boxes; their walls dominate a scan
taken at the door and give registration a structure that is not part of the floor (and mirror
ghosts). The cabin is where the robot stood during the ride: a box around the base pose there.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from mfmap.mapping.config import MappingConfig
from mfmap.mapping.geometry import inverse, transform
from mfmap.types import F64, Transition, TransitionKind


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
        self.window_ns = int(cfg.cabin_window_s * 1e9)
        self.half_xy_m = (cfg.cabin_size_m[0] / 2.0, cfg.cabin_size_m[1] / 2.0)
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
