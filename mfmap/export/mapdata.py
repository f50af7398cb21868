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
    idx = np.floor(points / voxel_m).astype(np.int64) + _OFFSET
    idx = np.clip(idx, 0, (1 << _BITS) - 1)
    return np.asarray((idx[:, 0] << (2 * _BITS)) | (idx[:, 1] << _BITS) | idx[:, 2])


class _FloorCloud:
    """One point per voxel, merged in batches so memory stays bounded by the map's size."""

    def __init__(self, voxel_m: float) -> None:
        self.voxel_m = voxel_m
        self.keys = np.zeros(0, dtype=np.int64)
        self.points = np.zeros((0, 3), dtype=np.float32)
        self.pending: list[tuple[np.ndarray, np.ndarray]] = []
        self.pending_n = 0

    def add(self, points: np.ndarray) -> None:
        keys = _voxel_keys(points, self.voxel_m)
        keys, first = np.unique(keys, return_index=True)
        self.pending.append((keys, points[first].astype(np.float32)))
        self.pending_n += len(keys)
        if self.pending_n > max(2_000_000, 2 * len(self.keys)):
            self._merge()

    def _merge(self) -> None:
        if not self.pending:
            return
        keys = np.concatenate([self.keys, *[k for k, _ in self.pending]])
        points = np.concatenate([self.points, *[p for _, p in self.pending]])
        self.keys, first = np.unique(keys, return_index=True)
        self.points = points[first]
        self.pending = []
        self.pending_n = 0

    def cloud(self) -> np.ndarray:
        self._merge()
        return self.points


class MapAccumulator:
    """Collects each floor's cloud, grid views and trajectory from posed scans."""

    def __init__(self, config: ExportConfig, floor_z_m: dict[int, float]) -> None:
        self.config = config
        self.floor_z_m = floor_z_m
        self.clouds: dict[int, _FloorCloud] = {}
        self.grids: dict[int, GridBuilder] = {}
        self.last_view: dict[int, F64] = {}
        self.scans = 0
        self.min_hits = config.grid_min_hits

    def add(self, floor_id: int, pose: F64, points_base: np.ndarray, force_view: bool = False) -> None:
        """One scan (or keyframe) in the base frame, at its optimised base-in-world pose."""
        if floor_id < 0 or floor_id not in self.floor_z_m or points_base.shape[0] == 0:
            return
        cfg = self.config
        pts = np.asarray(points_base, dtype=np.float64)
        pts = pts[np.einsum("ij,ij->i", pts, pts) >= cfg.cloud_min_range_m**2]
        world = pts @ pose[:3, :3].T + pose[:3, 3]
        cloud = self.clouds.setdefault(floor_id, _FloorCloud(cfg.cloud_voxel_m))
        cloud.add(world)
        self.scans += 1
        grid = self.grids.setdefault(
            floor_id, GridBuilder(cfg.grid_resolution_m, max_range_m=cfg.grid_max_range_m)
        )
        rel_z = world[:, 2] - self.floor_z_m[floor_id]
        band = world[(rel_z >= cfg.grid_band_m[0]) & (rel_z <= cfg.grid_band_m[1]), :2]
        last = self.last_view.get(floor_id)
        moved = last is None or force_view
        if last is not None and not moved:
            delta = np.linalg.inv(last) @ pose
            turn = abs(math.degrees(math.atan2(delta[1, 0], delta[0, 0])))
            moved = bool(np.hypot(delta[0, 3], delta[1, 3]) >= cfg.grid_view_spacing_m or turn >= 10.0)
        if moved:
            grid.add_view(pose[:2, 3], band)
            self.last_view[floor_id] = pose.copy()
        else:
            grid.add_obstacles(band)

    def floor_ids(self) -> list[int]:
        return sorted(self.clouds)

    def cloud(self, floor_id: int) -> np.ndarray:
        return self.clouds[floor_id].cloud()

    def grid(self, floor_id: int, trajectory_xy: np.ndarray | None = None) -> OccupancyGrid:
        return self.grids[floor_id].build(trajectory_xy, min_hits=self.min_hits)
