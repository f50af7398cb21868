"""Occupied cells of a built folder's grids against a grid rendered from the ground-truth cloud.

One scoring for the tests and the benchmark: per floor, ground-truth points in the grid's height
band above the floor are rasterised on the exported grid's cells. Precision: occupied cells
within `tolerance_cells` of a ground-truth cell. Recall: ground-truth wall cells the robot could
see that have an occupied cell within `tolerance_cells`. "Could see" is, given the ground-truth
trajectory, the cells a 2D ray cast on the rasterised band reaches first from the true positions
of the floor's visits (the far face of a wall and rooms never entered cannot be in any map); it
does not depend on the build, so a map that sees more is not scored against more. Without the
trajectory (fallback) it is the cells within two cells of the build's own free space.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mfmap.errors import GroundTruthError, OutputError
from mfmap.export.grid import FREE, OCCUPIED, UNKNOWN, precision_recall, rasterise

if TYPE_CHECKING:
    from mfmap.eval.io import TumTrajectory

GRID_KEYS = frozenset({"image", "mode", "resolution", "origin", "negate", "occupied_thresh", "free_thresh"})


@dataclass(frozen=True)
class GridScore:
    floor_id: int
    precision: float
    recall: float
    occupied_cells: int
    reference_cells: int


@dataclass(frozen=True)
class LoadedGrid:
    occupied: np.ndarray  # bool (H, W), row 0 = lowest y
    free: np.ndarray
    origin_xy: np.ndarray
    resolution_m: float
    meta: dict[str, object]


def load_grid(folder: Path) -> LoadedGrid:
    """floors/<id>/grid.yaml and its image, rows flipped so row 0 is the lowest y."""
    import cv2
    import yaml

    meta = yaml.safe_load((folder / "grid.yaml").read_text())
    if not isinstance(meta, dict) or not set(meta) >= GRID_KEYS:
        raise OutputError("grid.yaml lacks nav2 map_server keys", folder / "grid.yaml")
    raw = cv2.imread(str(folder / str(meta["image"])), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise OutputError("cannot read the grid image", folder / str(meta["image"]))
    img = raw[::-1]
    if not set(np.unique(img).tolist()) <= {OCCUPIED, FREE, UNKNOWN}:
        raise OutputError("grid image is not trinary", folder / str(meta["image"]))
    return LoadedGrid(img == OCCUPIED, img == FREE, np.array(meta["origin"][:2], dtype=np.float64),
                      float(meta["resolution"]), meta)


def path_viewpoints(xy: np.ndarray, spacing_m: float = 0.25) -> np.ndarray:
    """Positions along a path (N, 2) kept after every `spacing_m` of travel (the first always)."""
    if xy.shape[0] == 0:
        return xy.reshape(0, 2)
    travelled = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))))
    _, first = np.unique(np.floor(travelled / spacing_m), return_index=True)
    return xy[first]


def visible_cells(
    reference: np.ndarray,
    viewpoints_cells: np.ndarray,
    max_range_cells: float,
    ray_step_deg: float = 0.1,
    min_step_cells: float = 0.5,
    batch_rays: int = 500_000,
) -> np.ndarray:
    """Cells of `reference` (bool, rows = y) that a ray from a viewpoint meets first.

    Viewpoints are (x, y) in cell units (cell (r, c) spans x in [c, c + 1), y in [r, r + 1)).
    A ray every `ray_step_deg` walks out to `max_range_cells`; the first reference cell it lands
    in is visible and ends it. Steps are `min_step_cells` (half a cell cannot step over a wall one
    cell thick along x or y) or longer where the distance transform says no reference cell is
    near: the step leaves sqrt(2) cells to spare (cell centre to any point of either cell), so a
    long step never jumps a cell that short steps would have landed in.
    """
    import cv2

    height, width = reference.shape
    visible = np.zeros_like(reference, dtype=bool)
    if viewpoints_cells.shape[0] == 0 or not reference.any():
        return visible
    clearance = cv2.distanceTransform((~reference).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    step = np.maximum(clearance - math.sqrt(2.0), min_step_cells)
    n_rays = max(1, round(360.0 / ray_step_deg))
    angles = (np.arange(n_rays) + 0.5) * (2 * math.pi / n_rays)
    dirs = np.column_stack([np.cos(angles), np.sin(angles)])
    per_pass = max(1, batch_rays // n_rays)
    for b in range(0, viewpoints_cells.shape[0], per_pass):
        origins = np.repeat(np.asarray(viewpoints_cells[b : b + per_pass], dtype=np.float64), n_rays, axis=0)
        ray_dirs = np.tile(dirs, (origins.shape[0] // n_rays, 1))
        # A ray leaves the grid for good at this distance (slab test; fmin skips 0/0).
        with np.errstate(divide="ignore", invalid="ignore"):
            exit_x = np.where(ray_dirs[:, 0] > 0, width - origins[:, 0], -origins[:, 0]) / ray_dirs[:, 0]
            exit_y = np.where(ray_dirs[:, 1] > 0, height - origins[:, 1], -origins[:, 1]) / ray_dirs[:, 1]
        last = np.fmin(np.fmin(exit_x, exit_y), max_range_cells)
        t = np.full(origins.shape[0], min_step_cells)
        active = np.flatnonzero(t <= last)
        while active.size:
            pos = origins[active] + ray_dirs[active] * t[active, None]
            cols = np.floor(pos[:, 0]).astype(np.int64)
            rows = np.floor(pos[:, 1]).astype(np.int64)
            inside = (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height)
            hit = np.zeros(active.shape, dtype=bool)
            hit[inside] = reference[rows[inside], cols[inside]]
            visible[rows[hit], cols[hit]] = True
            advance = np.full(active.shape, min_step_cells)
            advance[inside] = step[rows[inside], cols[inside]]
            t[active] += advance
            active = active[~hit & (t[active] <= last[active])]
    return visible


def score_grid(
    grid: LoadedGrid,
    gt_xyz: np.ndarray,
    elevation_m: float,
    band_m: tuple[float, float] = (0.1, 1.8),
    tolerance_cells: int = 2,
    viewpoints_xy: np.ndarray | None = None,
    max_range_m: float = 30.0,
) -> tuple[float, float, int, int]:
    """(precision, recall, occupied cells, scored reference cells) of one floor's grid.

    With `viewpoints_xy` (true positions, world x, y) recall counts the band cells visible from
    them within `max_range_m`; without, the band cells within two cells of the grid's free space.
    """
    import cv2

    z = gt_xyz[:, 2]
    band = (z >= elevation_m + band_m[0]) & (z <= elevation_m + band_m[1])
    reference = rasterise(gt_xyz[band, :2], grid.origin_xy, grid.occupied.shape, grid.resolution_m)
    if viewpoints_xy is not None:
        seen = visible_cells(reference, (viewpoints_xy - grid.origin_xy) / grid.resolution_m,
                             max_range_m / grid.resolution_m)
    else:
        seen = cv2.dilate(grid.free.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    precision, _ = precision_recall(grid.occupied, reference, tolerance_cells)
    _, recall = precision_recall(grid.occupied, reference & seen, tolerance_cells)
    return precision, recall, int(grid.occupied.sum()), int((reference & seen).sum())


def score_build(
    out: Path,
    gt_cloud: Path,
    gt_floors: Path,
    tolerance_cells: int = 2,
    gt_trajectory: Path | None = None,
    viewpoint_spacing_m: float = 0.25,
    shaft_radius_m: float = 1.35,
) -> list[GridScore]:
    """Score every floor grid of the build folder `out` (floors matched in order of elevation).

    With `gt_trajectory` (TUM) recall is against the walls visible from the true path of each
    floor's visits (gt_floors.json floors[].visits, seconds), up to the build's grid range.
    Positions within `shaft_radius_m` (the sim's shaft outer half-size) of an elevator ride's x, y
    are no viewpoints: the ground-truth cloud has no cabin, so rays from inside it or from its
    doorway would reach the shaft walls the cabin hides.
    """
    from mfmap.eval.io import read_tum
    from mfmap.export.files import read_ply

    cloud = read_ply(gt_cloud)
    gt_xyz = np.column_stack([cloud["x"], cloud["y"], cloud["z"]]).astype(np.float64)
    floors = json.loads((out / "floors.json").read_text())["floors"]
    truth_file = json.loads(gt_floors.read_text())
    truth = truth_file["floors"]
    if len(floors) != len(truth):
        raise GroundTruthError(f"{len(floors)} floors built, {len(truth)} in the ground truth", out / "floors.json")
    path = read_tum(gt_trajectory) if gt_trajectory is not None else None
    max_range_m = _grid_max_range_m(out)
    scores = []
    for est, gt in zip(sorted(floors, key=lambda f: f["elevation_m"]),
                       sorted(truth, key=lambda f: f["elevation_m"]), strict=True):
        grid = load_grid(out / "floors" / str(est["id"]))
        viewpoints = None
        if path is not None:
            if not gt.get("visits"):
                raise GroundTruthError(f"floor {gt.get('id')} has no visits", gt_floors)
            viewpoints = floor_viewpoints(path, gt, truth_file.get("transitions", []), viewpoint_spacing_m,
                                          shaft_radius_m)
            if viewpoints.shape[0] == 0:
                raise GroundTruthError(f"no true position during the visits of floor {gt.get('id')}",
                                       gt_trajectory)
        p, r, n_occ, n_ref = score_grid(grid, gt_xyz, float(gt["elevation_m"]), tolerance_cells=tolerance_cells,
                                        viewpoints_xy=viewpoints, max_range_m=max_range_m)
        scores.append(GridScore(int(est["id"]), p, r, n_occ, n_ref))
    return scores


def floor_viewpoints(
    path: TumTrajectory,
    floor: dict[str, Any],
    transitions: list[dict[str, Any]],
    spacing_m: float = 0.25,
    shaft_radius_m: float = 1.35,
) -> np.ndarray:
    """True x, y every `spacing_m` along a gt_floors.json floor's visits, none in an elevator shaft."""
    viewpoints = np.concatenate([np.zeros((0, 2))] + [
        path_viewpoints(path.xyz[(path.stamps_s >= t0) & (path.stamps_s <= t1), :2], spacing_m)
        for t0, t1 in floor.get("visits", [])
    ])
    for ride in transitions:
        if ride.get("kind") == "elevator" and "x" in ride and floor.get("id") in (ride.get("from"), ride.get("to")):
            far = np.hypot(viewpoints[:, 0] - ride["x"], viewpoints[:, 1] - ride["y"]) > shaft_radius_m
            viewpoints = viewpoints[far]
    return viewpoints


def _grid_max_range_m(out: Path) -> float:
    """The build's free-space ray range (its config.yaml), else the default."""
    import yaml

    from mfmap.export.config import GridConfig

    default = float(GridConfig.model_fields["max_range_m"].default)
    config = out / "config.yaml"
    if not config.is_file():
        return default
    export = (yaml.safe_load(config.read_text()) or {}).get("export") or {}
    # A map built before the keys were grouped in sections has the flat key.
    grid = export.get("grid") or {}
    return float(grid.get("max_range_m", export.get("grid_max_range_m", default)))
