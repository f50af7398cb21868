"""Global search: where on a floor a query cloud fits, without an initial pose.

A correlative search in x, y and yaw (as in Olson, "Real-Time Correlative Scan Matching"): the
floor's walls and furniture in a height band above its floor are a 2D likelihood field; the
query's points in the same band, turned by each yaw of a coarse step, are scored at every
translation at once as a cross-correlation by FFT. The best distinct places are refined by
point-to-plane ICP against the floor's 3D cloud and scored by their fitness there.

Why not features: open3d's FPFH + RANSAC (as the build's inter-floor registration runs it)
placed the first second of a log on the right place in 2 of 6 runs on the tiny building, at 1.4
to 8 s per floor; corridors, slabs and ceilings give features that match everywhere. The
correlative search looks at every place of every floor, so a place that fits nearly as well as
the best one is seen (and the result called ambiguous) instead of missed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy import fft

from mfmap.mapping.geometry import yaw_rad
from mfmap.mapping.registration import IcpTarget, icp
from mfmap.types import F32, F64

# ICP passes from a coarse place: correspondence distance and Tukey kernel (m). The first pass
# reaches across the coarse cell and the coarse yaw step at the query's range.
REFINE_PASSES = ((1.0, 0.5, 10), (0.3, 0.1, 10), (0.15, 0.05, 10))


@dataclass
class SearchField:
    """A floor's walls as a likelihood field: exp(-d^2 / 2 sigma^2) of the distance d to the
    nearest wall cell, sigma one cell; row r, column c cover y, x from origin + (r, c) * res."""

    values: F32  # (H, W)
    origin_xy: F64
    resolution_m: float
    _spectra: dict[tuple[int, int], np.ndarray] = field(default_factory=dict, repr=False)

    @classmethod
    def from_points(cls, xy: F64, resolution_m: float, margin_m: float = 2.0) -> SearchField:
        if len(xy) == 0:
            return cls(np.zeros((1, 1), np.float32), np.zeros(2), resolution_m)
        lo = xy.min(axis=0) - margin_m
        hi = xy.max(axis=0) + margin_m
        shape = np.ceil((hi - lo) / resolution_m).astype(int) + 1
        cells = np.floor((xy - lo) / resolution_m).astype(int)
        free = np.full((shape[1], shape[0]), 255, np.uint8)
        free[cells[:, 1], cells[:, 0]] = 0
        dist = cv2.distanceTransform(free, cv2.DIST_L2, 5)  # in cells
        values = np.exp(-0.5 * dist.astype(np.float32) ** 2).astype(np.float32)
        return cls(values, lo, resolution_m)

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.values.shape[0]), int(self.values.shape[1])

    def spectrum(self, size: tuple[int, int]) -> np.ndarray:
        """The field's 2D real FFT, zero-padded to `size` (kept per size)."""
        if size not in self._spectra:
            self._spectra[size] = fft.rfft2(self.values, s=size)
        return self._spectra[size]


@dataclass(frozen=True)
class Candidate:
    """A place on a floor where the query fits: the base pose in the map frame."""

    floor: int
    pose: F64  # (4, 4)
    fitness: float  # share of the query's points within fit_distance_m of the floor's cloud
    field_score: float  # mean likelihood of the query's band points at the coarse place

    @property
    def yaw_deg(self) -> float:
        return math.degrees(yaw_rad(self.pose))

    def distinct(self, other: Candidate, dist_m: float, yaw_deg: float) -> bool:
        """Another place: another floor, or farther than dist_m or turned more than yaw_deg."""
        if other.floor != self.floor:
            return True
        dyaw = abs((self.yaw_deg - other.yaw_deg + 180.0) % 360.0 - 180.0)
        return bool(np.hypot(*(self.pose[:2, 3] - other.pose[:2, 3])) > dist_m or dyaw > yaw_deg)


