"""2D occupancy grids per floor, in the nav2 map_server trinary format.

Obstacles are the points in a height band above the floor; free space is what the sensor saw
through: for each scan (or keyframe) the nearest obstacle per bearing bounds a visibility polygon
that is filled as free. Occupied wins over free; the rest is unknown.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from mfmap.errors import MissingDataError
from mfmap.export.config import GRID_BYTES_PER_CELL
from mfmap.types import F64

OCCUPIED = 0
FREE = 254
UNKNOWN = 205
_SHIFT = 2  # sub-cell precision of cv2.fillPoly vertices (1/4 cell)
_KEY_OFFSET = 1 << 30  # cell index offset and span for packing (x, y) cells into one int64
_KEY_SPAN = 1 << 31


@dataclass
class GridBuilder:
    """Collects obstacle points and visibility polygons of one floor, then rasterises."""

    resolution_m: float = 0.05
    n_bearings: int = 1440
    max_range_m: float = 30.0
    window_bins: int = 2  # each bearing is bounded by the nearest return within this many bins
    max_bytes: float = 2048e6  # the grid's memory while it is drawn (`ExportConfig.grid.max_mb`)
    polygons: list[np.ndarray] = field(default_factory=list)  # (M, 2) float32 world xy

    cell_keys: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    cell_hits: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    pending: list[np.ndarray] = field(default_factory=list)
    pending_count: int = 0

    def add_obstacles(self, band_xy: np.ndarray) -> None:
        """One scan's obstacle points (world x, y): each cell it hits counts one hit."""
        if band_xy.shape[0] == 0:
            return
        cells = np.floor(np.asarray(band_xy, dtype=np.float64) / self.resolution_m).astype(np.int64)
        keys = np.sort((cells[:, 0] + _KEY_OFFSET) * _KEY_SPAN + (cells[:, 1] + _KEY_OFFSET))
        keys = keys[np.concatenate(([True], keys[1:] != keys[:-1]))]  # (np.unique hashes: slower)
        self.pending.append(keys)
        self.pending_count += keys.shape[0]
        if self.pending_count > 2_000_000:
            self._merge()

    def _merge(self) -> None:
        if not self.pending:
            return
        keys = np.concatenate([self.cell_keys, *self.pending])
        hits = np.concatenate([self.cell_hits, *[np.ones(len(p), dtype=np.int64) for p in self.pending]])
        self.cell_keys, inverse = np.unique(keys, return_inverse=True)
        self.cell_hits = np.bincount(inverse, weights=hits).astype(np.int64)
        self.pending = []
        self.pending_count = 0

    def obstacle_xy(self, min_hits: int = 1) -> np.ndarray:
        """Centres of the cells hit by at least `min_hits` scans."""
        self._merge()
        keys = self.cell_keys[self.cell_hits >= min_hits]
        cx = keys // _KEY_SPAN - _KEY_OFFSET
        cy = keys % _KEY_SPAN - _KEY_OFFSET
        return (np.column_stack([cx, cy]).astype(np.float64) + 0.5) * self.resolution_m

    def add_view(self, origin_xy: np.ndarray, band_xy: np.ndarray) -> None:
        """One sensor view: origin and the band's hit points, both in world x, y."""
        if band_xy.shape[0] == 0:
            return
        pts = np.asarray(band_xy, dtype=np.float64)
        self.add_obstacles(pts)
        d = pts - origin_xy
        rng = np.hypot(d[:, 0], d[:, 1])
        keep = rng < self.max_range_m
        d, rng = d[keep], rng[keep]
        bins = ((np.arctan2(d[:, 1], d[:, 0]) + math.pi) / (2 * math.pi) * self.n_bearings).astype(np.int64)
        bins = np.clip(bins, 0, self.n_bearings - 1)
        nearest = np.full(self.n_bearings, np.inf)
        np.minimum.at(nearest, bins, rng)
        # A spinning lidar's columns (and its beams' azimuth offsets) are sparser than the bins:
        # a bin holding only the returns of the beams that pass over a desk or through a gap
        # would paint a free spike across the obstacle. Bound each bearing by its neighbours.
        k = self.window_bins
        if k > 0:
            ring = np.concatenate([nearest[-k:], nearest, nearest[:k]])
            nearest = np.lib.stride_tricks.sliding_window_view(ring, 2 * k + 1).min(axis=1)
        # Bearings with no return stay unknown: the polygon collapses to the origin there.
        nearest[~np.isfinite(nearest)] = 0.0
        # Stop half a cell short of the hit so the obstacle's own cell is not painted free.
        nearest = np.maximum(nearest - 0.5 * self.resolution_m, 0.0)
        angles = (np.arange(self.n_bearings) + 0.5) / self.n_bearings * 2 * math.pi - math.pi
        poly = origin_xy + np.column_stack([np.cos(angles), np.sin(angles)]) * nearest[:, None]
        self.polygons.append(poly.astype(np.float32))

    def build(
        self, extra_xy: np.ndarray | None = None, margin_m: float = 1.0, min_hits: int = 1
    ) -> OccupancyGrid:
        """Rasterise: occupied = cells hit by `min_hits` scans or more, free = seen through."""
        obstacles = self.obstacle_xy(min_hits)
        parts = [obstacles] + [p for p in self.polygons] + ([extra_xy] if extra_xy is not None else [])
        allxy = np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in parts])
        if allxy.shape[0] == 0:
            allxy = np.zeros((1, 2))
        lo = np.floor((allxy.min(axis=0) - margin_m) / self.resolution_m) * self.resolution_m
        hi = allxy.max(axis=0) + margin_m
        width = math.ceil((hi[0] - lo[0]) / self.resolution_m)
        height = math.ceil((hi[1] - lo[1]) / self.resolution_m)
        if width * height * GRID_BYTES_PER_CELL > self.max_bytes:
            raise MissingDataError(
                f"a floor's occupancy grid would be {width} x {height} cells "
                f"({(hi[0] - lo[0]):.0f} x {(hi[1] - lo[1]):.0f} m at {self.resolution_m:g} m), "
                f"over export.grid.max_mb ({self.max_bytes / 1e6:g} MB): the map spreads further "
                "than a building (a lidar that gives too few points, or a wrong trajectory); "
                "raise export.grid.resolution_m or export.grid.max_mb if the building is that big")
        free = np.zeros((height, width), dtype=np.uint8)
        scale = self.resolution_m / (1 << _SHIFT)
        for poly in self.polygons:
            cells = np.round((poly - lo) / scale).astype(np.int32)
            cv2.fillPoly(free, [cells.reshape(-1, 1, 2)], 1, lineType=cv2.LINE_8, shift=_SHIFT)
        occupied = rasterise(obstacles, lo, (height, width), self.resolution_m)
        return OccupancyGrid(occupied, free.astype(bool) & ~occupied, lo, self.resolution_m)


