"""Occupied cells of a built folder's grids against a grid rendered from the ground-truth cloud.

One scoring for the tests and the benchmark: per floor, ground-truth points in the grid's height
band above the floor are rasterised on the exported grid's cells. Precision: occupied cells
within `tolerance_cells` of a ground-truth cell. Recall: ground-truth wall cells the robot could
see (within two cells of free space; the far face of a wall and rooms never entered cannot be in
any map) that have an occupied cell within `tolerance_cells`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mfmap.errors import GroundTruthError, OutputError
from mfmap.export.grid import FREE, OCCUPIED, UNKNOWN, precision_recall, rasterise

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


def score_grid(
    grid: LoadedGrid,
    gt_xyz: np.ndarray,
    elevation_m: float,
    band_m: tuple[float, float] = (0.1, 1.8),
    tolerance_cells: int = 2,
) -> tuple[float, float, int, int]:
    """(precision, recall, occupied cells, scored reference cells) of one floor's grid."""
    import cv2

    z = gt_xyz[:, 2]
    band = (z >= elevation_m + band_m[0]) & (z <= elevation_m + band_m[1])
    reference = rasterise(gt_xyz[band, :2], grid.origin_xy, grid.occupied.shape, grid.resolution_m)
    seen = cv2.dilate(grid.free.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    precision, _ = precision_recall(grid.occupied, reference, tolerance_cells)
    _, recall = precision_recall(grid.occupied, reference & seen, tolerance_cells)
    return precision, recall, int(grid.occupied.sum()), int((reference & seen).sum())


def score_build(out: Path, gt_cloud: Path, gt_floors: Path, tolerance_cells: int = 2) -> list[GridScore]:
    """Score every floor grid of the build folder `out` (floors matched in order of elevation)."""
    from mfmap.export.files import read_ply

    cloud = read_ply(gt_cloud)
    gt_xyz = np.column_stack([cloud["x"], cloud["y"], cloud["z"]]).astype(np.float64)
    floors = json.loads((out / "floors.json").read_text())["floors"]
    truth = json.loads(gt_floors.read_text())["floors"]
    if len(floors) != len(truth):
        raise GroundTruthError(f"{len(floors)} floors built, {len(truth)} in the ground truth", out / "floors.json")
    scores = []
    for est, gt in zip(sorted(floors, key=lambda f: f["elevation_m"]),
                       sorted(truth, key=lambda f: f["elevation_m"]), strict=True):
        grid = load_grid(out / "floors" / str(est["id"]))
        p, r, n_occ, n_ref = score_grid(grid, gt_xyz, float(gt["elevation_m"]), tolerance_cells=tolerance_cells)
        scores.append(GridScore(int(est["id"]), p, r, n_occ, n_ref))
    return scores
