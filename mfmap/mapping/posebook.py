"""What the mapping stage hands on: keyframes, their edges, and every scan's pose on a keyframe."""

from __future__ import annotations

import numpy as np

from mfmap.mapping.config import MappingConfig
from mfmap.mapping.geometry import inverse
from mfmap.mapping.wheelscale import Run, rescale
from mfmap.types import F64, Keyframe, PoseEdge, ScanPose


def odometry_sigma_m(cfg: MappingConfig, travelled_m: float) -> float:
    """An odometry edge's position noise after this much travel."""
    return cfg.odom_edge.sigma_m + cfg.odom_edge.sigma_per_m * travelled_m


def odometry_information(cfg: MappingConfig, delta: F64) -> F64:
    """The information matrix of an odometry edge over `delta` (rotation first)."""
    sig_t = odometry_sigma_m(cfg, float(np.linalg.norm(delta[:3, 3])))
    sig_r = np.radians(cfg.odom_edge.sigma_deg)
    return np.diag([1 / sig_r**2] * 3 + [1 / sig_t**2] * 3)


class PoseBook:
    """Keyframes and edges in the order they were made, scan poses relative to a keyframe, and
    the scans still waiting for a keyframe of their visit (`pending`, world poses)."""

    def __init__(self) -> None:
        self.keyframes: list[Keyframe] = []
        self.edges: list[PoseEdge] = []
        self.scan_poses: list[ScanPose] = []
        self.pending: list[tuple[int, F64]] = []  # scans before the first keyframe

    def hang(self, keyframe: Keyframe, stamp_ns: int, pose: F64) -> None:
        """The scan at `stamp_ns`, posed in the world, on `keyframe`."""
        self.scan_poses.append(ScanPose(stamp_ns, keyframe.id, inverse(keyframe.pose) @ pose))

    def hang_pending(self, kf: Keyframe) -> None:
        """The scans held for their visit's first keyframe, on `kf`."""
        for pending_ns, pending_pose in self.pending:
            self.scan_poses.append(ScanPose(pending_ns, kf.id, inverse(kf.pose) @ pending_pose))
        if self.pending:
            self.scan_poses.sort(key=lambda sp: sp.stamp_ns)
            self.pending.clear()

    def hang_pending_on_last(self) -> None:
        """A visit that ended before its first keyframe: its scans hang on the last keyframe."""
        last = self.keyframes[-1]
        self.scan_poses.extend(ScanPose(ns, last.id, inverse(last.pose) @ pose)
                               for ns, pose in self.pending)
        self.scan_poses.sort(key=lambda sp: sp.stamp_ns)
        self.pending.clear()

    def rescale_run(self, run: Run, scale: float) -> F64 | None:
        """Move a run's way out of the cabin to the calibrated wheels (see `Mapper.finish_run`)
        and the rest of the run rigidly with it; the rigid motion, None if the run has no
        keyframe."""
        if run.first_keyframe >= len(self.keyframes):
            return None
        first = self.keyframes[run.first_keyframe]
        moved = rescale(run.start, first.pose, scale)
        rigid = moved @ inverse(first.pose)
        for index in range(run.first_scan_pose, len(self.scan_poses)):
            sp = self.scan_poses[index]
            if sp.keyframe == first.id and sp.stamp_ns < first.stamp_ns:
                world = rescale(run.start, first.pose @ sp.relative, scale)
                self.scan_poses[index] = ScanPose(sp.stamp_ns, sp.keyframe, inverse(moved) @ world)
        for kf in self.keyframes[run.first_keyframe:]:
            kf.pose = rigid @ kf.pose  # the loop search holds the same objects
        return rigid