def coarse_places(field_: SearchField, query_xy: F64, yaw_step_deg: float, range_m: float,
                  count: int, distinct_m: float, distinct_deg: float
                  ) -> list[tuple[float, float, float, float]]:
    """The `count` best distinct (x, y, yaw_rad, mean likelihood) of the query's 2D points
    (robot frame, gravity-aligned) on the field, best first."""
    res = field_.resolution_m
    near = query_xy[np.hypot(query_xy[:, 0], query_xy[:, 1]) <= range_m]
    if len(near) < 10:
        return []
    # One point per cell: a wall seen at close range has many more returns than one far away,
    # but no more to say about where the robot is.
    keys = np.unique(np.floor(near / (0.5 * res)).astype(np.int64), axis=0)
    pts = (keys.astype(np.float64) + 0.5) * (0.5 * res)
    n = len(pts)
    height, width = field_.shape
    reach = math.ceil(range_m / res) + 1
    size = (fft.next_fast_len(height + reach, real=True), fft.next_fast_len(width + reach, real=True))
    spectrum = field_.spectrum(size)
    yaws = np.radians(np.arange(0.0, 360.0, yaw_step_deg))
    volume = np.empty((len(yaws), height, width), np.float32)
    for k, yaw in enumerate(yaws):
        c, s = math.cos(yaw), math.sin(yaw)
        rotated = pts @ np.array([[c, s], [-s, c]])
        offsets = np.rint(rotated / res).astype(np.int64)
        # The query as an image of offsets from the robot's cell, wrapped around: the FFT's
        # circular correlation then scores every robot cell at once (the padding is zeros).
        image = np.zeros(size, np.float64)
        np.add.at(image, (offsets[:, 1] % size[0], offsets[:, 0] % size[1]), 1.0)
        corr = fft.irfft2(spectrum * np.conj(fft.rfft2(image)), s=size)
        volume[k] = corr[:height, :width] / n
    places: list[tuple[float, float, float, float]] = []
    cells_m = max(1, round(distinct_m / res))
    steps_deg = max(1, round(distinct_deg / yaw_step_deg))
    for _ in range(count):
        best, r, col = (int(v) for v in np.unravel_index(int(np.argmax(volume)), volume.shape))
        score = float(volume[best, r, col])
        if score <= 0.0:
            break
        x = field_.origin_xy[0] + (col + 0.5) * res
        y = field_.origin_xy[1] + (r + 0.5) * res
        places.append((x, y, float(yaws[best]), score))
        rows = slice(max(0, r - cells_m), r + cells_m + 1)
        cols = slice(max(0, col - cells_m), col + cells_m + 1)
        for dk in range(-steps_deg, steps_deg + 1):
            volume[(best + dk) % len(yaws), rows, cols] = 0.0
    return places


def refine(points: F64, target: IcpTarget, start: F64, fit_distance_m: float,
           icp_points: int = 1500) -> tuple[F64, float]:
    """Point-to-plane ICP of the query (robot frame) from `start`, on at most `icp_points` of
    its points (evenly spread); the pose and the fitness of all of them."""
    pose = start
    sample = points
    if len(points) > icp_points:
        sample = points[np.linspace(0, len(points) - 1, icp_points).astype(np.int64)]
    for max_distance, kernel, iterations in REFINE_PASSES:
        pose = icp(sample, target, pose, max_distance, kernel, iterations).transform
    return pose, fitness(points, target, pose, fit_distance_m)


def fitness(points: F64, target: IcpTarget, pose: F64, fit_distance_m: float) -> float:
    """Share of the points (robot frame) within fit_distance_m of the target at `pose`."""
    if len(points) == 0:
        return 0.0
    moved = points @ pose[:3, :3].T + pose[:3, 3]
    found, _, _ = target.nearest(moved, fit_distance_m)
    return len(found) / len(points)


__all__ = ["Candidate", "SearchField", "coarse_places", "fitness", "refine"]


def pose_xyz_yaw(x: float, y: float, z: float, yaw: float, level: F64 | None = None) -> F64:
    """The base pose at x, y, z turned by yaw; `level` (3x3) is the base's tilt to gravity."""
    pose = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    pose[:3, :3] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    if level is not None:
        pose[:3, :3] = pose[:3, :3] @ level
    pose[:3, 3] = (x, y, z)
    return pose
