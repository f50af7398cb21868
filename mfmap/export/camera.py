"""Depth cameras into the floor maps: each image posed by the build's trajectory at its stamp."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from mfmap.export.mapdata import MapAccumulator
from mfmap.ingest.camera_config import CameraConfig
from mfmap.types import F64

if TYPE_CHECKING:
    from mfmap.export.write import FloorTrajectory
    from mfmap.ingest.depth import Camera
    from mfmap.ingest.source import LogSource

logger = logging.getLogger(__name__)


def pose_at(trajectory: FloorTrajectory, stamp_ns: int, max_gap_ns: int) -> tuple[F64, int] | None:
    """Base pose (4x4) and floor at a stamp between two trajectory poses of one floor: the
    translation interpolated linearly, the rotation by slerp. None outside the trajectory, across
    a gap longer than max_gap_ns or a floor change."""
    stamps = trajectory.stamps_ns
    n = stamps.shape[0]
    if n == 0:
        return None
    b = int(np.searchsorted(stamps, stamp_ns))
    if b < n and stamps[b] == stamp_ns:
        return trajectory.poses[b].copy(), int(trajectory.floor[b])
    if b == 0 or b == n:
        return None
    a = b - 1
    if stamps[b] - stamps[a] > max_gap_ns or trajectory.floor[a] != trajectory.floor[b]:
        return None
    from scipy.spatial.transform import Rotation, Slerp

    t = (stamp_ns - int(stamps[a])) / float(stamps[b] - stamps[a])
    pa, pb = trajectory.poses[a], trajectory.poses[b]
    slerp = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([pa[:3, :3], pb[:3, :3]])))
    out = np.eye(4)
    out[:3, :3] = slerp([t]).as_matrix()[0]
    out[:3, 3] = (1.0 - t) * pa[:3, 3] + t * pb[:3, 3]
    return out, int(trajectory.floor[a])


def add_cameras(src: LogSource, cameras: list[Camera], trajectory: FloorTrajectory, maps: MapAccumulator,
                config: CameraConfig, band_m: tuple[float, float],
                usable: Callable[[int, F64], bool],
                keep: Callable[[np.ndarray, F64, int], np.ndarray] | None = None) -> dict[str, int]:
    """Add the depth cameras' images to `maps`; returns images used per depth topic.

    An image is used when the trajectory poses it, `usable(stamp, pose)` accepts it (not in a
    ride, a stair walk or a cabin) and the robot moved or turned enough since that camera's last
    used image; `keep(points_base, pose, stamp)` masks the points to use (not the cabin's).
    """
    from mfmap.ingest.depth import camera_points

    used: dict[str, int] = {}
    max_gap_ns = int(config.max_pose_gap_s * 1e9)
    for cam in cameras:
        posed: dict[int, tuple[F64, int]] = {}
        last: list[F64] = []

        def want(stamp_ns: int, posed: dict[int, tuple[F64, int]] = posed, last: list[F64] = last) -> bool:
            hit = pose_at(trajectory, stamp_ns, max_gap_ns)
            if hit is None or not usable(stamp_ns, hit[0]):
                return False
            if last and not moved_enough(last[0], hit[0], config):
                return False
            last[:] = [hit[0]]
            posed[stamp_ns] = hit
            return True

        count = 0
        for image in camera_points(src, cam, config, want):
            pose, floor_id = posed.pop(image.stamp_ns)
            pts = image.xyz.astype(np.float64) @ cam.to_base[:3, :3].T + cam.to_base[:3, 3]
            rgb = image.rgb
            if keep is not None:
                mask = keep(pts, pose, image.stamp_ns)
                pts = pts[mask]
                rgb = rgb[mask] if rgb is not None else None
            maps.add_camera(floor_id, pose, pts, rgb, band_m)
            count += 1
        used[cam.depth_topic] = count
    return used


def moved_enough(last: F64, pose: F64, config: CameraConfig) -> bool:
    delta = np.linalg.inv(last) @ pose
    turn = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(delta[:3, :3]) - 1.0) / 2.0))))
    return bool(np.linalg.norm(delta[:3, 3]) >= config.image_min_motion_m
                or turn >= config.image_min_turn_deg)
