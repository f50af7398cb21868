"""Colour cameras paint the lidar's points: each floor cloud's points are projected into the
floor's colour images, posed by the build's trajectory at each image's stamp.

The points painted are the floor cloud's (one per voxel, at the optimised poses) rather than
each scan's: the cloud is denser than one scan, so it hides what the camera cannot see better
than a 16-beam scan would, and the scans need not be kept or re-read. A point is occluded when
another point of the cloud lies in front of it along the camera's ray: each point is splatted
into a depth buffer as a disc of its voxel's size at its depth, and a point farther than the
nearest surface at its pixel (beyond a tolerance that grows with depth, for surfaces seen at
grazing angles) is not painted from that image. Of the images that see a point, the nearest
one's colour is kept (the most pixels per metre). Points no image sees keep what they had: a
depth camera's colour, else the nearest coloured point's, else grey (mapdata).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

import numpy as np

from mfmap.export.camera import moved_enough, pose_at
from mfmap.ingest.camera_config import CameraConfig
from mfmap.types import F64

if TYPE_CHECKING:
    from mfmap.export.mapdata import MapAccumulator
    from mfmap.export.write import FloorTrajectory
    from mfmap.ingest.colour import ColourCamera
    from mfmap.ingest.depth import CameraModel
    from mfmap.ingest.source import LogSource

logger = logging.getLogger(__name__)

# A point is hidden when it lies this much behind the nearest splat at its pixel: a few voxels,
# and a share of the depth (neighbouring points of a floor or wall seen at a grazing angle
# differ in depth by far more than a voxel).
OCCLUSION_TOL_VOXELS = 2.0
OCCLUSION_TOL_SHARE = 0.05
MAX_SPLAT_PX = 4  # splat radius cap, in depth-buffer cells


def paint_clouds(src: LogSource, cameras: list[ColourCamera], trajectory: FloorTrajectory,
                 maps: MapAccumulator, config: CameraConfig, usable: Callable[[int, F64], bool]) -> int:
    """Paint the floor clouds' points that the colour images see; returns the images used."""
    if not cameras or not maps.floor_ids():
        return 0
    voxel_m = maps.config.cloud.voxel_m
    clouds = {f: maps.cloud(f).astype(np.float64) for f in maps.floor_ids()}
    tiles = {f: _Tiles(c[:, :2], 2.0 * config.max_range_m) for f, c in clouds.items()}
    best = {f: np.full(c.shape[0], np.inf) for f, c in clouds.items()}
    rgb = {f: np.zeros((c.shape[0], 3), dtype=np.uint8) for f, c in clouds.items()}
    used = 0
    for cam in cameras:
        for floor_id, pose, image in _posed_images(src, cam, trajectory, config, usable):
            if floor_id not in clouds:
                continue
            cam_to_world = pose @ cam.to_base
            world_to_cam = np.asarray(np.linalg.inv(cam_to_world), dtype=np.float64)
            near = tiles[floor_id].around(cam_to_world[:2, 3])
            sub, colours, z = project_visible(clouds[floor_id][near], world_to_cam, cam.model, image,
                                              config.max_range_m, voxel_m)
            idx = near[sub]
            nearer = z < best[floor_id][idx]
            best[floor_id][idx[nearer]] = z[nearer]
            rgb[floor_id][idx[nearer]] = colours[nearer]
            used += 1
    for floor_id in clouds:
        seen = np.isfinite(best[floor_id])
        if seen.any():
            maps.paint(floor_id, rgb[floor_id], seen)
    return used


class _Tiles:
    """A floor cloud's points by square tiles of the ground plane, to take those near a camera
    without transforming the whole floor for each image."""

    def __init__(self, xy: F64, size_m: float) -> None:
        self.size_m = size_m
        cells = np.floor(xy / size_m).astype(np.int64)
        keys = cells[:, 0] * 1_000_003 + cells[:, 1] if cells.shape[0] else np.zeros(0, np.int64)
        self.order = np.argsort(keys, kind="stable")
        self.keys = keys[self.order]

    def around(self, xy: F64) -> np.ndarray[Any, Any]:
        """Indices (ascending) of the points in the 3 x 3 tiles around xy: every point within
        one tile's size of it (a tile twice the paint range: a camera up to 120 degrees wide)."""
        cx, cy = (int(v) for v in np.floor(np.asarray(xy) / self.size_m))
        parts = []
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                key = (cx + dx) * 1_000_003 + (cy + dy)
                lo, hi = np.searchsorted(self.keys, [key, key + 1])
                parts.append(self.order[lo:hi])
        return np.sort(np.concatenate(parts))


