"""A stair walk's climb registered several times and averaged (mfmap.mapping.climb)."""

from __future__ import annotations

import numpy as np
import pytest

from mfmap.mapping.climb import member_voxel, ramp_climb
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
