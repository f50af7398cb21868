"""Depth-camera points in the floor maps: posing at a stamp, colours in the clouds, grid obstacles."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mfmap.export.camera import pose_at
from mfmap.export.config import CloudConfig, ExportConfig
from mfmap.export.files import ply_bytes, read_ply, write_ply
from mfmap.export.mapdata import MapAccumulator
from mfmap.export.write import FloorTrajectory


def _yaw_pose(x: float, yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.eye(4)
    out[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    out[0, 3] = x
    return out


def test_pose_at_interpolates_between_scans_of_one_floor() -> None:
    traj = FloorTrajectory(np.array([0, 100_000_000, 900_000_000, 1_000_000_000], dtype=np.int64),
                      np.stack([_yaw_pose(0.0, 0.0), _yaw_pose(1.0, 0.4), _yaw_pose(2.0, 0.0),
                                _yaw_pose(3.0, 0.0)]),
                      np.array([0, 0, 0, 1], dtype=np.int32))
    hit = pose_at(traj, 25_000_000, 500_000_000)
    assert hit is not None
    pose, floor = hit
    assert floor == 0
    np.testing.assert_allclose(pose[0, 3], 0.25, atol=1e-12)
    np.testing.assert_allclose(np.arctan2(pose[1, 0], pose[0, 0]), 0.1, atol=1e-12)  # slerp
    assert pose_at(traj, 500_000_000, 500_000_000) is None  # 0.8 s gap
    assert pose_at(traj, 950_000_000, 500_000_000) is None  # across a floor change
    assert pose_at(traj, 1_100_000_000, 500_000_000) is None  # after the trajectory
    exact = pose_at(traj, 900_000_000, 500_000_000)
    assert exact is not None and exact[0][0, 3] == 2.0


def test_camera_points_colour_the_cloud_and_mark_obstacles() -> None:
    cfg = ExportConfig(cloud=CloudConfig(voxel_m=0.05, min_range_m=0.0))
    maps = MapAccumulator(cfg, {0: 0.0})
    pose = np.eye(4)
    # A lidar scan: a wall at x = 3 (at z 0.3), and one point 2 m away from anything coloured.
    wall = np.column_stack([np.full(20, 3.02), np.linspace(-0.5, 0.5, 20), np.full(20, 0.32)])
    lonely = np.array([[0.02, 3.02, 0.32]])
    maps.add(0, pose, np.vstack([wall, lonely]))
    # Two images of a table top at 0.75 m (coloured red) and of the wall above the scan (blue).
    top = np.column_stack([np.full(30, 1.52), np.linspace(-0.3, 0.3, 30), np.full(30, 0.75)])
    wall_cam = np.column_stack([np.full(20, 3.02), np.linspace(-0.5, 0.5, 20), np.full(20, 0.32)])
    rgb = np.vstack([np.tile([200, 20, 20], (30, 1)), np.tile([20, 20, 200], (20, 1))]).astype(np.uint8)
    for _ in range(2):
        maps.add_camera(0, pose, np.vstack([top, wall_cam]), rgb, (0.1, 1.8))
    assert maps.images == 2 and maps.scans == 1
    cloud = maps.cloud(0)
    colours = maps.colours(0)
    assert colours is not None and colours.shape == cloud.shape
    on_top = np.abs(cloud[:, 2] - 0.75) < 0.01
    assert on_top.sum() >= 10 and np.all(colours[on_top] == [200, 20, 20])
    # The wall's voxels hold both a lidar and a camera point: the coloured one is kept.
    on_wall = np.abs(cloud[:, 0] - 3.02) < 0.01
    assert np.all(colours[on_wall] == [20, 20, 200])
    # A point no camera saw and no coloured point is near: mid grey, not a made-up colour.
    far = np.abs(cloud[:, 1] - 3.02) < 0.01
    assert far.sum() == 1 and np.all(colours[far] == 128)
    # The table top is an obstacle in the band (seen by two images: grid_min_hits 2).
    grid = maps.grids[0]
    occupied = grid.obstacle_xy(min_hits=2)
    assert np.any(np.hypot(occupied[:, 0] - 1.52, occupied[:, 1]) < 0.05)


def test_ply_colours_only_when_given(tmp_path: Path) -> None:
    xyz = np.array([[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]], dtype=np.float32)
    plain = ply_bytes(xyz, np.array([0, 1], dtype=np.int32))
    assert b"red" not in plain
    write_ply(tmp_path / "c.ply", xyz, np.array([0, 1], dtype=np.int32),
              np.array([[1, 2, 3], [250, 251, 252]], dtype=np.uint8))
    back = read_ply(tmp_path / "c.ply")
    assert back["red"].tolist() == [1, 250] and back["blue"].tolist() == [3, 252]
    assert back["floor"].tolist() == [0, 1]
    np.testing.assert_array_equal(back["z"], [2.0, 5.0])


def test_a_cloud_without_camera_keeps_its_layout() -> None:
    cfg = ExportConfig(cloud=CloudConfig(voxel_m=0.05, min_range_m=0.0))
    maps = MapAccumulator(cfg, {0: 0.0})
    maps.add(0, np.eye(4), np.array([[1.0, 0.0, 0.3], [1.01, 0.0, 0.3], [2.0, 0.0, 0.3]]))
    assert maps.colours(0) is None
    assert maps.cloud(0).shape == (2, 3)
