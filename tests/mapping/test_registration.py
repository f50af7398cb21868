"""Registration core on real lidar scans (koide3/small_gicp test data, MIT)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d
import pytest

from mfmap.mapping.geometry import inverse, rotation_angle_rad
from mfmap.mapping.registration import register_pair

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
