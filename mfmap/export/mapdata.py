"""Per-floor accumulation of the exported clouds and grids from scans at their optimised poses."""

from __future__ import annotations

import math

import numpy as np

from mfmap.export.config import ExportConfig
from mfmap.export.grid import GridBuilder, OccupancyGrid
from mfmap.types import F64

_BITS = 21
_OFFSET = 1 << (_BITS - 1)


def _voxel_keys(points: np.ndarray, voxel_m: float) -> np.ndarray:
    return _keys_of_cells(np.floor(points / voxel_m).astype(np.int64))


def _keys_of_cells(cells: np.ndarray) -> np.ndarray:
    idx = np.clip(cells + _OFFSET, 0, (1 << _BITS) - 1)
    return np.asarray((idx[:, 0] << (2 * _BITS)) | (idx[:, 1] << _BITS) | idx[:, 2])


def _first_per_cell(cells: np.ndarray) -> np.ndarray:
    """Index of the first point in each distinct voxel, in voxel order (what np.unique's
    return_index gives on the keys) - by one plain sort of (voxel rank, index) packed in an
    int64, several times faster than np.unique's stable argsort."""
    n = cells.shape[0]
    index_bits = max(int(n - 1).bit_length(), 1)
    # Per column: a reduction along axis 0 of an (N, 3) array is ten times slower.
    lo = np.array([cells[:, k].min() for k in range(3)])
    bits = [max(int(cells[:, k].max() - lo[k]).bit_length(), 1) for k in range(3)]
    if sum(bits) + index_bits > 63:
        return np.asarray(np.unique(_keys_of_cells(cells), return_index=True)[1])
    rel = cells - lo  # relative voxel coordinates keep the (x, y, z) order in fewer bits
    rank = ((rel[:, 0] << (bits[1] + bits[2])) | (rel[:, 1] << bits[2]) | rel[:, 2]) << index_bits
    packed = np.sort(rank | np.arange(n, dtype=np.int64))
    voxel = packed >> index_bits
    starts = np.concatenate(([True], voxel[1:] != voxel[:-1]))
    return np.asarray(packed[starts] & ((1 << index_bits) - 1))


class _FloorCloud:
    """One point per voxel, merged in batches so memory stays bounded by the map's size.

    Once a coloured point (a camera's) arrives the cloud carries colours: in a voxel with both a
    coloured and an uncoloured point, the coloured one is kept.
    """

    def __init__(self, voxel_m: float) -> None:
        self.voxel_m = voxel_m
        self.keys = np.zeros(0, dtype=np.int64)
        self.points = np.zeros((0, 3), dtype=np.float32)
        self.rgb: np.ndarray | None = None  # (N, 3) uint8 once coloured
        self.coloured_mask: np.ndarray | None = None  # (N,) bool once coloured
        self.pending: list[tuple[np.ndarray, np.ndarray, np.ndarray | None]] = []
        self.pending_n = 0

    def add(self, points: np.ndarray, rgb: np.ndarray | None = None) -> None:
        if points.shape[0] == 0:
            return
        cells = np.floor(points / self.voxel_m).astype(np.int64)
        first = _first_per_cell(cells)
        colours = None if rgb is None else np.asarray(rgb, dtype=np.uint8)[first]
        self.pending.append((_keys_of_cells(cells[first]), points[first].astype(np.float32), colours))
        self.pending_n += len(first)
        if rgb is not None and self.rgb is None:
            self.rgb = np.zeros((len(self.keys), 3), dtype=np.uint8)
            self.coloured_mask = np.zeros(len(self.keys), dtype=bool)
        if self.pending_n > max(2_000_000, 2 * len(self.keys)):
            self._merge()

    def _merge(self) -> None:
        if not self.pending:
            return
        keys = np.concatenate([self.keys, *[k for k, _, _ in self.pending]])
        points = np.concatenate([self.points, *[p for _, p, _ in self.pending]])
        if self.rgb is None or self.coloured_mask is None:
            self.keys, first = np.unique(keys, return_index=True)
            self.points = points[first]
        else:
            rgb = np.concatenate([self.rgb, *[c if c is not None else np.zeros((len(k), 3), np.uint8)
                                              for k, _, c in self.pending]])
            has = np.concatenate([self.coloured_mask, *[np.full(len(k), c is not None)
                                                        for k, _, c in self.pending]])
            # By voxel, coloured first, then arrival order: the first of each voxel is kept.
            order = np.lexsort((np.arange(len(keys)), ~has, keys))
            sorted_keys = keys[order]
            starts = np.concatenate(([True], sorted_keys[1:] != sorted_keys[:-1]))
            first = order[starts]
            self.keys = sorted_keys[starts]
            self.points, self.rgb, self.coloured_mask = points[first], rgb[first], has[first]
        self.pending = []
        self.pending_n = 0

    def cloud(self) -> np.ndarray:
        self._merge()
        return self.points

    def paint(self, rgb: np.ndarray, mask: np.ndarray) -> None:
        """Colours for the points of cloud() where mask, except points a camera coloured."""
        self._merge()
        if self.rgb is None or self.coloured_mask is None:
            self.rgb = np.zeros((len(self.keys), 3), dtype=np.uint8)
            self.coloured_mask = np.zeros(len(self.keys), dtype=bool)
        new = mask & ~self.coloured_mask
        self.rgb[new] = rgb[new]
        self.coloured_mask |= new

    def colours(self, fill_radius_m: float) -> np.ndarray | None:
        """(N, 3) uint8 colours, None when no camera coloured this cloud. A point no camera saw
        (a lidar return) takes the colour of the nearest coloured point within fill_radius_m,
        else mid grey."""
        self._merge()
        if self.rgb is None or self.coloured_mask is None:
            return None
        out = self.rgb.copy()
        missing = np.flatnonzero(~self.coloured_mask)
        out[missing] = 128
        have = np.flatnonzero(self.coloured_mask)
        if missing.shape[0] and have.shape[0]:
            from pykdtree.kdtree import KDTree

            tree = KDTree(self.points[have].astype(np.float64))
            dist, idx = tree.query(self.points[missing].astype(np.float64), k=1)
            near = dist <= fill_radius_m
            out[missing[near]] = self.rgb[have[idx[near]]]
        return out


