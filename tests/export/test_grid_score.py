"""The build-independent recall reference: ray casting on a hand-made raster, and its recall."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from mfmap.errors import GroundTruthError
from mfmap.eval.grids import LoadedGrid, floor_viewpoints, score_build, score_grid, visible_cells
from mfmap.eval.io import TumTrajectory, write_ply
from mfmap.export.grid import OccupancyGrid

SIZE = 40  # cells; rows = y, cols = x
VIEW = np.array([[10.5, 20.5]])  # cell units: the middle of the left room


def two_rooms(gap_row: int | None = None) -> np.ndarray:
    """A 40 x 40 room, walls one cell thick, split by an inner wall two cells thick (cols 20, 21)."""
    ref = np.zeros((SIZE, SIZE), dtype=bool)
    ref[0, :] = ref[-1, :] = ref[:, 0] = ref[:, -1] = True
    ref[:, 20:22] = True
    if gap_row is not None:
        ref[gap_row, 20:22] = False
    return ref


def test_near_faces_are_visible_the_far_face_and_the_room_behind_are_not() -> None:
    vis = visible_cells(two_rooms(), VIEW, max_range_cells=100)
    inner = slice(1, SIZE - 1)
    assert vis[inner, 0].sum() == 38  # left wall, every cell between the corners
    assert vis[inner, 20].sum() == 38  # near face of the inner wall
    assert vis[0, 1:20].sum() == 19 and vis[-1, 1:20].sum() == 19  # bottom and top, left room
    assert vis[:, 21].sum() == 0  # far face of the inner wall
    assert vis[:, 22:].sum() == 0  # the room behind it
    # A sampled ray may land in a room's concave corner cell (a point in continuous geometry).
    corners = int(vis[0, 0]) + int(vis[0, 20]) + int(vis[-1, 0]) + int(vis[-1, 20])
    assert vis.sum() == 38 + 38 + 19 + 19 + corners


def test_a_ray_through_a_one_cell_gap_reaches_the_wall_behind() -> None:
    vis = visible_cells(two_rooms(gap_row=20), VIEW, max_range_cells=100)
    # Through y in [20, 21) at x = 20..22 from (10.5, 20.5): |angle| < 2.5 deg, so the right wall
    # (x 39, 28.5 cells away) is met within 1.24 cells of y = 20.5: rows 19, 20, 21.
    assert np.flatnonzero(vis[:, 39]).tolist() == [19, 20, 21]
    assert vis[:, 22:39].sum() == 0 and vis[0, 22:].sum() == 0 and vis[-1, 22:].sum() == 0
    # Of the inner wall's far face only the gap's jambs are met (from inside the gap).
    assert np.flatnonzero(vis[:, 21]).tolist() == [19, 21]


def test_range_limit() -> None:
    ref = np.zeros((10, 100), dtype=bool)
    ref[:, 60] = True  # a wall whose near side is 59.5 cells from the viewpoint
    view = np.array([[0.5, 5.5]])
    assert visible_cells(ref, view, max_range_cells=59).sum() == 0
    far = visible_cells(ref, view, max_range_cells=70)  # every cell of it is within 60.3 cells
    assert far.sum() == 10 and far[:, 60].all()


def test_recall_against_the_visible_walls() -> None:
    res_m = 0.05
    origin = np.array([-1.0, 2.0])
    ref = two_rooms()
    rows, cols = np.nonzero(ref)
    # The ground-truth cloud: cell centres, 1 m above a floor at 3.5 m (inside the band).
    gt_xyz = np.column_stack([origin[0] + (cols + 0.5) * res_m, origin[1] + (rows + 0.5) * res_m,
                              np.full(rows.size, 4.5)])
    views_xy = origin + VIEW * res_m
    vis = visible_cells(ref, VIEW, max_range_cells=30.0 / res_m)
    n_ref = int(vis.sum())

    def score(occupied: np.ndarray, tol: int) -> tuple[float, float, int, int]:
        grid = LoadedGrid(occupied, np.zeros_like(occupied), origin, res_m, {})
        return score_grid(grid, gt_xyz, 3.5, tolerance_cells=tol, viewpoints_xy=views_xy)

    assert score(vis, 0) == (1.0, 1.0, n_ref, n_ref)
    no_left = vis.copy()
    no_left[1:-1, 0] = False  # the left wall's 38 cells
    p, r, _, _ = score(no_left, 0)
    assert p == 1.0 and r == (n_ref - 38) / n_ref
    # Within one cell the wall's end cells still touch the bottom and top walls' visible cells.
    _, r, _, _ = score(no_left, 1)
    assert r == (n_ref - 36) / n_ref
    # The far face and the room behind are no reference cells: mapping them scores the same.
    assert score(ref, 0) == (1.0, 1.0, int(ref.sum()), n_ref)


def test_viewpoints_follow_the_visits_and_skip_the_shaft() -> None:
    x_m = 0.125 * np.arange(41)  # 0 .. 5 m, exact in binary
    stamps_s = 0.1 * np.arange(41, dtype=np.float64)
    xyz = np.column_stack([x_m, np.zeros(41), np.zeros(41)]).astype(np.float64)
    path = TumTrajectory(stamps_s, xyz, np.tile(np.array([0.0, 0.0, 0.0, 1.0]), (41, 1)))
    floor = {"id": 0, "visits": [[0.0, 2.0]]}  # stamps 0 .. 2 s: x 0 .. 2.5 m
    assert floor_viewpoints(path, floor, [], spacing_m=0.25)[:, 0].tolist() == [0.25 * i for i in range(11)]
    ride = {"kind": "elevator", "from": 0, "to": 1, "x": 0.0, "y": 0.0}
    kept = floor_viewpoints(path, floor, [ride], spacing_m=0.25, shaft_radius_m=1.35)
    assert kept[:, 0].tolist() == [1.5, 1.75, 2.0, 2.25, 2.5]
    other = floor_viewpoints(path, floor, [{**ride, "from": 1, "to": 2}], spacing_m=0.25)
    assert other.shape == (11, 2)


def test_score_build_uses_the_true_path_of_the_floor_visits(tmp_path: Path) -> None:
    res_m, origin = 0.05, np.array([-1.0, 2.0])
    ref = two_rooms()
    vis = visible_cells(ref, VIEW, max_range_cells=30.0 / res_m)
    free = np.zeros_like(ref)
    free[1:-1, 1:20] = True  # the build saw the left room
    out = tmp_path / "out"
    (out / "floors" / "0").mkdir(parents=True)
    grid = OccupancyGrid(vis, free, origin, res_m)
    (out / "floors" / "0" / "grid.pgm").write_bytes(grid.pgm_bytes())
    (out / "floors" / "0" / "grid.yaml").write_text(yaml.safe_dump(grid.yaml_dict()))
    (out / "floors.json").write_text(json.dumps({"floors": [{"id": 0, "elevation_m": 3.4}]}))
    rows, cols = np.nonzero(ref)
    cloud = tmp_path / "gt_cloud.ply"
    write_ply(cloud, np.column_stack([origin[0] + (cols + 0.5) * res_m, origin[1] + (rows + 0.5) * res_m,
                                      np.full(rows.size, 4.5)]))
    # Standing in the left room during the visit, then in the right room after it.
    view_xy = origin + VIEW[0] * res_m
    right_xy = origin + np.array([30.5, 20.5]) * res_m
    poses = [(100.0 + i, *view_xy) for i in range(11)] + [(200.0, *right_xy)]
    traj = tmp_path / "gt_trajectory.tum"
    traj.write_text("".join(f"{t} {x} {y} 3.5 0 0 0 1\n" for t, x, y in poses))
    floors = tmp_path / "gt_floors.json"
    floors.write_text(json.dumps({"floors": [{"id": 0, "elevation_m": 3.5, "visits": [[100.0, 110.0]]}]}))

    (s,) = score_build(out, cloud, floors, tolerance_cells=0, gt_trajectory=traj)
    assert (s.precision, s.recall, s.reference_cells) == (1.0, 1.0, int(vis.sum()))
    # Fallback without the path: band cells within two cells of the build's free space, which
    # takes in the inner wall's far face: 22 + 22 (bottom, top: cols 0..21) + 38 + 2 * 38 = 158.
    (s,) = score_build(out, cloud, floors, tolerance_cells=0)
    assert (s.reference_cells, s.recall) == (158, vis.sum() / 158)
    floors.write_text(json.dumps({"floors": [{"id": 0, "elevation_m": 3.5, "visits": [[300.0, 310.0]]}]}))
    with pytest.raises(GroundTruthError, match="no true position"):
        score_build(out, cloud, floors, gt_trajectory=traj)
