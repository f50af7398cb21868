"""Inter-floor registration: align adjacent floors on their shared structure (x, y, yaw only).

Each floor's cloud is cut to a height band above its own floor level and shifted to floor-relative
height, so walls that run through both floors (outer walls, shafts, stairwells, pillars) overlap
in 3D. FPFH + RANSAC gives a global candidate, point-to-plane ICP refines it, and every estimate is
projected onto gravity-aligned (x, y, yaw). Similar or symmetric floors are a trap (seed 001): a
match is rejected when a distinct solution scores nearly as well, or when it is far from the
elevator's prior.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from mfmap.types import F64

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class FloorMatch:
    """Result of registering floor `upper` onto floor `lower`.

    `correction` is a 4x4 world-frame transform (x, y, yaw only) that, applied to the upper floor's
    current map, aligns it with the lower floor.
    """

    lower: int
    upper: int
    correction: F64
    fitness: float
    rmse_m: float
    runner_up_fitness: float
    accepted: bool
    reason: str

    @property
    def dx_m(self) -> float:
        return float(self.correction[0, 3])

    @property
    def dy_m(self) -> float:
        return float(self.correction[1, 3])

    @property
    def dyaw_deg(self) -> float:
        return math.degrees(math.atan2(self.correction[1, 0], self.correction[0, 0]))


def project_xyyaw(transform: F64) -> F64:
    """Closest gravity-aligned transform: keep x, y and yaw, drop roll, pitch and z."""
    yaw = math.atan2(transform[1, 0], transform[0, 0])
    out = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    out[:2, :2] = [[c, -s], [s, c]]
    out[:2, 3] = transform[:2, 3]
    return out


def _yaw_about(center_xy: F64, yaw: float) -> F64:
    """Rotation by yaw about a vertical axis through center_xy."""
    out = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    out[:2, :2] = [[c, -s], [s, c]]
    out[:2, 3] = center_xy - out[:2, :2] @ center_xy
    return out


def _cloud(points: np.ndarray, voxel_m: float) -> o3d.geometry.PointCloud:
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points.astype(np.float64)))
    pcd = pcd.voxel_down_sample(voxel_m)
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=voxel_m * 3.0, max_nn=30))
    # Walls: keep normals horizontal so point-to-plane ICP cannot drift in z or tilt.
    normals = np.asarray(pcd.normals)
    normals[:, 2] = 0.0
    norm = np.linalg.norm(normals, axis=1, keepdims=True)
    normals /= np.maximum(norm, 1e-9)
    pcd.normals = o3d.utility.Vector3dVector(normals)
    return pcd


def _distinct(a: F64, b: F64, dist_m: float, yaw_deg: float) -> bool:
    delta = np.linalg.inv(a) @ b
    yaw = abs(math.degrees(math.atan2(delta[1, 0], delta[0, 0])))
    return bool(np.hypot(delta[0, 3], delta[1, 3]) > dist_m or yaw > yaw_deg)


def _extrude_flat(points: np.ndarray, layers: int = 5, step_m: float = 0.1) -> np.ndarray:
    """A planar (2D scanner) cloud as short vertical walls, so normals and FPFH are defined."""
    if np.ptp(points[:, 2]) > 2 * step_m:
        return points
    return np.concatenate([points + np.array([0.0, 0.0, k * step_m]) for k in range(layers)])


def _plausible(transform: F64, max_m: float, max_deg: float) -> bool:
    yaw = abs(math.degrees(math.atan2(transform[1, 0], transform[0, 0])))
    return bool(np.hypot(transform[0, 3], transform[1, 3]) <= max_m and yaw <= max_deg)


def register_floors(
    lower_points: np.ndarray,
    upper_points: np.ndarray,
    lower: int,
    upper: int,
    voxel_m: float = 0.1,
    min_fitness: float = 0.3,
    ambiguity_ratio: float = 0.9,
    max_correction_m: float = 2.0,
    max_correction_deg: float = 20.0,
    seed: int = 0,
) -> FloorMatch:
    """Register the upper floor's band onto the lower floor's (both floor-relative, world x, y).

    Both inputs are (N, 3) points in the world frame with z already made floor-relative.
    """
    if len(lower_points) < 50 or len(upper_points) < 50:
        return FloorMatch(lower, upper, np.eye(4), 0.0, 0.0, 0.0, False, "too few points")
    lower_points, upper_points = _extrude_flat(lower_points), _extrude_flat(upper_points)
    o3d.utility.random.seed(seed)
    reg = o3d.pipelines.registration
    target = _cloud(lower_points, voxel_m)
    source = _cloud(upper_points, voxel_m)
    feature_param = o3d.geometry.KDTreeSearchParamHybrid(radius=voxel_m * 5.0, max_nn=50)
    source_fpfh = reg.compute_fpfh_feature(source, feature_param)  # type: ignore[call-arg]
    target_fpfh = reg.compute_fpfh_feature(target, feature_param)  # type: ignore[call-arg]
    ransac = reg.registration_ransac_based_on_feature_matching(
        source,
        target,
        source_fpfh,
        target_fpfh,
        True,
        voxel_m * 1.5,
        reg.TransformationEstimationPointToPoint(False),
        3,
        [
            reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
            reg.CorrespondenceCheckerBasedOnDistance(voxel_m * 1.5),
        ],
        reg.RANSACConvergenceCriteria(20000, 0.999),
    )
    # Starts: the global (RANSAC) guess, the prior (identity: the elevator hold), and the prior
    # shifted and turned a little, so a floor that slides along itself (a corridor, a row of
    # pillars) shows itself as a second, distinct solution that fits as well.
    starts = [np.eye(4), project_xyyaw(np.asarray(ransac.transformation))]
    starts += [_yaw_about(np.zeros(2), math.radians(5.0)), _yaw_about(np.zeros(2), math.radians(-5.0))]
    for dx, dy in ((0.5, 0.0), (0.0, 0.5), (-0.5, 0.0), (0.0, -0.5)):
        shifted = np.eye(4)
        shifted[:2, 3] = (dx, dy)
        starts.append(shifted)
    coarse_source = source.voxel_down_sample(voxel_m * 2.0)
    coarse_target = target.voxel_down_sample(voxel_m * 2.0)
    candidates: list[tuple[float, float, F64]] = []
    for start in starts:
        current = start
        for cloud_s, cloud_t, radius in (
            (coarse_source, coarse_target, voxel_m * 5.0),
            (coarse_source, coarse_target, voxel_m * 2.5),
            (source, target, voxel_m * 1.0),
        ):
            result = reg.registration_icp(
                cloud_s,
                cloud_t,
                radius,
                current,
                reg.TransformationEstimationPointToPlane(),
                reg.ICPConvergenceCriteria(1e-5, 1e-5, 15),
            )
            current = project_xyyaw(np.asarray(result.transformation))
        score = reg.evaluate_registration(source, target, voxel_m, current)
        candidates.append((float(score.fitness), float(score.inlier_rmse), current))
    # Only corrections the mapping stage's prior allows compete: a 180-degree turn of a
    # rectangular building fits its outer walls but is not a plausible error of the elevator hold.
    plausible = [c for c in candidates if _plausible(c[2], max_correction_m, max_correction_deg)]
    if not plausible:
        return FloorMatch(lower, upper, np.eye(4), 0.0, 0.0, 0.0, False,
                          "no solution within the plausible correction")
    candidates = sorted(plausible, key=lambda c: -c[0])
    logger.debug("candidates %s", [(round(c[0], 3), np.round(c[2][:2, 3], 3).tolist()) for c in candidates])
    best_fitness, best_rmse, best = candidates[0]
    runner_up = max(
        (c[0] for c in candidates[1:] if _distinct(best, c[2], 4.0 * voxel_m, 3.0)), default=0.0
    )
    reason = "ok"
    accepted = True
    if best_fitness < min_fitness:
        accepted, reason = False, f"fitness {best_fitness:.2f} < {min_fitness:.2f}"
    elif runner_up >= ambiguity_ratio * best_fitness:
        accepted, reason = False, f"ambiguous: a distinct solution scores {runner_up:.2f} vs {best_fitness:.2f}"
    logger.debug("floors %d/%d: fitness %.3f runner-up %.3f %s", lower, upper, best_fitness, runner_up, reason)
    return FloorMatch(lower, upper, best, best_fitness, best_rmse, runner_up, accepted, reason)
