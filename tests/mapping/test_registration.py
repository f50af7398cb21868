"""Registration core on real lidar scans (koide3/small_gicp test data, MIT)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d
import pytest

from mfmap.mapping.geometry import inverse, rotation_angle_rad, yaw_pose
from mfmap.mapping.registration import IcpTarget, downsample, icp, register_pair, to_o3d

DATA = Path(__file__).resolve().parent.parent / "data" / "lidar"


def _errors(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    diff = inverse(truth) @ estimate
    return float(np.linalg.norm(diff[:3, 3])), float(np.degrees(rotation_angle_rad(diff)))


def _load(path: Path) -> np.ndarray:
    return np.asarray(o3d.io.read_point_cloud(path).points)


def test_real_scan_pair_within_2cm_and_0p2deg() -> None:
    source, target = _load(DATA / "source.ply"), _load(DATA / "target.ply")
    truth = np.loadtxt(DATA / "T_target_source.txt")
    assert len(source) == 69792 and len(target) == 69088
    result = register_pair(source, target)  # from identity: the truth is 0.50 m and 0.8 deg away
    trans_m, rot_deg = _errors(result.transform, truth)
    assert trans_m < 0.02
    assert rot_deg < 0.2
    assert result.fitness > 0.9


def _open3d_icp(source: np.ndarray, target: IcpTarget, init: np.ndarray, max_distance_m: float,
                kernel_m: float, iterations: int) -> tuple[np.ndarray, float, float]:
    reg = o3d.pipelines.registration
    result = reg.registration_icp(
        to_o3d(source), target.cloud, max_distance_m, init,
        reg.TransformationEstimationPointToPlane(reg.TukeyLoss(k=kernel_m)),
        reg.ICPConvergenceCriteria(1e-6, 1e-6, iterations))
    return np.asarray(result.transformation), result.fitness, result.inlier_rmse


@pytest.mark.parametrize(("voxel_m", "kernel_m", "offset_m", "offset_deg", "iterations"), [
    (0.25, 0.25, 0.3, 2.0, 30),  # the odometry's first pass: 0.75 m correspondences
    (0.25, 0.03, 0.05, 0.3, 30),  # its fine pass, a kernel at the lidar's noise
    (0.5, 0.5, 0.8, 8.0, 40),  # loop verification's coarse pass
    (0.2, 0.2, 0.2, 1.0, 3),  # stopped by the iteration count
])
def test_icp_on_a_kept_tree_is_open3ds_registration_icp(
        voxel_m: float, kernel_m: float, offset_m: float, offset_deg: float,
        iterations: int) -> None:
    """The same poses, fitness and RMSE as open3d's ICP to rounding, on real scans, from starts
    off the truth (so the result is many steps away from the start)."""
    source = downsample(_load(DATA / "source.ply"), voxel_m)
    target = IcpTarget.estimate(downsample(_load(DATA / "target.ply"), voxel_m), 3.0 * voxel_m)
    init = np.loadtxt(DATA / "T_target_source.txt") @ yaw_pose(np.radians(offset_deg),
                                                               np.array([offset_m, -offset_m, 0.0]))
    ours = icp(source, target, init, 3.0 * voxel_m, kernel_m, iterations)
    theirs, fitness, rmse = _open3d_icp(source, target, init, 3.0 * voxel_m, kernel_m, iterations)
    assert np.abs(ours.transform - init).max() > 0.5 * offset_m  # ICP moved it
    assert np.abs(ours.transform - theirs).max() < 1e-9
    assert ours.fitness == pytest.approx(fitness, abs=1e-12)
    assert ours.rmse_m == pytest.approx(rmse, abs=1e-12)
    # The same target again (its tree kept): the same bits.
    again = icp(source, target, init, 3.0 * voxel_m, kernel_m, iterations)
    assert np.array_equal(again.transform, ours.transform)


def test_icp_on_a_plane_or_out_of_reach_keeps_the_start_as_open3d_does() -> None:
    """A flat floor leaves x, y and yaw unmeasured (a singular step: the start is kept); a source
    out of reach has no correspondences (fitness 0, the start kept)."""
    rng = np.random.default_rng(3)
    floor = np.column_stack([rng.uniform(-5, 5, (2000, 2)), np.zeros(2000)])
    target = IcpTarget.estimate(floor, 0.3)
    init = yaw_pose(0.05, np.array([0.2, 0.1, 0.03]))
    for start in (init, yaw_pose(0.0, np.array([50.0, 0.0, 0.0]))):
        ours = icp(floor[::4], target, start, 0.3, 0.1, 30)
        theirs, fitness, rmse = _open3d_icp(floor[::4], target, start, 0.3, 0.1, 30)
        assert np.abs(ours.transform - theirs).max() < 1e-9
        assert ours.fitness == pytest.approx(fitness, abs=1e-12)
        assert ours.rmse_m == pytest.approx(rmse, abs=1e-12)
    assert ours.fitness == 0.0
    assert np.array_equal(ours.transform, yaw_pose(0.0, np.array([50.0, 0.0, 0.0])))


def test_starting_far_off_is_not_silently_accepted() -> None:
    """A start 3 m off lands in a wrong minimum; its fitness is what lets callers reject it."""
    source, target = _load(DATA / "source.ply"), _load(DATA / "target.ply")
    truth = np.loadtxt(DATA / "T_target_source.txt")
    init = truth.copy()
    init[:3, 3] += [3.0, -2.0, 0.0]
    good = register_pair(source, target)
    bad = register_pair(source, target, init=init)
    trans_m, _ = _errors(bad.transform, truth)
    if trans_m > 0.1:
        assert bad.fitness < good.fitness


@pytest.mark.shared
def test_fast_gicp_pcd_pair(shared_dir: Path) -> None:
    """fast_gicp's pair is small_gicp's pair: the issue's bar holds against the better truth.

    The two PCDs hold exactly the points of small_gicp's source/target PLYs, but the two
    projects publish truths for them that differ by 1.9 cm and 0.22 degrees, more than the
    0.2 degree bar. Neither is a surveyed truth (fast_gicp's own test accepts 5 cm and 1 degree
    against its file). Fine registrations land near small_gicp's: point-to-plane here, and
    open3d's GICP or point-to-plane at 0.05-0.25 m voxels land 0.4-1.4 cm from it.
    """
    folder = shared_dir / "realdata" / "lidar" / "fast_gicp"
    pcds = sorted(folder.glob("*.pcd"))
    target, source = _load(pcds[0]), _load(pcds[1])
    same_target, same_source = _load(DATA / "target.ply"), _load(DATA / "source.ply")
    assert np.array_equal(np.sort(target, axis=0), np.sort(same_target, axis=0))
    assert np.array_equal(np.sort(source, axis=0), np.sort(same_source, axis=0))
    fast_truth = np.loadtxt(folder / "relative.txt")
    small_truth = np.loadtxt(DATA / "T_target_source.txt")
    truths_m, truths_deg = _errors(fast_truth, small_truth)
    assert truths_m > 0.019 and truths_deg > 0.2
    result = register_pair(source, target)
    trans_m, rot_deg = _errors(result.transform, small_truth)
    assert trans_m < 0.02
    assert rot_deg < 0.2
    # Against fast_gicp's own truth: no further off than the two truths are from each other.
    trans_m, rot_deg = _errors(result.transform, fast_truth)
    assert trans_m < 0.035
    assert rot_deg < 0.4
