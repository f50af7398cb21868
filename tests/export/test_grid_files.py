"""Occupancy grids, PLY, TUM and floors.json writers on a synthetic building with known walls."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from mfmap.export.config import ExportConfig, GridConfig
from mfmap.export.files import read_ply, rotation_to_quat_xyzw, tum_text, write_ply
from mfmap.export.floorsjson import floors_json
from mfmap.export.grid import FREE, OCCUPIED, UNKNOWN, precision_recall, rasterise
from mfmap.export.mapdata import MapAccumulator
from tests.graph.synthetic import SyntheticBuilding, make_building, pose_xyyaw


@pytest.fixture(scope="module")
def building() -> SyntheticBuilding:
    return make_building((0, 1), seed=1)


def _wall_points(walls: np.ndarray, step_m: float = 0.01) -> np.ndarray:
    out = []
    for x0, y0, x1, y1 in walls:
        n = max(int(math.hypot(x1 - x0, y1 - y0) / step_m), 1)
        t = np.linspace(0.0, 1.0, n + 1)
        out.append(np.column_stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0)]))
    return np.concatenate(out)


def test_grid_matches_the_walls(building: SyntheticBuilding, tmp_path: Path) -> None:
    b = building
    maps = MapAccumulator(ExportConfig(grid=GridConfig(min_hits=1)), {0: 0.0, 1: 4.0})
    for kf in b.keyframes:
        maps.add(kf.floor_id, b.gt_poses[kf.id], kf.cloud, force_view=True)
    for floor in (0, 1):
        grid = maps.grid(floor)
        reference = rasterise(_wall_points(b.walls[floor]), grid.origin_xy, grid.shape, grid.resolution_m)
        # Walls the robot never saw cannot be in the grid: score against walls seen from a keyframe.
        precision, recall = precision_recall(grid.occupied, reference, tolerance_cells=1)
        assert precision >= 0.97, (floor, precision)
        assert recall >= 0.9, (floor, recall)
        # A cell in the middle of the corridor the robot drove along is free.
        free_cell = np.floor((np.array([9.0, 3.0]) - grid.origin_xy) / grid.resolution_m).astype(int)
        assert grid.free[free_cell[1], free_cell[0]]
        img = grid.image()
        assert set(np.unique(img).tolist()) == {OCCUPIED, FREE, UNKNOWN}
        # Image row 0 is the top (highest y): the wall y = 12 is near the top, y = 0 near the bottom.
        wall_top = int(np.floor((12.0 - grid.origin_xy[1]) / grid.resolution_m))
        assert img[grid.shape[0] - 1 - wall_top, img.shape[1] // 2] == OCCUPIED


def test_grid_yaml_and_pgm_load_as_nav2_expects(building: SyntheticBuilding, tmp_path: Path) -> None:
    b = building
    maps = MapAccumulator(ExportConfig(grid=GridConfig(resolution_m=0.1, min_hits=1)), {0: 0.0})
    for kf in b.keyframes:
        if kf.floor_id == 0:
            maps.add(0, b.gt_poses[kf.id], kf.cloud, force_view=True)
    grid = maps.grid(0)
    (tmp_path / "grid.pgm").write_bytes(grid.pgm_bytes())
    doc = grid.yaml_dict("grid.pgm")
    (tmp_path / "grid.yaml").write_text(yaml.safe_dump(doc))
    loaded = yaml.safe_load((tmp_path / "grid.yaml").read_text())
    assert set(loaded) == {"image", "mode", "resolution", "origin", "negate", "occupied_thresh", "free_thresh"}
    assert loaded["mode"] == "trinary" and loaded["negate"] == 0 and loaded["resolution"] == 0.1
    assert len(loaded["origin"]) == 3
    pgm = cv2.imread(str(tmp_path / loaded["image"]), cv2.IMREAD_UNCHANGED)
    assert pgm is not None
    assert pgm.shape == grid.shape and pgm.dtype == np.uint8
    assert (tmp_path / "grid.pgm").read_bytes()[:2] == b"P5"
    # The outer wall corner (0, 0) sits where the origin says it does.
    col, row = np.floor((np.zeros(2) - np.array(loaded["origin"][:2])) / 0.1).astype(int)
    assert (pgm[pgm.shape[0] - 1 - row - 1 : pgm.shape[0] - row + 1, col - 1 : col + 2] == 0).any()


def test_ply_roundtrip(tmp_path: Path) -> None:
    xyz = np.random.default_rng(0).normal(size=(1000, 3)).astype(np.float32)
    floor = np.repeat(np.arange(4, dtype=np.int32), 250)
    write_ply(tmp_path / "map.ply", xyz, floor)
    back = read_ply(tmp_path / "map.ply")
    assert np.array_equal(back["floor"], floor)
    assert np.array_equal(np.column_stack([back["x"], back["y"], back["z"]]), xyz)
    import open3d as o3d

    pcd = o3d.io.read_point_cloud(str(tmp_path / "map.ply"))  # type: ignore[arg-type]
    assert len(pcd.points) == 1000


def test_tum_quaternions_roundtrip() -> None:
    poses = np.stack([pose_xyyaw(1.0, 2.0, 3.0, yaw) for yaw in (0.0, 1.0, math.pi, -2.5)])
    text = tum_text(np.arange(4, dtype=np.int64) * 10**9 + 1_700_000_000 * 10**9, poses)
    rows = np.loadtxt(text.splitlines())
    assert rows.shape == (4, 8)
    assert rows[0, 0] == pytest.approx(1_700_000_000.0)
    for row, pose in zip(rows, poses, strict=True):
        qx, qy, qz, qw = row[4:]
        yaw = math.atan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))
        assert yaw == pytest.approx(math.atan2(pose[1, 0], pose[0, 0]), abs=1e-6)
    q = rotation_to_quat_xyzw(pose_xyyaw(0, 0, 0, math.pi)[:3, :3])
    assert np.allclose(np.abs(q), [0, 0, 1, 0])


def test_floors_json_has_transitions_and_connectors(building: SyntheticBuilding) -> None:
    b = building
    seg = b.segmentation
    stamps = np.array([k.stamp_ns for k in b.keyframes])
    xyz = np.array([b.gt_poses[k.id][:3, 3] for k in b.keyframes])
    doc = floors_json(seg, {0: 0.0, 1: 3.98}, stamps, xyz)
    assert [f["id"] for f in doc["floors"]] == [0, 1]
    assert doc["floors"][1]["elevation_m"] == pytest.approx(3.98)
    (tr,) = doc["transitions"]
    assert tr["kind"] == "elevator" and (tr["from"], tr["to"]) == (0, 1)
    assert tr["height_change_m"] == pytest.approx(3.98)
    assert (tr["x"], tr["y"]) == pytest.approx((17.0, 9.0), abs=0.01)  # the cabin
    (conn,) = doc["connectors"]
    assert conn["kind"] == "elevator" and conn["floors"] == [0, 1]
    assert doc["floors"][0]["connectors"] == [0] and doc["floors"][1]["connectors"] == [0]


def test_first_point_per_voxel_is_np_unique_s() -> None:
    from mfmap.export.mapdata import _first_per_cell, _voxel_keys

    rng = np.random.default_rng(3)
    for scale_m in (0.2, 8.0, 5000.0):  # the last one falls back to np.unique (too many bits)
        points = rng.normal(size=(20_000, 3)) * scale_m
        cells = np.floor(points / 0.05).astype(np.int64)
        expected = np.unique(_voxel_keys(points, 0.05), return_index=True)[1]
        assert np.array_equal(_first_per_cell(cells), expected), scale_m


def test_a_tilted_pose_does_not_lift_the_floor_into_the_band() -> None:
    # The floor 5-9 m around a robot whose estimated pose is pitched by 1.5 degrees (the robot
    # stands level: in its frame the floor is at z = 0).
    ang = np.linspace(-math.pi, math.pi, 720, endpoint=False)
    rng = np.repeat([5.0, 7.0, 9.0], 720)
    floor = np.column_stack([rng * np.cos(np.tile(ang, 3)), rng * np.sin(np.tile(ang, 3)), np.zeros(2160)])
    pitch = math.radians(1.5)
    c, s = math.cos(pitch), math.sin(pitch)
    pose = np.array([[c, 0.0, s, 0.0], [0.0, 1.0, 0.0, 0.0], [-s, 0.0, c, 0.0], [0.0, 0.0, 0.0, 1.0]])
    for level, expected in ((True, 0), (False, 1)):
        maps = MapAccumulator(ExportConfig(grid=GridConfig(min_hits=1, level_band=level)), {0: 0.0})
        maps.add(0, pose, floor, force_view=True)
        occupied = int(maps.grid(0).occupied.sum())
        assert (occupied > 50) == bool(expected), (level, occupied)
