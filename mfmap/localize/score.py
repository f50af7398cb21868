"""A localisation's output folder against the ground truth: what the benchmark, the regression
set and the tests report.

Besides `mfmap eval`'s trajectory and floor figures (over the scans it posed):

- `localised_share`: scans posed, of all scans;
- `first_fix_s`: log time from the first scan to the first global fix (NaN: none);
- `wrong_share`: scans posed more than `wrong_m` from the truth (on another floor: metres off
  in z), of all scans: the confident wrong poses localisation must not give. For a log of another building
  (`foreign`) every posed scan is wrong;
- `not_localised_s`: the log time in spans not localised;
- `pos_median_m`, `pos_p95_m`, `yaw_median_deg`, `yaw_p95_deg`: the posed scans' position and
  heading errors (no alignment: the map's frame is the truth's), median and 95th percentile.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from mfmap.eval.config import EvalConfig

# A posed scan this far from the truth is wrong (not merely inaccurate).
WRONG_M = 0.5


def score_localization(out: Path, gt_trajectory: Path | None = None, gt_floors: Path | None = None,
                       foreign: bool = False, wrong_m: float = WRONG_M,
                       config: EvalConfig | None = None) -> dict[str, float]:
    """Flat metrics (`trajectory.*`, `floors.*` as `mfmap eval` names them, `localize.*`)."""
    from mfmap.eval import evaluate
    from mfmap.eval.io import read_tum
    from mfmap.eval.trajectory import associate, quat_to_matrix, yaw_of

    report = json.loads((out / "report.json").read_text())
    metrics: dict[str, float] = {
        "localize.localised_share": float(report["localised_share"]),
        "localize.first_fix_s": math.nan if report["first_fix_s"] is None else float(report["first_fix_s"]),
        "localize.not_localised_s": float(sum(s["to_s"] - s["from_s"] for s in report["not_localised"])),
        "localize.scans": float(report["scans"]),
        "localize.searches": float(report["searches"]),
    }
    posed = read_tum(out / "trajectory.tum") if (out / "trajectory.tum").stat().st_size else None
    n_posed = 0 if posed is None else len(posed.stamps_s)
    if foreign:
        metrics["localize.wrong_share"] = n_posed / max(report["scans"], 1)
        return metrics
    if gt_trajectory is not None and posed is not None:
        ev = evaluate(out, trajectory=gt_trajectory, floors=gt_floors, config=config or EvalConfig())
        metrics.update({k: v for k, v in ev.metrics.items()
                        if k.startswith(("trajectory.", "floors."))})
        gt = read_tum(gt_trajectory)
        i_est, i_gt = associate(posed.stamps_s, gt.stamps_s, (config or EvalConfig()).max_time_diff_s)
        error = np.linalg.norm(posed.xyz[i_est] - gt.xyz[i_gt], axis=1)
        far = error > wrong_m
        if len(error):
            yaw = np.degrees(np.abs(_wrap(yaw_of(quat_to_matrix(posed.quat_xyzw[i_est]))
                                          - yaw_of(quat_to_matrix(gt.quat_xyzw[i_gt])))))
            metrics.update({
                "localize.pos_median_m": float(np.median(error)),
                "localize.pos_p95_m": float(np.percentile(error, 95)),
                "localize.yaw_median_deg": float(np.median(yaw)),
                "localize.yaw_p95_deg": float(np.percentile(yaw, 95)),
            })
        wrong = int(far.sum()) + (n_posed - len(i_est))  # unpaired posed scans count as wrong
        metrics["localize.wrong_share"] = wrong / max(report["scans"], 1)
    elif gt_trajectory is not None:
        metrics["localize.wrong_share"] = 0.0
    return metrics


def _wrap(rad: np.ndarray) -> np.ndarray:
    return (rad + np.pi) % (2 * np.pi) - np.pi
