"""A stair walk's climb registered several times, the median taken (mfmap.mapping.climb)."""

from __future__ import annotations

import numpy as np
import pytest

from mfmap.mapping.climb import median_change, member_voxel, ramp_climb
from mfmap.types import Keyframe, ScanPose


def test_members_downsample_alternately_coarser_and_finer() -> None:
    voxels = [member_voxel(0.25, 0.05, i) for i in range(1, 5)]
    assert voxels == pytest.approx([0.2625, 0.2375, 0.275, 0.225])


def _pose(x: float, z: float) -> np.ndarray:
    pose = np.eye(4)
    pose[0, 3], pose[2, 3] = x, z
    return pose


def test_the_walks_scans_take_the_change_in_step_with_their_climb() -> None:
    before = Keyframe(id=3, stamp_ns=0, floor_id=0, visit=0, pose=_pose(1.0, 0.5),
                      cloud=np.zeros((0, 3), np.float32), fitness=1.0, rmse_m=0.0)
    other = ScanPose(-5, 2, np.eye(4))  # hangs on another keyframe: left alone
    # On the floor before the fork, then up 2 m, a landing, up 1 m more.
    heights = [0.5, 0.5, 1.5, 2.5, 2.5, 3.5]
    scans = [other] + [ScanPose(10 * (k + 1), 3, np.linalg.inv(before.pose) @ _pose(1.0 + k, z))
                       for k, z in enumerate(heights)]
    ramp_climb(scans, before, start_ns=20, start_z=0.5, climb_m=3.0, dz=0.03)
    world = [(before.pose @ sp.relative)[2, 3] for sp in scans[1:]]
    assert world == pytest.approx([0.5, 0.5, 1.51, 2.52, 2.52, 3.53])
    assert [(before.pose @ sp.relative)[0, 3] for sp in scans[1:]] == pytest.approx(
        [1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    assert scans[0] is other


def test_one_registration_far_off_does_not_move_the_climb() -> None:
    # gen-stairs-s3's walk 0 -> 2: the odometry and one copy within a centimetre, the other
    # copy 8.5 cm lower; the mean would drop the floor reached by 3.5 cm, the median by 1.
    assert median_change([6.0844, 6.0742, 5.9897]) == pytest.approx(-0.0102, abs=1e-9)
    # Two registrations: their mean.
    assert median_change([3.50, 3.48]) == pytest.approx(-0.01, abs=1e-9)
    assert median_change([3.5]) == 0.0