class MapAccumulator:
    """Collects each floor's cloud, grid views and trajectory from posed scans."""

    def __init__(self, config: ExportConfig, floor_z_m: dict[int, float]) -> None:
        self.config = config
        self.floor_z_m = floor_z_m
        self.clouds: dict[int, _FloorCloud] = {}
        self.grids: dict[int, GridBuilder] = {}
        self.last_view: dict[int, F64] = {}
        self.scans = 0
        self.images = 0  # depth images added
        self.min_hits = config.grid.min_hits

    def add(self, floor_id: int, pose: F64, points_base: np.ndarray, force_view: bool = False) -> None:
        """One scan (or keyframe) in the base frame, at its optimised base-in-world pose."""
        if floor_id < 0 or floor_id not in self.floor_z_m or points_base.shape[0] == 0:
            return
        cfg = self.config
        pts = np.asarray(points_base, dtype=np.float64)
        pts = pts[np.einsum("ij,ij->i", pts, pts) >= cfg.cloud.min_range_m**2]
        world = pts @ pose[:3, :3].T + pose[:3, 3]
        cloud = self.clouds.setdefault(floor_id, _FloorCloud(cfg.cloud.voxel_m))
        cloud.add(world)
        self.scans += 1
        grid = self.grids.setdefault(
            floor_id, GridBuilder(cfg.grid.resolution_m, max_range_m=cfg.grid.max_range_m,
                                  max_bytes=cfg.grid.max_mb * 1e6)
        )
        if cfg.grid.level_band:
            # Heights in the robot's frame: a ground robot stands level on its floor, and an error
            # of a fraction of a degree in the pose's roll/pitch would lift the floor seen 6-10 m
            # away into the band (arcs of false walls).
            rel_z = pts[:, 2] + (pose[2, 3] - self.floor_z_m[floor_id])
        else:
            rel_z = world[:, 2] - self.floor_z_m[floor_id]
        band = world[(rel_z >= cfg.grid.band_m[0]) & (rel_z <= cfg.grid.band_m[1]), :2]
        last = self.last_view.get(floor_id)
        moved = last is None or force_view
        if last is not None and not moved:
            delta = np.linalg.inv(last) @ pose
            turn = abs(math.degrees(math.atan2(delta[1, 0], delta[0, 0])))
            moved = bool(np.hypot(delta[0, 3], delta[1, 3]) >= cfg.grid.view_spacing_m or turn >= 10.0)
        if moved:
            grid.add_view(pose[:2, 3], band)
            self.last_view[floor_id] = pose.copy()
        else:
            grid.add_obstacles(band)

    def add_camera(self, floor_id: int, pose: F64, points_base: np.ndarray,
                   rgb: np.ndarray | None, band_m: tuple[float, float]) -> None:
        """One depth image's points in the base frame at the base pose of its stamp: into the
        cloud (with their colours), and as obstacles into the grid where they fall in the
        robot's height band (a camera sees tables and shelves a 2D scan passes under or over;
        its narrow view adds no free space)."""
        if floor_id < 0 or floor_id not in self.floor_z_m or points_base.shape[0] == 0:
            return
        pts = np.asarray(points_base, dtype=np.float64)
        world = pts @ pose[:3, :3].T + pose[:3, 3]
        cloud = self.clouds.setdefault(floor_id, _FloorCloud(self.config.cloud.voxel_m))
        cloud.add(world, rgb)
        self.images += 1
        grid = self.grids.get(floor_id)
        if grid is None:
            return  # no lidar view of this floor: no grid to add to
        rel_z = pts[:, 2] + (pose[2, 3] - self.floor_z_m[floor_id])
        grid.add_obstacles(world[(rel_z >= band_m[0]) & (rel_z <= band_m[1]), :2])

    def paint(self, floor_id: int, rgb: np.ndarray, mask: np.ndarray) -> None:
        """Colour the floor cloud's points (in cloud() order) where mask, keeping a camera's."""
        self.clouds[floor_id].paint(rgb, mask)

    def colours(self, floor_id: int, fill_radius_m: float = 0.2) -> np.ndarray | None:
        return self.clouds[floor_id].colours(fill_radius_m)

    def merge(self, other: MapAccumulator) -> None:
        """Take over the floors of an accumulator that saw other floors (a worker's)."""
        if set(other.clouds) & set(self.clouds) or set(other.grids) & set(self.grids):
            raise ValueError("accumulators to merge share a floor")
        self.clouds.update(other.clouds)
        self.grids.update(other.grids)
        self.last_view.update(other.last_view)
        self.scans += other.scans
        self.images += other.images

    def floor_ids(self) -> list[int]:
        return sorted(self.clouds)

    def cloud(self, floor_id: int) -> np.ndarray:
        return self.clouds[floor_id].cloud()

    def grid(self, floor_id: int, trajectory_xy: np.ndarray | None = None) -> OccupancyGrid:
        return self.grids[floor_id].build(trajectory_xy, min_hits=self.min_hits)
