"""Inter-floor registration: align adjacent floors on their shared structure (x, y, yaw only).

Each floor's cloud is cut to a height band above its own floor level and shifted to floor-relative
height, so walls that run through both floors (outer walls, shafts, stairwells, pillars) overlap
in 3D. FPFH + RANSAC gives a global candidate, point-to-plane ICP refines it, and every estimate is
projected onto gravity-aligned (x, y, yaw). Similar or symmetric floors are a trap (Fan et al.'s corridors): a
match is rejected when a distinct solution scores nearly as well, or when it is far from the
elevator's prior.
"""

from __future__ import annotations

import functools
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import open3d as o3d
from scipy.spatial.transform import Rotation

from mfmap.mapping.registration import IcpTarget
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


def _cloud(points: np.ndarray, voxel_m: float, views: np.ndarray | None = None) -> o3d.geometry.PointCloud:
    """Downsampled, with horizontal normals; with `views` (per point, towards where it was seen
    from) each normal points to the side of its wall the robot stood on."""
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points.astype(np.float64)))
    if views is not None:
        # Averaged per voxel like the points; estimate_normals then turns each normal to agree.
        pcd.normals = o3d.utility.Vector3dVector(views.astype(np.float64))
    pcd = pcd.voxel_down_sample(voxel_m)
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=voxel_m * 3.0, max_nn=30))
    # Walls: keep normals horizontal so point-to-plane ICP cannot drift in z or tilt.
    normals = np.asarray(pcd.normals)
    normals[:, 2] = 0.0
    norm = np.linalg.norm(normals, axis=1, keepdims=True)
    normals /= np.maximum(norm, 1e-9)
    pcd.normals = o3d.utility.Vector3dVector(normals)
    return pcd


# The fine pass's iterations: SCORE_ITERATIONS for every place the starts meet, then the winner
# goes on to FINE_ITERATIONS. On floors that share little (fitness 0.27, as two floors of the
# simulator's stairs building) the fine pass creeps along a shallow valley: stopped at 15
# iterations, inputs a few millimetres apart give corrections 6 cm and 0.15 degrees apart; at 100
# they agree within 1 cm and 0.03 degrees, and 300 moves them by a millimetre. Running every place
# to 100 would cost a second per pair of floors; only the winner needs it.
SCORE_ITERATIONS = 15
FINE_ITERATIONS = 100

# The inter-floor ICP's prior on roll and pitch, weak: a degree of tilt weighs as a metre of
# point-to-plane residual at every point. It only damps the steps (a fit that tilts the floors a
# few tenths of a degree, as open3d's did where it converged, is kept).
TILT_PRIOR_M_PER_DEG = 1.0


class _Target(IcpTarget):
    """A floor's cloud (horizontal normals) and its k-d tree, for point-to-plane ICP that holds z.

    With the walls' normals horizontal nothing measures z, and open3d's six-degree-of-freedom
    point-to-plane ICP solves a singular system: from starts a degree or two off it ran away
    (two floors of the simulator's stairs building, the top one's initial poses turned by half a
    degree: one start comes back turned by 180 degrees, the rest at fitness 0.03 where the match
    is 0.27, and the floors' factor is rejected). Here the coarse
    passes solve for x, y and yaw alone, and the fine pass adds roll and pitch, which walls seen
    over the band's height do measure, so the x, y and yaw kept are those of open3d's fit where
    that converged.
    """

    def icp(self, source: F64, start: F64, max_distance_m: float, tilt: bool = False,
            iterations: int = 15, source_normals: F64 | None = None, robust_m: float = 0.0) -> F64:
        """Point-to-plane ICP from `start` in x, y and yaw; with `tilt` also roll and pitch,
        turned about the source's centre and held near `start`'s by a prior (the clouds are
        gravity-aligned already). z, which horizontal normals leave free, is held.

        With `source_normals` and a target of oriented normals, a point is matched only to a
        surface seen from the same side: the two faces of a 12 cm inner wall, one seen on each
        floor, otherwise pull the floors a few centimetres towards each other's face."""
        pose = start.astype(np.float64).copy()
        tilt_weight = len(source) * (TILT_PRIOR_M_PER_DEG / math.radians(1.0)) ** -2
        facing = source_normals is not None and self.oriented
        for _ in range(iterations):
            moved = source @ pose[:3, :3].T + pose[:3, 3]
            found, idx, _ = self.nearest(moved, max_distance_m)
            if facing:
                assert source_normals is not None
                turned = source_normals[found] @ pose[:3, :3].T
                same_side = np.einsum("ij,ij->i", turned, self.normals[idx]) > 0.0
                found, idx = found[same_side], idx[same_side]
            if len(found) < 6:
                break
            p, q, n = moved[found], self.points[idx], self.normals[idx]
            residual = np.einsum("ij,ij->i", n, p - q)
            pivot = moved.mean(axis=0)
            # d residual / d (tx, ty, yaw[, roll, pitch about the pivot]), turns on the left.
            columns = [n[:, 0], n[:, 1], p[:, 0] * n[:, 1] - p[:, 1] * n[:, 0]]
            if tilt:
                c = p - pivot
                columns += [c[:, 1] * n[:, 2] - c[:, 2] * n[:, 1], c[:, 2] * n[:, 0] - c[:, 0] * n[:, 2]]
            jac = np.column_stack(columns)
            # Cauchy weights: structure only one floor has (rooms, furniture) lies within the
            # match distance of the other's here and there, and each such pair pulls.
            weight = 1.0 / (1.0 + (residual / robust_m) ** 2) if robust_m > 0 else np.ones(len(residual))
            hessian = jac.T @ (jac * weight[:, None])
            gradient = jac.T @ (residual * weight)
            if tilt:
                off_level = Rotation.from_matrix(pose[:3, :3] @ start[:3, :3].T).as_rotvec()
                hessian[3:, 3:] += tilt_weight * np.eye(2)
                gradient[3:] += tilt_weight * off_level[:2]
            if np.linalg.cond(hessian) > 1e12:
                break
            step = np.linalg.solve(hessian, -gradient)
            tilt_step = np.eye(4)
            if tilt:
                tilt_step[:3, :3] = Rotation.from_rotvec([step[3], step[4], 0.0]).as_matrix()
                tilt_step[:3, 3] = pivot - tilt_step[:3, :3] @ pivot
            spin = _yaw_about(np.zeros(2), float(step[2]))
            spin[:2, 3] = step[:2]
            height = pose[2, 3]
            pose = spin @ tilt_step @ pose
            pose[2, 3] = height  # not measured: as it came in
            if np.abs(step[2:]).max() < 1e-6 and np.abs(step[:2]).max() < 1e-5:
                break
        return pose


