"""Scan registration: downsampling and normals with open3d, robust point-to-plane ICP.

The ICP is open3d's algorithm (`registration_icp` with `TransformationEstimationPointToPlane`
and a `TukeyLoss`) step for step, on a target whose k-d tree is built once: open3d builds the
target's tree again in every call, which was 60-75 % of a call's time (3.1 of 5.0 ms for a local
map of 18k points), and the mapper registers every scan twice against a map that changes only at
keyframes. The result equals open3d's to rounding (the tests compare them on real scans).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d
from pykdtree.kdtree import KDTree

from mfmap.types import F32, F64

reg = o3d.pipelines.registration


@dataclass(frozen=True)
class Registration:
    """Result of aligning a source cloud to a target: target_T_source and its quality."""

    transform: F64  # (4, 4)
    fitness: float  # share of source points with a correspondence, [0, 1]
    rmse_m: float  # RMSE of the inlier correspondences


def to_o3d(points: F32 | F64) -> o3d.geometry.PointCloud:
    cloud = o3d.geometry.PointCloud()
    cloud.points = o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64))
    return cloud


def downsample(points: F32 | F64, voxel_m: float) -> F64:
    """Voxel-grid downsample (centroid per voxel)."""
    if len(points) == 0:
        return np.zeros((0, 3))
    return np.asarray(to_o3d(points).voxel_down_sample(voxel_m).points)


def with_normals(points: F32 | F64, radius_m: float, max_nn: int = 20) -> o3d.geometry.PointCloud:
    cloud = to_o3d(points)
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius_m, max_nn=max_nn))
    return cloud


def downsample_viewed(points: F64, views: F64, voxel_m: float) -> tuple[F64, F64]:
    """Voxel-grid downsample of points and their unit directions towards the sensor that saw
    them: per voxel the centroid and the mean direction (open3d averages normals)."""
    if len(points) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    cloud = to_o3d(points)
    cloud.normals = o3d.utility.Vector3dVector(np.asarray(views, dtype=np.float64))
    down = cloud.voxel_down_sample(voxel_m)
    return np.asarray(down.points), np.asarray(down.normals)


def view_directions(points: F64, sensor: F64) -> F64:
    """Unit vectors from each point towards the sensor position that saw it."""
    towards = sensor[None, :] - points
    norm = np.linalg.norm(towards, axis=1, keepdims=True)
    return towards / np.maximum(norm, 1e-9)


class IcpTarget:
    """A cloud with normals and its k-d tree, for many ICP calls (or nearest-point queries)
    against it. With `oriented`, every normal points to the side its surface was seen from."""

    def __init__(self, cloud: o3d.geometry.PointCloud, oriented: bool = False) -> None:
        self.cloud = cloud
        self.points: F64 = np.asarray(cloud.points)
        self.normals: F64 = np.asarray(cloud.normals)
        self.oriented = oriented
        self.tree = KDTree(self.points) if len(self.points) else None

    @classmethod
    def estimate(cls, points: F32 | F64, normal_radius_m: float, max_nn: int = 20,
                 views: F64 | None = None) -> IcpTarget:
        """The points with open3d's normals (`with_normals`); with `views` (per point, towards
        the sensors that saw it) each normal turned to the side it was seen from."""
        if views is None:
            return cls(with_normals(points, normal_radius_m, max_nn))
        cloud = to_o3d(points)
        # open3d turns each estimated normal to agree with the normal the point already has.
        cloud.normals = o3d.utility.Vector3dVector(np.asarray(views, dtype=np.float64))
        cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=normal_radius_m,
                                                                    max_nn=max_nn))
        return cls(cloud, oriented=True)

    def __len__(self) -> int:
        return len(self.points)

    def nearest(self, points: F64, max_distance_m: float,
                sensor: F64 | None = None) -> tuple[np.ndarray, np.ndarray, F64]:
        """(source indices, target indices, distances) of the points' nearest target point
        within `max_distance_m`.

        With `sensor` (its position, in the target's frame) and oriented normals, a point's
        nearest target point counts only where its surface faces the sensor: a point on one
        face of a thin wall is never matched to the other face, seen from the other side.
        """
        if self.tree is None or len(points) == 0:
            empty = np.zeros(0, dtype=np.int64)
            return empty, empty, np.zeros(0)
        dist, idx = self.tree.query(points, k=1, distance_upper_bound=max_distance_m)
        found = np.flatnonzero(idx < len(self.points))
        if sensor is not None and self.oriented:
            near = idx[found]
            facing = np.einsum("ij,ij->i", self.normals[near], sensor[None, :] - self.points[near])
            found = found[facing > 0.0]
        return found, idx[found].astype(np.int64), dist[found]


def _euler_pose(x: F64) -> F64:
    """open3d's TransformVector6dToMatrix4d: Rz(x2) Ry(x1) Rx(x0), translation x3..x5."""
    ca, sa = np.cos(x[0]), np.sin(x[0])
    cb, sb = np.cos(x[1]), np.sin(x[1])
    cc, sc = np.cos(x[2]), np.sin(x[2])
    pose = np.eye(4)
    pose[:3, :3] = np.array([
        [cc * cb, cc * sb * sa - sc * ca, cc * sb * ca + sc * sa],
        [sc * cb, sc * sb * sa + cc * ca, sc * sb * ca - cc * sa],
        [-sb, cb * sa, cb * ca],
    ])
    pose[:3, 3] = x[3:]
    return pose


def _solve_psd(a: F64, b: F64) -> F64:
    """x with a x = b for a symmetric positive semi-definite a, as open3d solves its ICP step
    (Eigen's LDLT): an unknown that nothing measures (its row of a all zero, like x, y and yaw
    against a flat floor) gets 0 and the others their solution."""
    live = np.flatnonzero(np.any(a != 0.0, axis=1))
    x = np.zeros(len(b))
    if len(live) == 0:
        return x
    sub, rhs = a[np.ix_(live, live)], b[live]
    try:
        x[live] = np.linalg.solve(sub, rhs)
    except np.linalg.LinAlgError:  # singular otherwise: the least-squares step of least norm
        x[live] = np.linalg.lstsq(sub, rhs, rcond=None)[0]
    return x


def icp(
    source: F32 | F64,
    target: IcpTarget,
    init: F64,
    max_distance_m: float,
    kernel_scale_m: float,
    max_iterations: int = 30,
    tolerance: float = 1e-6,
    sensor: F64 | None = None,
) -> Registration:
    """Point-to-plane ICP with a Tukey kernel, as open3d's `registration_icp` runs it.

    Each iteration takes every source point's nearest target point within `max_distance_m`,
    weighs its point-to-plane residual r by Tukey's (1 - (r/k)^2)^2 (0 beyond k), solves the
    Gauss-Newton step in (rx, ry, rz, tx, ty, tz) and applies it on the left. Stops when fitness
    and inlier RMSE change by less than `tolerance`. With `sensor` (the sensor's position in the
    source's frame) and a target with oriented normals, only target surfaces facing the sensor
    are correspondences (`IcpTarget.nearest`).
    """
    transform = np.asarray(init, dtype=np.float64).copy()
    moved = np.asarray(source, dtype=np.float64) @ transform[:3, :3].T + transform[:3, 3]

    def score(points: F64) -> tuple[np.ndarray, np.ndarray, float, float]:
        seen_from = None if sensor is None else transform[:3, :3] @ sensor + transform[:3, 3]
        src, tgt, dist = target.nearest(points, max_distance_m, seen_from)
        if len(src) == 0:
            return src, tgt, 0.0, 0.0
        return src, tgt, len(src) / len(points), float(np.sqrt(np.dot(dist, dist) / len(src)))

    src, tgt, fitness, rmse = score(moved)
    for _ in range(max_iterations):
        step = np.eye(4)
        if len(src):
            p, q, n = moved[src], target.points[tgt], target.normals[tgt]
            residual = np.einsum("ij,ij->i", p - q, n)
            jac = np.hstack([np.cross(p, n), n])
            scaled = residual / kernel_scale_m
            weight = np.where(np.abs(residual) < kernel_scale_m, (1.0 - scaled * scaled) ** 2, 0.0)
            weighted = jac * weight[:, None]
            step = _euler_pose(_solve_psd(weighted.T @ jac, -(weighted.T @ residual)))
        transform = step @ transform
        moved = moved @ step[:3, :3].T + step[:3, 3]
        last_fitness, last_rmse = fitness, rmse
        src, tgt, fitness, rmse = score(moved)
        if abs(last_fitness - fitness) < tolerance and abs(last_rmse - rmse) < tolerance:
            break
    return Registration(transform, fitness, rmse)


def register_pair(
    source_points: F32 | F64,
    target_points: F32 | F64,
    init: F64 | None = None,
    voxels_m: tuple[float, ...] = (0.5, 0.2),
    max_iterations: int = 50,
) -> Registration:
    """Coarse-to-fine point-to-plane ICP of two clouds (e.g. consecutive scans, loop pairs).

    Each level downsamples both clouds at its voxel and searches correspondences within 3 voxels,
    so a coarse level brings in a start that is tens of cm off and the finer one refines it.
    """
    transform = np.eye(4) if init is None else np.asarray(init, dtype=np.float64)
    result = Registration(transform, 0.0, 0.0)
    for voxel in voxels_m:
        target = IcpTarget.estimate(downsample(target_points, voxel), 3.0 * voxel)
        result = icp(downsample(source_points, voxel), target, result.transform, 3.0 * voxel,
                     voxel, max_iterations)
    return result


def information(
    source: o3d.geometry.PointCloud, target: o3d.geometry.PointCloud, max_distance_m: float,
    transform: F64,
) -> F64:
    """6x6 information of an alignment, (rx, ry, rz, tx, ty, tz) order, unit point noise."""
    return np.asarray(
        reg.get_information_matrix_from_point_clouds(source, target, max_distance_m, transform)
    )
