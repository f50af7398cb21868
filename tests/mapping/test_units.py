"""Small exact checks of the mapping stage's geometry helpers."""

from __future__ import annotations

import numpy as np
import pytest

from mfmap.mapping.cabin import through_box
from mfmap.mapping.geometry import deskew, yaw_pose
from mfmap.mapping.loops import descriptor_distance, place_descriptor
from mfmap.mapping.posegraph import optimize_poses
from mfmap.types import PoseEdge


def test_through_box_drops_cabin_returns_and_what_is_behind_its_walls() -> None:
    cabin = yaw_pose(0.0, np.array([3.0, 0.0, 0.0]))
    points = np.array([
        [3.0, 0.0, 0.5],   # inside the cabin
        [5.0, 0.0, 0.5],   # behind it (a mirror ghost / too-long range)
        [1.0, 0.0, 0.5],   # in front of it
        [5.0, 3.0, 0.5],   # beside it, ray passes clear
        [3.0, 2.0, 0.5],   # beside it
    ])
    mask = through_box(points, np.zeros(3), cabin, (1.0, 1.0))
    assert mask.tolist() == [True, True, False, False, False]
    # From inside the cabin every ray starts in it.
    assert through_box(points, np.array([3.0, 0.0, 0.0]), cabin, (1.0, 1.0)).all()


def test_deskew_undoes_a_constant_turn() -> None:
    # A wall point seen at t = 0.1 s by a sensor turning at 1 rad/s: expressed at t = 0 it is
    # the same point rotated by 0.1 rad.
    point = np.array([[2.0, 0.0, 0.0]])
    out = deskew(point, np.array([0.1]), np.array([0.0, 0.0, 1.0]), np.zeros(3))
    assert out[0] == pytest.approx([2.0 * np.cos(0.1), 2.0 * np.sin(0.1), 0.0])


def test_descriptor_finds_the_yaw_between_two_views() -> None:
    rng = np.random.default_rng(0)
    cloud = np.c_[rng.uniform(-10, 10, (4000, 2)), rng.uniform(0.3, 2.0, 4000)]
    cloud = cloud[np.hypot(cloud[:, 0], cloud[:, 1]) > 2 + 3 * (cloud[:, 0] > 0)]
    yaw = np.radians(60.0)
    rotated = cloud @ yaw_pose(-yaw)[:3, :3].T  # the same place seen with the robot yawed by 60
    dist, shift = descriptor_distance(place_descriptor(cloud), place_descriptor(rotated))
    assert dist < 0.05
    assert shift * 6.0 == pytest.approx(60.0, abs=6.0)


def test_pose_graph_spreads_a_loop_correction() -> None:
    # Four 1 m steps along x whose odometry says 1.02 m; a loop from 0 to 4 says 4.00 m.
    poses = {k: yaw_pose(0.0, np.array([1.02 * k, 0.0, 0.0])) for k in range(5)}
    info = np.diag([1e4] * 3 + [1e4] * 3)
    edges = [PoseEdge(k, k + 1, yaw_pose(0.0, np.array([1.02, 0.0, 0.0])), info, "odometry")
             for k in range(4)]
    edges.append(PoseEdge(0, 4, yaw_pose(0.0, np.array([4.0, 0.0, 0.0])), info * 100, "loop"))
    out = optimize_poses(poses, edges, anchor=0)
    assert out[4][0, 3] == pytest.approx(4.0, abs=0.005)
    assert out[2][0, 3] == pytest.approx(2.0, abs=0.01)