@dataclass(frozen=True)
class _Candidate:
    """Where the fine pass ended from one start: its scores at the voxel and at half of it."""

    fitness: float
    sharp_fitness: float
    correction: F64  # x, y, yaw
    pose: F64  # the fine pass's pose, with its tilt


def _distinct(a: F64, b: F64, dist_m: float, yaw_deg: float) -> bool:
    delta = np.linalg.inv(a) @ b
    yaw = abs(math.degrees(math.atan2(delta[1, 0], delta[0, 0])))
    return bool(np.hypot(delta[0, 3], delta[1, 3]) > dist_m or yaw > yaw_deg)


def _extrude_flat(points: np.ndarray, views: np.ndarray | None, layers: int = 5,
                  step_m: float = 0.1) -> tuple[np.ndarray, np.ndarray | None]:
    """A planar (2D scanner) cloud as short vertical walls, so normals and FPFH are defined,
    with its views (each layer seen from where its point was); other clouds as they are."""
    if np.ptp(points[:, 2]) > 2 * step_m:
        return points, views
    lifts = [np.array([0.0, 0.0, k * step_m]) for k in range(layers)]
    walls = np.concatenate([points + lift for lift in lifts])
    return walls, None if views is None else np.concatenate([views - lift for lift in lifts])


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
    lower_views: np.ndarray | None = None,
    upper_views: np.ndarray | None = None,
    robust_m: float = 0.0,
) -> FloorMatch:
    """Register the upper floor's band onto the lower floor's (both floor-relative, world x, y).

    Both inputs are (N, 3) points in the world frame with z already made floor-relative; with
    both `*_views` (per point, towards where it was seen from) a point is matched only to the
    same face of a wall.
    """
    if len(lower_points) < 50 or len(upper_points) < 50:
        return FloorMatch(lower, upper, np.eye(4), 0.0, 0.0, 0.0, False, "too few points")
    oriented = lower_views is not None and upper_views is not None
    target = _band_cloud(lower_points, lower_views if oriented else None, voxel_m)
    source = _band_cloud(upper_points, upper_views if oriented else None, voxel_m)
    o3d.utility.random.seed(seed)
    reg = o3d.pipelines.registration
    starts = _starts(_global_guess(source, target, voxel_m))
    coarse = _Target(target.voxel_down_sample(voxel_m * 2.0))
    coarse_source = np.asarray(source.voxel_down_sample(voxel_m * 2.0).points)
    fine_pass = functools.partial(
        _Target(target, oriented=oriented).icp, np.asarray(source.points), max_distance_m=voxel_m,
        tilt=True, source_normals=np.asarray(source.normals) if oriented else None, robust_m=robust_m)
    candidates = _refine_starts(starts, coarse, coarse_source, fine_pass, source, target, voxel_m)
    # Only corrections the mapping stage's prior allows compete: a 180-degree turn of a
    # rectangular building fits its outer walls but is not a plausible error of the elevator hold.
    plausible = [c for c in candidates if _plausible(c.correction, max_correction_m, max_correction_deg)]
    if not plausible:
        return FloorMatch(lower, upper, np.eye(4), 0.0, 0.0, 0.0, False,
                          "no solution within the plausible correction")
    # Ranked by the share of points within half the voxel: at the voxel itself two places 10 cm
    # apart can score alike (on floors that share little, 0.299 at the wrong one against 0.271 at
    # the right one; within 5 cm, 0.175 against 0.214).
    candidates = sorted(plausible, key=lambda c: -c.sharp_fitness)
    logger.debug("candidates %s", [(round(c.fitness, 3), round(c.sharp_fitness, 3),
                                    np.round(c.correction[:2, 3], 3).tolist()) for c in candidates])
    # The winner's fine pass runs on to convergence (FINE_ITERATIONS in all).
    pose = fine_pass(candidates[0].pose, iterations=FINE_ITERATIONS - SCORE_ITERATIONS)
    best = project_xyyaw(pose)
    score = reg.evaluate_registration(source, target, voxel_m, best)
    best_fitness, best_rmse = float(score.fitness), float(score.inlier_rmse)
    runner_up = max(
        (c.fitness for c in candidates[1:] if _distinct(best, c.correction, 4.0 * voxel_m, 3.0)),
        default=0.0,
    )
    accepted, reason = _verdict(best_fitness, runner_up, min_fitness, ambiguity_ratio)
    logger.debug("floors %d/%d: fitness %.3f runner-up %.3f %s", lower, upper, best_fitness, runner_up, reason)
    return FloorMatch(lower, upper, best, best_fitness, best_rmse, runner_up, accepted, reason)


