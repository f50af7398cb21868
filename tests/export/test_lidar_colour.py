"""Colour images paint the lidar's points: the occlusion test on a known scene, and a build of
a simulated 3D-lidar log with an RGB camera whose painted points carry their surfaces' paint."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from mfmap.export.lidar_colour import project_visible
from mfmap.ingest.depth import CameraModel
from tests.logcopy import copy_log

MODEL = CameraModel("cam", 80, 60, np.array([[40.0, 0, 39.5], [0, 40.0, 29.5], [0, 0, 1]]), np.zeros(5),
                    "plumb_bob")


def _grid(x0: float, x1: float, y0: float, y1: float, z: float, step: float) -> np.ndarray:
    xs, ys = np.meshgrid(np.arange(x0, x1, step), np.arange(y0, y1, step))
    return np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, z)])


def test_a_board_hides_the_wall_behind_it() -> None:
    """A wall 3 m ahead (blue) and a 0.6 m board 1.5 m ahead (red), both sampled at 5 cm as a
    map's voxels are: the board's points and the wall's around it are painted, the wall's
    behind the board are not (nor would they be red)."""
    wall = _grid(-2.0, 2.0, -1.5, 1.5, 3.0, 0.05)
    board = _grid(-0.3, 0.3, -0.3, 0.3, 1.5, 0.05)
    points = np.vstack([wall, board])
    image = np.zeros((60, 80, 3), dtype=np.uint8)
    image[:, :] = (0, 0, 255)
    # The board covers |u - cx| <= 40 * 0.3 / 1.5 = 8 px around the centre.
    image[22:38, 32:48] = (255, 0, 0)
    idx, colours, z = project_visible(points, np.eye(4), MODEL, image, 4.0, 0.05)
    seen = np.zeros(len(points), dtype=bool)
    seen[idx] = True
    on_board = np.arange(len(points)) >= len(wall)
    behind = ~on_board & (np.abs(points[:, 0]) < 0.25) & (np.abs(points[:, 1]) < 0.25)
    clear = ~on_board & ((np.abs(points[:, 0]) > 0.8) | (np.abs(points[:, 1]) > 0.8))
    in_view = (np.abs(points[:, 0] / points[:, 2] * 40) < 39) & (np.abs(points[:, 1] / points[:, 2] * 40) < 29)
    assert seen[on_board].all()
    assert not seen[behind].any()
    assert seen[clear & in_view].mean() > 0.99
    red = np.all(colours == (255, 0, 0), axis=1)
    # Every painted point but a board's edge (a pixel's rounding) takes its own surface's colour.
    assert np.mean(red == on_board[idx]) > 0.97
    np.testing.assert_allclose(z, points[idx, 2])


def painted_figures(ply: dict[str, Any], seed: int = 0) -> dict[str, float]:
    """Share of points painted (not grey) and, of those, the share within 40 levels (every
    channel) of the paint of the true surface nearest to them."""
    import open3d as o3d

    from mfmap.sim.boxes import make_scene
    from mfmap.sim.camera import box_colours
    from mfmap.sim.scenarios import SCENARIOS, building_for

    building = building_for(SCENARIOS["tiny-rgbd"], seed)
    boxes = building.static_boxes() + [building.landing_door(k) for k in range(building.n_floors)]
    xyz = np.column_stack([ply["x"], ply["y"], ply["z"]]).astype(np.float32)
    tensor: Any = o3d.core.Tensor
    ans = make_scene(boxes).compute_closest_points(tensor(xyz))
    paint = box_colours(boxes)[ans["primitive_ids"].numpy() // 12].astype(int)
    rgb = np.column_stack([ply["red"], ply["green"], ply["blue"]]).astype(int)
    grey = np.all(rgb == 128, axis=1)
    err = np.abs(rgb - paint).max(axis=1)
    return {"painted": float(np.mean(~grey)), "within_40": float(np.mean(err[~grey] <= 40))}


def test_lidar_points_carry_their_surfaces_colours(sim_run: Callable[..., Path], tmp_path: Path) -> None:
    """tiny-rgbd without its depth topics: a 3D lidar and a jpeg colour camera with its
    CameraInfo and /tf_static. The lidar's points near the robot's path take the camera's
    colours, and those colours are their surfaces' paint."""
    from mfmap.export.files import read_ply

    log = tmp_path / "log.mcap"
    copy_log(sim_run("tiny-rgbd") / "log.mcap", log, set(), drop_prefix="/camera/depth/")
    from mfmap.ingest.camera_info import describe_cameras

    rows, skipped = describe_cameras(log)
    assert [(r["topic"], r["used"]) for r in rows] == [("/camera/rgb/image_raw/compressed", "paints the lidar")]
    assert skipped == []
    out = tmp_path / "out"
    res = subprocess.run([sys.executable, "-m", "mfmap.cli", "build", str(log), "-o", str(out)],
                         capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, res.stderr
    ply = read_ply(out / "map.ply")
    assert "red" in ply
    figures = painted_figures(ply)
    assert figures["painted"] > 0.25, figures
    assert figures["within_40"] > 0.93, figures
    floor_ply = read_ply(out / "floors" / "0" / "cloud.ply")
    assert "red" in floor_ply and len(floor_ply["x"]) < len(ply["x"])
