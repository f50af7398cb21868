"""The wheel odometry's distance scale, calibrated against the lidar odometry.

Wheel odometry's distance is off by the error in the wheel radius (tyre pressure, load, wear):
a few percent is common. Most of the time it only seeds the registration, but in and out of an
elevator cabin, where the lidar is not used, it alone carries the robot: on three-floor-revisit
seed 1 (a 6 % scale error) every floor visit's first metre out of the cabin came out 8 cm long,
and its scans in the cabin were that far off the rest of the visit.

Between two keyframes of a visit, both placed by registration, the lidar measures the distance
travelled to about a centimetre; the least-squares scale of the wheels' displacements onto the
lidar's, over metres of travel, is good to a fraction of a percent.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mfmap.mapping.geometry import inverse
from mfmap.types import F64

# A keyframe pair shorter than this (a turn on the spot) says little about the distance scale.
MIN_PAIR_M = 0.2
# Outside this the wheels and the lidar disagree about more than a radius: not calibrated.
SCALE_RANGE = (0.8, 1.25)


@dataclass
class WheelScale:
    """Least-squares scale s with lidar ~ s * wheels, over keyframe-to-keyframe displacements
    in the plane (in the earlier keyframe's base frame)."""

    min_travel_m: float
    dot: float = 0.0  # sum of lidar . wheels
    norm: float = 0.0  # sum of |wheels|^2
    travel_m: float = 0.0  # sum of |wheels|

    def add(self, lidar_rel: F64, wheel_rel: F64) -> None:
        """One pair: the relative poses between two keyframes from registration and wheels."""
        wheels = wheel_rel[:2, 3]
        length = float(np.linalg.norm(wheels))
        if length < MIN_PAIR_M:
            return
        self.dot += float(lidar_rel[:2, 3] @ wheels)
        self.norm += length**2
        self.travel_m += length

    @property
    def value(self) -> float | None:
        """The scale, once enough travel was seen and within SCALE_RANGE; else None."""
        if self.min_travel_m <= 0 or self.travel_m < self.min_travel_m or self.norm <= 0:
            return None
        scale = self.dot / self.norm
        return scale if SCALE_RANGE[0] <= scale <= SCALE_RANGE[1] else None


def rescale(start: F64, pose: F64, scale: float) -> F64:
    """`pose`, reached from `start` by motion whose translations are all multiplied by `scale`.

    In the start's frame a chain of motions T_1 ... T_k has its translation sum_j R_(j-1) t_j,
    linear in the t_j, and its rotation free of them: scaling every step scales the chain's
    translation and keeps its rotation.
    """
    rel = inverse(start) @ pose
    rel[:3, 3] *= scale
    return start @ rel


@dataclass(frozen=True)
class Run:
    """A run of visits after an elevator ride: the held pose the odometry restarted from, and
    the indices of its first keyframe and first scan pose."""

    start: F64
    first_keyframe: int
    first_scan_pose: int


class RunScale:
    """The wheels' scale over the run of visits since the last elevator ride (see
    `Mapper.finish_run`), and the sums over the runs before it for the report."""

    def __init__(self, min_travel_m: float) -> None:
        self.min_travel_m = min_travel_m
        self.current = WheelScale(min_travel_m)
        self.totals = (0.0, 0.0)  # lidar . wheels and |wheels|^2 over finished runs
        self.run: Run | None = None

    def finish(self) -> tuple[float | None, Run | None]:
        """End the run: its scale (None if not calibrated) and where it started."""
        scale, run = self.current.value, self.run
        dot, norm = self.totals
        self.totals = (dot + self.current.dot, norm + self.current.norm)
        self.current = WheelScale(self.min_travel_m)
        self.run = None
        return scale, run

    @property
    def dot(self) -> float:
        return self.totals[0] + self.current.dot

    @property
    def norm(self) -> float:
        return self.totals[1] + self.current.norm