def _verdict(fitness: float, runner_up: float, min_fitness: float, ambiguity_ratio: float
             ) -> tuple[bool, str]:
    if fitness < min_fitness:
        return False, f"fitness {fitness:.2f} < {min_fitness:.2f}"
    if runner_up >= ambiguity_ratio * fitness:
        return False, f"ambiguous: a distinct solution scores {runner_up:.2f} vs {fitness:.2f}"
    return True, "ok"


def _band_cloud(points: np.ndarray, views: np.ndarray | None, voxel_m: float) -> o3d.geometry.PointCloud:
    """A floor's band as `_cloud`, a 2D scanner's extruded first."""
    walls, wall_views = _extrude_flat(points, views)
    return _cloud(walls, voxel_m, wall_views)


def _global_guess(source: Any, target: Any, voxel_m: float) -> F64:
    """The upper floor's pose on the lower one by FPFH features and RANSAC, with no prior."""
    reg = o3d.pipelines.registration
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
    return np.asarray(ransac.transformation)


def _starts(global_guess: F64) -> list[F64]:
    """Starts: the global (RANSAC) guess, the prior (identity: the elevator hold), and the prior
    shifted and turned a little, so a floor that slides along itself (a corridor, a row of
    pillars) shows itself as a second, distinct solution that fits as well."""
    starts = [np.eye(4), project_xyyaw(global_guess)]
    starts += [_yaw_about(np.zeros(2), math.radians(5.0)), _yaw_about(np.zeros(2), math.radians(-5.0))]
    for dx, dy in ((0.5, 0.0), (0.0, 0.5), (-0.5, 0.0), (0.0, -0.5)):
        shifted = np.eye(4)
        shifted[:2, 3] = (dx, dy)
        starts.append(shifted)
    return starts


def _refine_starts(
    starts: list[F64],
    coarse: _Target,
    coarse_source: np.ndarray,
    fine_pass: Callable[..., F64],
    source: Any,
    target: Any,
    voxel_m: float,
) -> list[_Candidate]:
    """Each start through the coarse passes and the fine pass (`fine_pass(start, iterations=)`),
    scored; one candidate per start."""
    reg = o3d.pipelines.registration
    candidates: list[_Candidate] = []
    refined: list[tuple[F64, _Candidate]] = []  # where the coarse passes ended -> candidate
    # Every start goes through the coarse passes, and the prior once more without them: on floors
    # that share little the coarse passes can pull every start into one valley beside the true
    # one (all nine can meet 10 cm off, where the fine pass alone from the prior stays within
    # 2 cm).
    for start, with_coarse in [(at, True) for at in starts] + [(np.eye(4), False)]:
        current = start
        if with_coarse:
            for radius in (voxel_m * 5.0, voxel_m * 2.5):
                current = coarse.icp(coarse_source, current, radius)
        # Starts usually meet in the coarse passes: the fine pass and the score once per place.
        done = next((c for at, c in refined if not _distinct(at, current, 1e-3, 1e-3)), None)
        if done is None:
            pose = fine_pass(current, iterations=SCORE_ITERATIONS)
            best = project_xyyaw(pose)
            score = reg.evaluate_registration(source, target, voxel_m, best)
            sharp = reg.evaluate_registration(source, target, voxel_m / 2.0, best)
            done = _Candidate(float(score.fitness), float(sharp.fitness), best, pose)
            refined.append((current, done))
        candidates.append(done)
    return candidates
