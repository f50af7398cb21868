"""2D lidar (LaserScan) odometry: point-to-line ICP in the plane against a local 2D map.

Same interface as `odometry.ScanMatcher`; poses stay 4x4 with z, roll, pitch taken from the
prediction (z comes from the floor elevation, the robot is assumed level).
"""

from __future__ import annotations

import math
from collections import deque
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

from mfmap.mapping.geometry import inverse, transform, wrap_angle, yaw_pose, yaw_rad
from mfmap.mapping.odometry import AdaptiveThreshold, ScanMatch
from mfmap.types import F64

if TYPE_CHECKING:
    from mfmap.mapping.config import MappingConfig


def grid_downsample_2d(xy: F64, voxel_m: float) -> F64:
    """Centroid of the points in each square cell."""
    if len(xy) == 0:
        return xy.reshape(0, 2)
    cells = np.floor(xy / voxel_m).astype(np.int64)
    _, inverse_idx, counts = np.unique(cells, axis=0, return_inverse=True, return_counts=True)
    sums = np.zeros((len(counts), 2))
    np.add.at(sums, inverse_idx.ravel(), xy)
    return sums / counts[:, None]


def line_normals(xy: F64, tree: cKDTree, k: int = 6) -> tuple[F64, F64]:
    """Unit normal and planarity (1 - minor/major eigenvalue) per point from its k neighbours."""
    k = min(k, len(xy))
    _, idx = tree.query(xy, k=k)
    nbrs = xy[idx]  # (N, k, 2)
    centred = nbrs - nbrs.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", centred, centred) / k
    evals, evecs = np.linalg.eigh(cov)
    normals = evecs[:, :, 0]
    quality = 1.0 - evals[:, 0] / np.maximum(evals[:, 1], 1e-12)
    return normals, quality


class Map2D:
    """The last keyframes' points in the world plane, merged on a grid."""

    def __init__(self, voxel_m: float, max_keyframes: int) -> None:
        self.voxel_m = voxel_m
        self._frames: deque[F64] = deque(maxlen=max_keyframes)
        self.points: F64 = np.zeros((0, 2))
        self.normals: F64 = np.zeros((0, 2))
        self.tree: cKDTree | None = None
        self.size = 0

    def clear(self) -> None:
        self._frames.clear()
        self.tree = None
        self.size = 0

    def add(self, world_xy: F64) -> None:
        self._frames.append(grid_downsample_2d(world_xy, self.voxel_m))
        merged = grid_downsample_2d(np.concatenate(list(self._frames)), self.voxel_m)
        tree = cKDTree(merged)
        normals, quality = line_normals(merged, tree)
        keep = quality > 0.5  # points on a line; corners and clutter have no normal
        self.points, self.normals = merged[keep], normals[keep]
        self.tree = cKDTree(self.points) if len(self.points) >= 3 else None
        self.size = len(self.points)


def icp_2d(source: F64, target: Map2D, x: float, y: float, yaw: float, max_distance_m: float,
           iterations: int, kernel_m: float = 0.0,
           fix_yaw: bool = False) -> tuple[float, float, float, float, float]:
    """Gauss-Newton point-to-line ICP with Tukey weights; (x, y, yaw, fitness, rmse).

    The kernel is `kernel_m`, or a third of the correspondence distance when 0. With `fix_yaw`
    only x and y are solved for.
    """
    assert target.tree is not None
    kernel = kernel_m or max_distance_m / 3.0
    fitness, rmse = 0.0, 0.0
    for _ in range(iterations):
        c, s = np.cos(yaw), np.sin(yaw)
        moved = source @ np.array([[c, s], [-s, c]]) + [x, y]
        dist, idx = target.tree.query(moved, distance_upper_bound=max_distance_m)
        ok = np.isfinite(dist)
        if ok.sum() < 10:
            return x, y, yaw, 0.0, 0.0
        n = target.normals[idx[ok]]
        r = ((moved[ok] - target.points[idx[ok]]) * n).sum(axis=1)
        src = source[ok]
        # d(R p)/d yaw = (-s px - c py, c px - s py)
        drot = np.stack([-s * src[:, 0] - c * src[:, 1], c * src[:, 0] - s * src[:, 1]], axis=1)
        jac = np.stack([n[:, 0], n[:, 1], (drot * n).sum(axis=1)], axis=1)
        if fix_yaw:
            jac = jac[:, :2]
        w = np.where(np.abs(r) < kernel, (1 - (r / kernel) ** 2) ** 2, 0.0)
        h = (jac * w[:, None]).T @ jac
        g = (jac * w[:, None]).T @ r
        try:
            step = -np.linalg.solve(h + 1e-9 * np.eye(jac.shape[1]), g)
        except np.linalg.LinAlgError:
            break
        if fix_yaw:
            step = np.append(step, 0.0)
        x, y, yaw = x + step[0], y + step[1], yaw + step[2]
        fitness = float(ok.mean())
        rmse = float(np.sqrt(np.mean(r**2)))
        if np.abs(step[:2]).max() < 1e-5 and abs(step[2]) < 1e-6:
            break
    return x, y, yaw, fitness, rmse