def rasterise(points_xy: np.ndarray, origin_xy: np.ndarray, shape: tuple[int, int], resolution_m: float) -> np.ndarray:
    """Boolean (rows = y, cols = x) mask of the cells holding at least one point."""
    mask = np.zeros(shape, dtype=bool)
    if points_xy.shape[0] == 0:
        return mask
    ij = np.floor((np.asarray(points_xy, dtype=np.float64) - origin_xy) / resolution_m).astype(np.int64)
    ok = (ij[:, 0] >= 0) & (ij[:, 0] < shape[1]) & (ij[:, 1] >= 0) & (ij[:, 1] < shape[0])
    mask[ij[ok, 1], ij[ok, 0]] = True
    return mask


@dataclass
class OccupancyGrid:
    """Row r, column c covers x in [ox + c*res, ..), y in [oy + r*res, ..) (row 0 = lowest y)."""

    occupied: np.ndarray  # bool (H, W)
    free: np.ndarray  # bool (H, W)
    origin_xy: F64  # world x, y of the lower-left corner of cell (0, 0)
    resolution_m: float

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.occupied.shape[0]), int(self.occupied.shape[1]))

    def image(self) -> np.ndarray:
        """The trinary map_server image, top row = highest y (as PGM/PNG store it)."""
        img = np.full(self.shape, UNKNOWN, dtype=np.uint8)
        img[self.free] = FREE
        img[self.occupied] = OCCUPIED
        return np.ascontiguousarray(img[::-1])

    def pgm_bytes(self) -> bytes:
        ok, buf = cv2.imencode(".pgm", self.image())
        if not ok:
            raise RuntimeError("cv2 could not encode the grid as PGM")
        return bytes(buf.tobytes())

    def yaml_dict(self, image_name: str = "grid.pgm") -> dict[str, object]:
        """nav2 map_server keys."""
        return {
            "image": image_name,
            "mode": "trinary",
            "resolution": float(self.resolution_m),
            "origin": [float(self.origin_xy[0]), float(self.origin_xy[1]), 0.0],
            "negate": 0,
            "occupied_thresh": 0.65,
            "free_thresh": 0.25,
        }

    def png_bytes(self, trajectory_xy: np.ndarray | None = None, min_width_px: int = 800) -> bytes:
        """The grid for people: grey unknown, white free, black occupied, trajectory in red."""
        img = cv2.cvtColor(self.image(), cv2.COLOR_GRAY2BGR)
        scale = max(1, math.ceil(min_width_px / max(self.shape[1], 1)))
        if scale > 1:
            img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
        if trajectory_xy is not None and trajectory_xy.shape[0] > 1:
            px = (trajectory_xy - self.origin_xy) / self.resolution_m * scale
            rows = img.shape[0] - px[:, 1]
            pts = np.column_stack([px[:, 0], rows]).round().astype(np.int32)
            cv2.polylines(img, [pts.reshape(-1, 1, 2)], False, (0, 0, 220), max(1, scale // 2),
                          lineType=cv2.LINE_AA)
            cv2.circle(img, tuple(int(v) for v in pts[0]), 3 * scale, (0, 160, 0), -1)
        ok, buf = cv2.imencode(".png", img)
        if not ok:
            raise RuntimeError("cv2 could not encode the grid as PNG")
        return bytes(buf.tobytes())


def precision_recall(estimate: np.ndarray, reference: np.ndarray, tolerance_cells: int = 1) -> tuple[float, float]:
    """Occupied-cell precision and recall, a cell counting as matched within `tolerance_cells`."""
    kernel = np.ones((2 * tolerance_cells + 1, 2 * tolerance_cells + 1), dtype=np.uint8)
    ref_dil = cv2.dilate(reference.astype(np.uint8), kernel).astype(bool)
    est_dil = cv2.dilate(estimate.astype(np.uint8), kernel).astype(bool)
    n_est = int(estimate.sum())
    n_ref = int(reference.sum())
    precision = float((estimate & ref_dil).sum()) / n_est if n_est else 0.0
    recall = float((reference & est_dil).sum()) / n_ref if n_ref else 0.0
    return precision, recall
