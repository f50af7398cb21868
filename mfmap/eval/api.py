"""`evaluate`: score one build folder against whichever ground truth is given."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

from mfmap.errors import GroundTruthError, MfmapError, OutputError
from mfmap.eval.config import EvalConfig
from mfmap.eval.metrics import EvalResult

if TYPE_CHECKING:
    from mfmap.eval.io import FloorsFile, TumTrajectory

logger = logging.getLogger(__name__)

ALIGNMENTS = ("none", "se3", "4dof")


def evaluate(
    out_dir: Path,
    points: Path | None = None,
    cloud: Path | None = None,
    trajectory: Path | None = None,
    floors: Path | None = None,
    align: str = "none",
    config: EvalConfig | None = None,
) -> EvalResult:
    """Score the build in `out_dir`; each given ground-truth file adds its metrics and table."""
    from mfmap.eval import io

    cfg = config if config is not None else EvalConfig()
    _check_inputs(out_dir, points, cloud, trajectory, floors, align)
    inputs = {
        k: str(v)
        for k, v in (("points", points), ("cloud", cloud), ("trajectory", trajectory), ("floors", floors))
        if v is not None
    }
    result = EvalResult(build=out_dir, inputs=inputs)
    # The floors comparison uses the trajectory for yaw at the rides when there is one.
    wants_traj = points is not None or trajectory is not None or floors is not None
    est_traj = (
        io.read_tum(out_dir / "trajectory.tum", OutputError)
        if wants_traj and (out_dir / "trajectory.tum").is_file()
        else None
    )
    est_floors = io.read_floors_json(out_dir / "floors.json", OutputError)
    gt_traj = io.read_tum(trajectory) if trajectory is not None else None
    gt_floors = io.read_floors_json(floors) if floors is not None else None

    if points is not None:
        assert est_traj is not None
        _score_points(result, points, est_traj, est_floors)

    if trajectory is not None:
        assert est_traj is not None and gt_traj is not None
        # Per-floor figures over the true visits when given, else over the build's own.
        visits_file = gt_floors if gt_floors is not None else est_floors
        _score_trajectory(result, trajectory, est_traj, gt_traj, visits_file, align, cfg)

    if floors is not None:
        from mfmap.eval.floors import compare_floors

        assert gt_floors is not None
        comparison = compare_floors(est_floors, gt_floors, cfg.transition_match_s, est_traj, gt_traj)
        _add(result, "floors", comparison.metrics)
        result.tables["floors"] = {
            "floors": comparison.floors,
            "pairs": comparison.pairs,
            "rides": [vars(r) for r in comparison.rides],
        }

    if cloud is not None:
        _score_cloud(result, out_dir, cloud, est_floors, cfg)
    return result


def _check_inputs(
    out_dir: Path,
    points: Path | None,
    cloud: Path | None,
    trajectory: Path | None,
    floors: Path | None,
    align: str,
) -> None:
    """The alignment is known, some ground truth is given, and every file it needs exists."""
    from mfmap.eval import io

    if align not in ALIGNMENTS:
        raise MfmapError(f"unknown alignment '{align}' (choose from {', '.join(ALIGNMENTS)})")
    if points is None and cloud is None and trajectory is None and floors is None:
        raise MfmapError("nothing to evaluate: give --points, --cloud, --trajectory or --floors")
    needed: list[str] = []
    if points is not None or trajectory is not None:
        needed.append("trajectory.tum")
    needed.append("floors.json")  # floor ids, elevations and visits: every part uses them
    if cloud is not None:
        needed.append("map.ply")
    io.check_build(out_dir, needed)
    for given in (points, cloud, trajectory, floors):
        if given is not None and not given.is_file():
            raise GroundTruthError("file not found", given)


def _score_points(result: EvalResult, points: Path, est_traj: TumTrajectory, est_floors: FloorsFile) -> None:
    """Errors at the surveyed points, from the build's trajectory at their times."""
    from mfmap.eval import io
    from mfmap.eval.points import point_errors, points_metrics, points_table, spread_warnings

    errors = point_errors(io.read_points_csv(points), est_traj, est_floors.ids, points)
    _add(result, "points", points_metrics(errors))
    result.tables["points"] = points_table(errors)
    result.warnings += spread_warnings(errors)


def _score_trajectory(
    result: EvalResult,
    trajectory: Path,
    est_traj: TumTrajectory,
    gt_traj: TumTrajectory,
    visits_file: FloorsFile,
    align: str,
    cfg: EvalConfig,
) -> None:
    """Pose errors unaligned and, when asked, aligned; per-floor figures over the visits."""
    from mfmap.eval.trajectory import ape_metrics, per_floor_metrics, pose_errors

    visits = {f.id: list(f.visits_s) for f in visits_file.floors}
    variants = ["none"] if align == "none" else ["none", align]
    for variant in variants:
        try:
            errs = pose_errors(est_traj, gt_traj, cfg.max_time_diff_s, variant)
        except ValueError as err:
            raise GroundTruthError(
                f"{err}: no ground-truth stamp within {cfg.max_time_diff_s} s of the build's "
                f"trajectory ({est_traj.stamps_s[0]:.3f}..{est_traj.stamps_s[-1]:.3f} s)",
                trajectory,
            ) from err
        prefix = "trajectory" if variant == "none" else f"trajectory.{variant}"
        _add(result, prefix, ape_metrics(errs))
        if variant == "none" and visits:
            _add(result, prefix, per_floor_metrics(errs, visits))
        if variant != "none":
            result.tables[f"trajectory_{variant}_alignment"] = {
                "rotation": errs.align_rotation.tolist(),
                "translation_m": errs.align_translation.tolist(),
            }
    gt_span = (gt_traj.stamps_s[0], gt_traj.stamps_s[-1])
    paired = result.metrics["trajectory.pairs"]
    if paired < 0.5 * min(len(est_traj.stamps_s), len(gt_traj.stamps_s)):
        result.warnings.append(
            f"only {paired:.0f} poses paired with the ground truth "
            f"({gt_span[0]:.3f}..{gt_span[1]:.3f} s); check the time base"
        )


def _score_cloud(result: EvalResult, out_dir: Path, cloud: Path, est_floors: FloorsFile, cfg: EvalConfig) -> None:
    """Distances between the build's map.ply and the reference cloud, per floor when labelled."""
    from mfmap.eval import io
    from mfmap.eval.cloud import assign_floors_by_z, cloud_distances, cloud_metrics

    est_cloud = io.read_cloud(out_dir / "map.ply", OutputError)
    ref_cloud = io.read_cloud(cloud)
    ref_floor = ref_cloud.floor
    if ref_floor is None and est_cloud.floor is not None:
        elevations = {f.id: f.elevation_m for f in est_floors.floors}
        ref_floor = assign_floors_by_z(ref_cloud.xyz[:, 2], elevations, cfg.floor_z_margin_m)
    d = cloud_distances(est_cloud, ref_cloud, ref_floor)
    _add(result, "cloud", cloud_metrics(d, cfg.fscore_thresholds_m))
    if est_cloud.floor is None:
        result.warnings.append("map.ply has no 'floor' field: no per-floor cloud figures")


def _add(result: EvalResult, prefix: str, metrics: dict[str, float]) -> None:
    result.metrics.update({f"{prefix}.{k}": v for k, v in metrics.items()})