def _posed_images(src: LogSource, cam: ColourCamera, trajectory: FloorTrajectory, config: CameraConfig,
                  usable: Callable[[int, F64], bool]) -> Iterator[tuple[int, F64, np.ndarray[Any, Any]]]:
    """(floor, base pose, RGB image) of the camera's images that the trajectory poses, off the
    rides, after the robot moved or turned enough since the last one used."""
    from mfmap.ingest.depth import decode_colour

    msgtype = next(t.msgtype for t in src.topics if t.name == cam.topic)
    max_gap_ns = int(config.max_pose_gap_s * 1e9)
    where = f"{src.path} topic {cam.topic}"
    last: F64 | None = None
    for rec in src.messages(cam.topic):
        hit = pose_at(trajectory, rec.stamp_ns, max_gap_ns)
        if hit is None or not usable(rec.stamp_ns, hit[0]):
            continue
        if last is not None and not moved_enough(last, hit[0], config):
            continue
        image = decode_colour(rec.msg, msgtype, where)
        if image.shape[:2] != (cam.model.height, cam.model.width):
            from mfmap.errors import DecodeError

            raise DecodeError(f"{where}: colour image is {image.shape[1]} x {image.shape[0]}, its "
                              f"CameraInfo says {cam.model.width} x {cam.model.height}")
        last = hit[0]
        yield hit[1], hit[0], image


def project_visible(points: F64, world_to_cam: F64, model: CameraModel, image: np.ndarray[Any, Any],
                    max_range_m: float, voxel_m: float) -> tuple[np.ndarray[Any, Any], np.ndarray[Any, Any], F64]:
    """Indices of the points the image sees unoccluded, their colours and optical depths."""
    import cv2

    cam = points @ world_to_cam[:3, :3].T + world_to_cam[:3, 3]
    near = np.flatnonzero((cam[:, 2] > 0.05) & (cam[:, 2] <= max_range_m))
    empty = (near[:0], np.zeros((0, 3), dtype=np.uint8), np.zeros(0))
    if near.shape[0] == 0:
        return empty
    pts = cam[near]
    k = model.k
    if model.distorted:
        projected, _ = cv2.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), model.k, model.d)
        uv: F64 = np.asarray(projected, dtype=np.float64).reshape(-1, 2)
    else:
        uv = np.column_stack([k[0, 0] * pts[:, 0] / pts[:, 2] + k[0, 2], k[1, 1] * pts[:, 1] / pts[:, 2] + k[1, 2]])
    h, w = image.shape[:2]
    inside = np.flatnonzero((uv[:, 0] > -0.5) & (uv[:, 0] < w - 0.5) & (uv[:, 1] > -0.5) & (uv[:, 1] < h - 0.5))
    if inside.shape[0] == 0:
        return empty
    near, pts, uv = near[inside], pts[inside], uv[inside]
    z = pts[:, 2]
    seen = _unoccluded(uv, z, float(k[0, 0]), (w, h), voxel_m)
    u = np.clip(np.floor(uv[seen, 0] + 0.5).astype(np.int64), 0, w - 1)
    v = np.clip(np.floor(uv[seen, 1] + 0.5).astype(np.int64), 0, h - 1)
    return near[seen], image[v, u], z[seen]


def _unoccluded(uv: F64, z: F64, focal_px: float, size: tuple[int, int], voxel_m: float) -> np.ndarray[Any, Any]:
    """Which projected points are the nearest surface at their pixel (a depth buffer of splats)."""
    # A buffer coarse enough that a voxel 2 m away covers about one cell: its splats stay small.
    cell = max(1.0, focal_px * voxel_m / 2.0)
    bw, bh = math.ceil(size[0] / cell), math.ceil(size[1] / cell)
    bu = np.clip(((uv[:, 0] + 0.5) / cell).astype(np.int64), 0, bw - 1)
    bv = np.clip(((uv[:, 1] + 0.5) / cell).astype(np.int64), 0, bh - 1)
    # At least a cell around each point: a background point between the foreground's cells
    # would otherwise show through.
    radius = np.clip(np.ceil(0.5 * focal_px * voxel_m / (z * cell)), 1, MAX_SPLAT_PX).astype(np.int64)
    zbuf = np.full(bw * bh, np.inf)
    for r in np.unique(radius).tolist():
        sel = np.flatnonzero(radius == r)
        for dv in range(-r, r + 1):
            for du in range(-r, r + 1):
                if du * du + dv * dv > r * r + r:
                    continue
                cu, cv = bu[sel] + du, bv[sel] + dv
                ok = (cu >= 0) & (cu < bw) & (cv >= 0) & (cv < bh)
                np.minimum.at(zbuf, cv[ok] * bw + cu[ok], z[sel[ok]])
    front = zbuf[bv * bw + bu]
    return np.asarray(z <= front + OCCLUSION_TOL_VOXELS * voxel_m + OCCLUSION_TOL_SHARE * z)

