"""Per-visit trajectory errors of the mapping stage's odometry against a ground-truth TUM file.

Used by the mapping tests and `pipelines/bench_odometry.py`; a build's own scores are in `api`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from mfmap.eval import io
from mfmap.mapping.geometry import PoseInterpolator, yaw_pose, yaw_rad
from mfmap.mapping.posegraph import scan_trajectory
from mfmap.types import F64, I64, MappingResult


def read_tum(path: Path) -> tuple[I64, F64]:
    """(stamp_ns (N,), poses (N, 4, 4)) from a TUM file `t x y z qx qy qz qw`, read by
    `mfmap.eval.io.read_tum`."""
    traj = io.read_tum(path)
    stamps = np.round(traj.stamps_s * 1e9).astype(np.int64)
    poses = np.tile(np.eye(4), (len(stamps), 1, 1))
    poses[:, :3, :3] = Rotation.from_quat(traj.quat_xyzw).as_matrix()
    poses[:, :3, 3] = traj.xyz
    return stamps, poses


@dataclass(frozen=True)
class VisitError:
    visit: int
    floor_id: int
    scans: int
    distance_m: float  # travelled, from the ground truth
    end_error_m: float  # position error at the visit's last scan, aligned at its first
    rmse_m: float
    max_error_m: float

    @property
    def drift_pct(self) -> float:
        return 100.0 * self.end_error_m / self.distance_m if self.distance_m > 0 else 0.0


def visit_errors(
    result: MappingResult,
    visits: list[tuple[int, int, int]],
    gt_stamp_ns: I64,
    gt_poses: F64,
    keyframe_poses: dict[int, F64] | None = None,
) -> list[VisitError]:
    """Errors of every visit's scan poses, each aligned at its first scan (x, y, z, yaw)."""
    stamps, poses = scan_trajectory(result, keyframe_poses)
    quats = Rotation.from_matrix(gt_poses[:, :3, :3]).as_quat()
    truth = PoseInterpolator(gt_stamp_ns, gt_poses[:, :3, 3], quats)
    out: list[VisitError] = []
    for index, (floor_id, start_ns, end_ns) in enumerate(visits):
        inside = (stamps >= start_ns) & (stamps <= end_ns)
        inside &= (stamps >= gt_stamp_ns[0]) & (stamps <= gt_stamp_ns[-1])
        if inside.sum() < 2:
            continue
        est = poses[inside]
        gt = np.array([truth.at(int(s)) for s in stamps[inside]])
        # Position and yaw only: both frames are levelled to gravity, and a single pose's
        # roll/pitch (the robot rocks by tenths of a degree) would tilt the whole visit.
        align = yaw_pose(yaw_rad(gt[0]) - yaw_rad(est[0]))
        align[:3, 3] = gt[0][:3, 3] - align[:3, :3] @ est[0][:3, 3]
        est_xyz = est[:, :3, 3] @ align[:3, :3].T + align[:3, 3]
        err = np.linalg.norm(est_xyz - gt[:, :3, 3], axis=1)
        dist = float(np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1).sum())
        out.append(VisitError(index, floor_id, int(inside.sum()), dist, float(err[-1]),
                              float(np.sqrt(np.mean(err**2))), float(err.max())))
    return out
