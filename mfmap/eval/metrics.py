"""Metric names (stable, documented), the eval result and `--fail-above` thresholds.

Every metric is a flat dotted name with a float value. In the names below `<k>` is a floor id,
`<a>_<b>` a pair of adjacent ground-truth floors and `<d>` a distance threshold in centimetres
from `eval.fscore_thresholds_m` (5cm, 10cm, 20cm by default; 2.5 cm is written `2p5cm`).
`--fail-above NAME=VALUE` fails when the metric is above VALUE; every higher-is-better metric has
an error-style counterpart (`*_miss_*`, `*_wrong_*`, `hilti_miss`) so it can be guarded the same
way.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mfmap.errors import MfmapError

METRICS: dict[str, str] = {
    # points: surveyed checkpoints vs the median estimated position over each stand-still window
    "points.count": "number of checkpoints scored",
    "points.rmse_m": "RMSE of the 3D position error over all checkpoints",
    "points.mean_m": "mean 3D position error",
    "points.max_m": "largest 3D position error",
    "points.x_rmse_m": "RMSE of the x error",
    "points.y_rmse_m": "RMSE of the y error",
    "points.z_rmse_m": "RMSE of the z (height) error",
    "points.xy_rmse_m": "RMSE of the horizontal error",
    "points.floor<k>.count": "checkpoints on floor k",
    "points.floor<k>.rmse_m": "RMSE of the 3D error on floor k (Table I of the LeGO-LOAM elevator paper reports this per floor)",
    "points.floor<k>.z_rmse_m": "RMSE of the z error on floor k",
    "points.hilti_points": "sum of Hilti 2023 points (<0.5 cm 20, <1 cm 10, <3 cm 6, <6 cm 5, <10 cm 3, <40 cm 1, else 0)",
    "points.hilti_score": "Hilti points as 0-100 (sum / (20 x count) x 100); higher is better",
    "points.hilti_miss": "100 - points.hilti_score (guard with --fail-above)",
    # cloud: map.ply vs a reference cloud, nearest-neighbour distances both ways
    "cloud.map_points": "points in map.ply",
    "cloud.ref_points": "points in the reference cloud",
    "cloud.accuracy_m": "mean distance from map points to the nearest reference point",
    "cloud.accuracy_median_m": "median distance map -> reference",
    "cloud.completeness_m": "mean distance from reference points to the nearest map point",
    "cloud.completeness_median_m": "median distance reference -> map",
    "cloud.precision_<d>": "share of map points within d of the reference",
    "cloud.recall_<d>": "share of reference points within d of the map (completeness share)",
    "cloud.fscore_<d>": "harmonic mean of precision and recall at d; higher is better",
    "cloud.precision_miss_<d>": "1 - precision at d",
    "cloud.recall_miss_<d>": "1 - recall at d (share of the reference the map misses)",
    "cloud.fscore_miss_<d>": "1 - F-score at d",
    "cloud.floor<k>.<any cloud metric above>": "the same figures for floor k alone (map points by their floor field, reference points by their floor field or by z)",
    # trajectory: trajectory.tum vs a ground-truth TUM, poses paired by nearest time
    "trajectory.pairs": "number of pose pairs scored",
    "trajectory.ape_rmse_m": "RMSE of the position error (no alignment: both in the world frame)",
    "trajectory.ape_mean_m": "mean position error",
    "trajectory.ape_median_m": "median position error",
    "trajectory.ape_max_m": "largest position error",
    "trajectory.rot_rmse_deg": "RMSE of the rotation error angle (angle of R_gt^T R_est)",
    "trajectory.rot_mean_deg": "mean rotation error angle",
    "trajectory.rot_median_deg": "median rotation error angle",
    "trajectory.rot_max_deg": "largest rotation error angle",
    "trajectory.tilt_rmse_deg": "RMSE of the tilt error: the angle between the estimated and the true up in the body frame (roll and pitch, not yaw)",
    "trajectory.tilt_max_deg": "largest tilt error",
    "trajectory.z_rmse_m": "RMSE of the z error alone",
    "trajectory.z_max_m": "largest absolute z error",
    "trajectory.xy_rmse_m": "RMSE of the horizontal error",
    "trajectory.floor<k>.pairs": "pose pairs while on floor k (ground-truth visits with --floors, else the build's)",
    "trajectory.floor<k>.ape_rmse_m": "APE RMSE while on floor k (no alignment)",
    "trajectory.floor<k>.z_rmse_m": "z RMSE while on floor k (no alignment)",
    "trajectory.se3.<any trajectory metric above>": "the same (except per floor) after an SE(3) Umeyama alignment (no scale), with --align se3",
    "trajectory.4dof.<any trajectory metric above>": "the same after an x, y, z, yaw alignment, with --align 4dof",
    # floors: the build's floors.json vs ground-truth floors JSON
    "floors.count_gt": "floors in the ground truth",
    "floors.count_est": "floors in the build",
    "floors.count_correct": "1 when the counts match, else 0",
    "floors.count_error": "absolute difference of the floor counts",
    "floors.time_correct_share": "share of ground-truth visit time the build assigns to the right floor",
    "floors.time_wrong_share": "1 - floors.time_correct_share",
    "floors.floor<k>.elevation_error_m": "absolute elevation error of ground-truth floor k (both relative to the start floor)",
    "floors.elevation_error_max_m": "largest per-floor elevation error",
    "floors.elevation_error_rmse_m": "RMSE of the per-floor elevation errors",
    "floors.unmatched_floors": "ground-truth floors with no estimated floor",
    "floors.transitions_gt": "transitions in the ground truth",
    "floors.transitions_missed": "ground-truth transitions with no matching estimated one",
    "floors.transitions_extra": "estimated transitions that match none in the ground truth",
    "floors.transition_time_error_max_s": "largest start/end time error of matched transitions",
    "floors.inter<a>_<b>.dx_m": "x error of floor b placed relative to floor a at their connectors: the x change across each ride between a and b, build minus truth (trajectories at the true ride times with --trajectory, else the floors files' ride start/end x, y); mean of absolute values over rides (the multi-floor precision mapping paper's Table 1)",
    "floors.inter<a>_<b>.dy_m": "y error of the relative placement at the connectors",
    "floors.inter<a>_<b>.dyaw_deg": "yaw error of the relative placement (needs --trajectory)",
    "floors.inter<a>_<b>.dz_m": "error of the elevation difference between floors a and b (the multi-floor precision mapping paper's Table 2)",
    "floors.inter<a>_<b>.dz_pct": "dz error as % of the true floor-to-floor height",
    "floors.inter.dx_m": "average of floors.inter<a>_<b>.dx_m over adjacent pairs (the tables' Average row)",
    "floors.inter.dy_m": "average dy error",
    "floors.inter.dyaw_deg": "average yaw error",
    "floors.inter.dz_m": "average dz error",
    "floors.inter.dz_pct": "average dz error in %",
}

_CLOUD_KEYS = [k.split(".", 1)[1] for k in METRICS if k.startswith("cloud.") and "floor<k>" not in k]
_TRAJ_KEYS = [
    k.split(".", 1)[1]
    for k in METRICS
    if k.startswith("trajectory.") and not k.startswith(("trajectory.se3", "trajectory.4dof", "trajectory.floor"))
]


def _pattern(template: str) -> str:
    text = re.escape(template)
    text = text.replace(re.escape("<a>_<b>"), r"\d+_\d+")
    text = text.replace(re.escape("<k>"), r"\d+").replace(re.escape("<d>"), r"[0-9p]+cm")
    return text


def _build_regex() -> re.Pattern[str]:
    names: list[str] = []
    for key in METRICS:
        if "<any" in key:
            continue
        names.append(_pattern(key))
    names += [_pattern("cloud.floor<k>." + k) for k in _CLOUD_KEYS]
    names += [_pattern(f"trajectory.{a}." + k) for a in ("se3", "4dof") for k in _TRAJ_KEYS]
    return re.compile("^(?:" + "|".join(names) + ")$")


_KNOWN = _build_regex()


def is_metric_name(name: str) -> bool:
    """True when `name` is a documented metric (floor ids and thresholds filled in)."""
    return _KNOWN.match(name) is not None


def threshold_label(distance_m: float) -> str:
    """0.05 -> '5cm', 0.025 -> '2p5cm' (no dot, so names stay dotted paths)."""
    cm = round(distance_m * 100, 6)
    return f"{cm:g}".replace(".", "p") + "cm"


def parse_thresholds(items: list[str]) -> dict[str, float]:
    """`NAME=VALUE` strings from --fail-above -> {name: value}; bad syntax or name -> MfmapError."""
    out: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or not name or not value.strip():
            raise MfmapError(f"--fail-above expects METRIC=VALUE, got '{item}'")
        try:
            number = float(value)
        except ValueError as err:
            raise MfmapError(f"--fail-above {name}: '{value}' is not a number") from err
        if not math.isfinite(number):
            raise MfmapError(f"--fail-above {name}: value must be finite")
        if not is_metric_name(name):
            raise MfmapError(f"--fail-above: unknown metric '{name}' (see mfmap.eval.METRICS)")
        out[name] = number
    return out


@dataclass
class EvalResult:
    """Every figure of one evaluation: flat metrics plus the tables behind them."""

    build: Path
    inputs: dict[str, str]
    metrics: dict[str, float] = field(default_factory=dict)
    tables: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return {
            "build": str(self.build),
            "inputs": self.inputs,
            "metrics": {k: _finite(v) for k, v in sorted(self.metrics.items())},
            "tables": _clean(self.tables),
            "warnings": list(self.warnings),
        }

    def write_json(self, path: Path) -> None:
        """eval.json with every figure, written atomically."""
        from mfmap.atomic import write_text_atomic

        write_text_atomic(path, json.dumps(self.to_json(), indent=2) + "\n")

    def check_thresholds(self, thresholds: dict[str, float]) -> list[str]:
        """Human-readable failures of `--fail-above`; a metric this run lacks -> MfmapError."""
        failures: list[str] = []
        for name, limit in thresholds.items():
            if not is_metric_name(name):
                raise MfmapError(f"--fail-above: unknown metric '{name}' (see mfmap.eval.METRICS)")
            if name not in self.metrics:
                raise MfmapError(
                    f"--fail-above: metric '{name}' was not computed by this evaluation "
                    "(give the matching ground truth, or check the floor id)"
                )
            value = self.metrics[name]
            if not math.isfinite(value) or value > limit:
                failures.append(f"{name} = {value:.6g} is above {limit:.6g}")
        return failures


def _finite(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _clean(obj: Any) -> Any:
    if isinstance(obj, float):
        return _finite(obj)
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    return obj
