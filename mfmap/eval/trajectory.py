"""Absolute pose error of an estimated trajectory against ground truth (pure math)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mfmap.eval.io import TumTrajectory
from mfmap.types import F64, I64


def associate(stamps_a: F64, stamps_b: F64, max_diff_s: float) -> tuple[I64, I64]:
    """Pairs (i, j) with a[i] matched to its nearest b[j] within max_diff_s.

    Same rule as evo's `associate_trajectories`: the shorter trajectory is the one whose every
    stamp looks for its nearest stamp in the longer (ties go to the earlier stamp).
    """
    swap = len(stamps_b) < len(stamps_a)
    short, long_ = (stamps_b, stamps_a) if swap else (stamps_a, stamps_b)
    right = np.searchsorted(long_, short, side="right")
    right = np.minimum(right, len(long_) - 1)
    left = np.maximum(right - 1, 0)
    diff_ub = long_[right] - short
    diff_lb = np.where(right > 0, short - long_[left], np.inf)
    take_ub = (diff_ub <= max_diff_s) & (diff_ub < diff_lb)
    take_lb = ~take_ub & (diff_lb <= max_diff_s) & (diff_lb <= diff_ub)
    in_range = (short >= long_[0] - max_diff_s) & (short <= long_[-1] + max_diff_s)
    keep = (take_ub | take_lb) & in_range
    idx_short = np.nonzero(keep)[0].astype(np.int64)
    idx_long = np.where(take_ub, right, left)[keep].astype(np.int64)
    return (idx_long, idx_short) if swap else (idx_short, idx_long)


def quat_to_matrix(q_xyzw: F64) -> F64:
    """(N, 4) quaternions (x, y, z, w) -> (N, 3, 3) rotation matrices."""
    x, y, z, w = (q_xyzw[:, i] for i in range(4))
    r = np.empty((len(q_xyzw), 3, 3))
    r[:, 0, 0] = 1 - 2 * (y * y + z * z)
    r[:, 0, 1] = 2 * (x * y - z * w)
    r[:, 0, 2] = 2 * (x * z + y * w)
    r[:, 1, 0] = 2 * (x * y + z * w)
    r[:, 1, 1] = 1 - 2 * (x * x + z * z)
    r[:, 1, 2] = 2 * (y * z - x * w)
    r[:, 2, 0] = 2 * (x * z - y * w)
    r[:, 2, 1] = 2 * (y * z + x * w)
    r[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return r


def yaw_of(rot: F64) -> F64:
    """Yaw (rad) of (N, 3, 3) rotations, z-y-x convention."""
    return np.arctan2(rot[:, 1, 0], rot[:, 0, 0])


def umeyama_se3(src: F64, dst: F64) -> tuple[F64, F64]:
    """R, t minimising sum |R src + t - dst|^2 (Umeyama 1991, no scale)."""
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    cov = (dst - mu_d).T @ (src - mu_s) / len(src)
    u, _, vt = np.linalg.svd(cov)
    s = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        s[2, 2] = -1
    rot = u @ s @ vt
    return rot, mu_d - rot @ mu_s


def align_4dof(src: F64, dst: F64) -> tuple[F64, F64]:
    """R (yaw only), t minimising sum |R src + t - dst|^2: closed form in the xy plane."""
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - mu_s, dst - mu_d
    sin_sum = np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    cos_sum = np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1])
    yaw = np.arctan2(sin_sum, cos_sum)
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return rot, mu_d - rot @ mu_s


@dataclass(frozen=True)
class PoseErrors:
    """Per-pair errors after association (and alignment, if any)."""

    stamps_s: F64
    dxyz: F64  # (N, 3) est - gt
    rot_deg: F64  # (N,)
    tilt_deg: F64  # (N,) angle between the estimated and the true up, in the body frame
    align_rotation: F64  # 3x3 applied to the estimate (identity without alignment)
    align_translation: F64


def pose_errors(est: TumTrajectory, gt: TumTrajectory, max_diff_s: float, align: str = "none") -> PoseErrors:
    """Associate `est` with `gt` by time and compute position and rotation errors.

    Raises ValueError when no stamps pair up.
    """
    i_est, i_gt = associate(est.stamps_s, gt.stamps_s, max_diff_s)
    if len(i_est) == 0:
        raise ValueError("no poses pair up in time")
    p_est, p_gt = est.xyz[i_est], gt.xyz[i_gt]
    r_est, r_gt = quat_to_matrix(est.quat_xyzw[i_est]), quat_to_matrix(gt.quat_xyzw[i_gt])
    rot, trans = np.eye(3), np.zeros(3)
    if align == "se3":
        rot, trans = umeyama_se3(p_est, p_gt)
    elif align == "4dof":
        rot, trans = align_4dof(p_est, p_gt)
    elif align != "none":
        raise ValueError(f"unknown alignment '{align}'")
    p_est = p_est @ rot.T + trans
    r_est = rot[None] @ r_est
    rel = np.transpose(r_gt, (0, 2, 1)) @ r_est
    cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    # arccos loses precision near 0; the axis-angle norm via arctan2 keeps it.
    skew = np.stack([rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0], rel[:, 1, 0] - rel[:, 0, 1]], axis=1)
    angle = np.arctan2(np.linalg.norm(skew, axis=1) / 2.0, cos)
    # The world's up in each body frame (R^T z, the third row): roll and pitch, blind to yaw.
    up_est, up_gt = r_est[:, 2, :], r_gt[:, 2, :]
    tilt = np.arctan2(np.linalg.norm(np.cross(up_est, up_gt), axis=1), np.einsum("ij,ij->i", up_est, up_gt))
    return PoseErrors(est.stamps_s[i_est], p_est - p_gt, np.degrees(angle), np.degrees(tilt), rot, trans)


def _rmse(values: F64) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def ape_metrics(errors: PoseErrors) -> dict[str, float]:
    """Flat metrics (names without the `trajectory.` prefix)."""
    norm = np.linalg.norm(errors.dxyz, axis=1)
    return {
        "pairs": float(len(norm)),
        "ape_rmse_m": _rmse(norm),
        "ape_mean_m": float(np.mean(norm)),
        "ape_median_m": float(np.median(norm)),
        "ape_max_m": float(np.max(norm)),
        "rot_rmse_deg": _rmse(errors.rot_deg),
        "rot_mean_deg": float(np.mean(errors.rot_deg)),
        "rot_median_deg": float(np.median(errors.rot_deg)),
        "rot_max_deg": float(np.max(errors.rot_deg)),
        "tilt_rmse_deg": _rmse(errors.tilt_deg),
        "tilt_max_deg": float(np.max(errors.tilt_deg)),
        "z_rmse_m": _rmse(errors.dxyz[:, 2]),
        "z_max_m": float(np.max(np.abs(errors.dxyz[:, 2]))),
        "xy_rmse_m": _rmse(np.linalg.norm(errors.dxyz[:, :2], axis=1)),
    }


def per_floor_metrics(errors: PoseErrors, visits: dict[int, list[tuple[float, float]]]) -> dict[str, float]:
    """APE and z RMSE of the pairs inside each floor's visits (names `floor<k>.*`)."""
    m: dict[str, float] = {}
    for fid, intervals in sorted(visits.items()):
        inside = np.zeros(len(errors.stamps_s), dtype=bool)
        for t0, t1 in intervals:
            inside |= (errors.stamps_s >= t0) & (errors.stamps_s <= t1)
        if not inside.any():
            continue
        m[f"floor{fid}.pairs"] = float(inside.sum())
        m[f"floor{fid}.ape_rmse_m"] = _rmse(np.linalg.norm(errors.dxyz[inside], axis=1))
        m[f"floor{fid}.z_rmse_m"] = _rmse(errors.dxyz[inside, 2])
    return m


def pose_at(traj: TumTrajectory, t_s: float) -> tuple[F64, float]:
    """Position and yaw (rad) of the pose nearest in time to t_s."""
    i = int(np.argmin(np.abs(traj.stamps_s - t_s)))
    rot = quat_to_matrix(traj.quat_xyzw[i : i + 1])
    return traj.xyz[i], float(yaw_of(rot)[0])
