"""Checkpoint errors: the build's position at each surveyed point (the LeGO-LOAM elevator paper, Table I)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mfmap.errors import GroundTruthError
from mfmap.eval.io import GtPoint, TumTrajectory

# Hilti SLAM Challenge 2023 scoring (github.com/Hilti-Research/hilti-slam-challenge-2023, README):
# error below each threshold earns the points; 40 cm or more earns 0.
HILTI_THRESHOLDS_M: tuple[float, ...] = (0.005, 0.01, 0.03, 0.06, 0.10, 0.40)
HILTI_POINTS: tuple[int, ...] = (20, 10, 6, 5, 3, 1)
HILTI_MAX = HILTI_POINTS[0]
# A window whose poses spread further than this (90th percentile from their median) was probably
# not a stand-still: the median is then a poor estimate, so eval warns.
STAND_SPREAD_WARN_M = 0.10


def hilti_points(error_m: float) -> int:
    """Points for one checkpoint's 3D error."""
    for limit, points in zip(HILTI_THRESHOLDS_M, HILTI_POINTS, strict=True):
        if error_m < limit:
            return points
    return 0


@dataclass(frozen=True)
class PointError:
    label: str
    floor: int
    gt_xyz: tuple[float, float, float]
    est_xyz: tuple[float, float, float]
    poses: int  # trajectory poses in the window
    spread_m: float  # 90th percentile distance of the window's poses from their median

    @property
    def dxyz(self) -> tuple[float, float, float]:
        e, g = self.est_xyz, self.gt_xyz
        return (e[0] - g[0], e[1] - g[1], e[2] - g[2])

    @property
    def error_m(self) -> float:
        return float(np.linalg.norm(self.dxyz))


def point_errors(
    points: list[GtPoint],
    traj: TumTrajectory,
    build_floors: list[int],
    points_path: Path,
) -> list[PointError]:
    """Median estimated position over each point's window; bad windows/floors -> GroundTruthError."""
    t0, t1 = float(traj.stamps_s[0]), float(traj.stamps_s[-1])
    out: list[PointError] = []
    for p in points:
        where = f"line {p.line} ({p.label})"
        if p.floor not in build_floors:
            have = ", ".join(str(f) for f in build_floors)
            raise GroundTruthError(
                f"{where}: floor {p.floor} is not in the build (its floors: {have})", points_path
            )
        if p.t_end_s < t0 or p.t_start_s > t1:
            raise GroundTruthError(
                f"{where}: window [{p.t_start_s:.3f}, {p.t_end_s:.3f}] s is outside the log "
                f"[{t0:.3f}, {t1:.3f}] s",
                points_path,
            )
        lo = np.searchsorted(traj.stamps_s, p.t_start_s, side="left")
        hi = np.searchsorted(traj.stamps_s, p.t_end_s, side="right")
        if hi <= lo:
            raise GroundTruthError(
                f"{where}: no trajectory pose in the window [{p.t_start_s:.3f}, {p.t_end_s:.3f}] s",
                points_path,
            )
        window = traj.xyz[lo:hi]
        est = np.median(window, axis=0)
        spread = float(np.percentile(np.linalg.norm(window - est, axis=1), 90))
        out.append(
            PointError(p.label, p.floor, p.xyz, (float(est[0]), float(est[1]), float(est[2])), int(hi - lo), spread)
        )
    return out


def spread_warnings(errors: list[PointError]) -> list[str]:
    """One warning per checkpoint whose window does not look like a stand-still."""
    return [
        f"checkpoint {e.label} (floor {e.floor}): the build's poses in its window spread "
        f"{e.spread_m:.2f} m; did the robot stand still there?"
        for e in errors
        if e.spread_m > STAND_SPREAD_WARN_M
    ]


def _rmse(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def points_metrics(errors: list[PointError]) -> dict[str, float]:
    """Flat metrics (names without the `points.` prefix)."""
    d = np.array([e.dxyz for e in errors], dtype=np.float64)
    norm = np.linalg.norm(d, axis=1)
    hilti = sum(hilti_points(float(n)) for n in norm)
    score = 100.0 * hilti / (HILTI_MAX * len(errors))
    m: dict[str, float] = {
        "count": float(len(errors)),
        "rmse_m": _rmse(norm),
        "mean_m": float(norm.mean()),
        "max_m": float(norm.max()),
        "x_rmse_m": _rmse(d[:, 0]),
        "y_rmse_m": _rmse(d[:, 1]),
        "z_rmse_m": _rmse(d[:, 2]),
        "xy_rmse_m": _rmse(np.linalg.norm(d[:, :2], axis=1)),
        "hilti_points": float(hilti),
        "hilti_score": score,
        "hilti_miss": 100.0 - score,
    }
    floors = np.array([e.floor for e in errors])
    for fid in sorted(set(floors.tolist())):
        sel = floors == fid
        m[f"floor{fid}.count"] = float(sel.sum())
        m[f"floor{fid}.rmse_m"] = _rmse(norm[sel])
        m[f"floor{fid}.z_rmse_m"] = _rmse(d[sel, 2])
    return m


def points_table(errors: list[PointError]) -> dict[str, object]:
    """The Table I layout of the LeGO-LOAM elevator paper: one row per label, ground truth, then one estimate per floor."""
    floors = sorted({e.floor for e in errors})
    labels: list[str] = []
    for e in errors:
        if e.label not in labels:
            labels.append(e.label)
    rows = []
    for label in labels:
        cells: dict[str, object] = {"label": label}
        for e in errors:
            if e.label != label:
                continue
            # A label seen twice on one floor keeps its first stand.
            cells.setdefault(
                f"floor{e.floor}",
                {
                    "gt": list(e.gt_xyz),
                    "est": list(e.est_xyz),
                    "dxyz": list(e.dxyz),
                    "error_m": e.error_m,
                    "hilti_points": hilti_points(e.error_m),
                    "poses": e.poses,
                    "spread_m": e.spread_m,
                },
            )
        rows.append(cells)
    return {"floors": floors, "rows": rows}
