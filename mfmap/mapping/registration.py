"""Scan registration with open3d: downsampling, normals, robust point-to-plane ICP."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

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


def icp(
    source: o3d.geometry.PointCloud,
    target: o3d.geometry.PointCloud,
    init: F64,
    max_distance_m: float,
    kernel_scale_m: float,
    max_iterations: int = 30,
    tolerance: float = 1e-6,
) -> Registration:
    """Point-to-plane ICP with a Tukey kernel; the target needs normals.

    Stops when fitness and inlier RMSE change by less than `tolerance` (relative).
    """
    result = reg.registration_icp(
        source,
        target,
        max_distance_m,
        init,
        reg.TransformationEstimationPointToPlane(reg.TukeyLoss(k=kernel_scale_m)),
        reg.ICPConvergenceCriteria(tolerance, tolerance, max_iterations),
    )
    return Registration(np.asarray(result.transformation).copy(), float(result.fitness),
                        float(result.inlier_rmse))


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
        source = to_o3d(downsample(source_points, voxel))
        target = with_normals(downsample(target_points, voxel), 3.0 * voxel)
        result = icp(source, target, result.transform, 3.0 * voxel, voxel, max_iterations)
    return result


def information(
    source: o3d.geometry.PointCloud, target: o3d.geometry.PointCloud, max_distance_m: float,
    transform: F64,
) -> F64:
    """6x6 information of an alignment, (rx, ry, rz, tx, ty, tz) order, unit point noise."""
    return np.asarray(
        reg.get_information_matrix_from_point_clouds(source, target, max_distance_m, transform)
    )