class Scan2DMatcher:
    """Registers planar scans (base frame, z ignored) against a local 2D map."""

    def __init__(self, voxel_m: float, map_voxel_m: float, max_keyframes: int,
                 threshold: AdaptiveThreshold, max_iterations: int, min_fitness: float = 0.3,
                 fine_kernel_m: float = 0.0, max_gyro_disagreement_deg: float = 0.0,
                 low_fitness: float = 0.0, max_overruled: int = 3) -> None:
        self.voxel_m = voxel_m
        self.max_gyro_disagreement_rad = math.radians(max_gyro_disagreement_deg)
        self.low_fitness = low_fitness
        self.max_overruled = max_overruled
        self.overruled = 0  # registrations whose heading the gyro overruled
        self._overruled_in_a_row = 0
        self.fine_kernel_m = fine_kernel_m
        self.refined = 0
        self.map = Map2D(map_voxel_m, max_keyframes)
        self.threshold = threshold
        self.max_iterations = max_iterations
        self.min_fitness = min_fitness
        self.failures = 0

    @classmethod
    def from_config(cls, cfg: MappingConfig, threshold: AdaptiveThreshold) -> Scan2DMatcher:
        return cls(cfg.voxel_size_m, cfg.local_map.voxel_size_m, cfg.local_map.keyframes, threshold,
                   cfg.icp.max_iterations, fine_kernel_m=cfg.icp.fine_kernel_m,
                   max_gyro_disagreement_deg=cfg.icp.max_gyro_disagreement_deg,
                   low_fitness=cfg.icp.gyro_low_fitness)

    def match(self, points_base: F64, predicted: F64, gyro_prior: bool = False) -> ScanMatch:
        """Register against the local 2D map from `predicted`.

        With `gyro_prior` (the predicted heading is the IMU gyro's over a fraction of a second),
        a registration that turns the heading more than `max_gyro_disagreement_deg` (half that
        below `low_fitness`) from the gyro's keeps the gyro's heading, x and y solved again at
        it, as `odometry.ScanMatcher` does in 3D: a scan of one wall and a doorway can rotate
        about its few lines, and a turned scan turns the rest of the visit. After
        `max_overruled` in a row the registration is taken again, so a biased gyro cannot hold
        the odometry off the map.
        """
        if self.map.tree is None or len(points_base) < 10:
            return ScanMatch(predicted, 0.0, 0.0, False)
        source = grid_downsample_2d(points_base[:, :2], self.voxel_m)
        x, y, yaw, fitness, rmse = icp_2d(source, self.map, float(predicted[0, 3]),
                                          float(predicted[1, 3]), yaw_rad(predicted),
                                          self.threshold.value_m, self.max_iterations)
        if fitness < self.min_fitness:
            self.failures += 1
            return ScanMatch(predicted, fitness, rmse, False)
        if self.fine_kernel_m > 0:
            # A last pass at the lidar's noise, as `odometry.ScanMatcher` does; the map's k-d
            # tree is kept, so every scan gets it.
            x, y, yaw, _, _ = icp_2d(source, self.map, x, y, yaw, self.threshold.value_m,
                                     self.max_iterations, self.fine_kernel_m)
            self.refined += 1
        limit = self.max_gyro_disagreement_rad * (0.5 if fitness < self.low_fitness else 1.0)
        turned = wrap_angle(yaw - yaw_rad(predicted))
        if (gyro_prior and limit > 0 and abs(turned) > limit
                and self._overruled_in_a_row < self.max_overruled):
            self.overruled += 1
            self._overruled_in_a_row += 1
            held = yaw_rad(predicted)
            x, y, _, _, _ = icp_2d(source, self.map, x, y, held, self.threshold.value_m,
                                   self.max_iterations, self.fine_kernel_m, fix_yaw=True)
            return ScanMatch(yaw_pose(held, np.array([x, y, predicted[2, 3]])), fitness, rmse, False)
        self._overruled_in_a_row = 0
        pose = yaw_pose(yaw, np.array([x, y, predicted[2, 3]]))
        self.threshold.update(inverse(predicted) @ pose)
        return ScanMatch(pose, fitness, rmse, True)

    def add_keyframe(self, points_base: F64, pose: F64, sensor: F64 | None = None) -> None:
        """A keyframe's points (base frame) at `pose`; `sensor` is not needed in the plane."""
        self.map.add(transform(points_base, pose)[:, :2])
