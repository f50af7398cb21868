"""The building's outputs from several logs: each log's scans at the building's poses into the
floors' clouds and grids, then the usual files (`mfmap.export.write.write_outputs`) and one
trajectory per log."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mfmap.config import MfmapConfig, dump_config
from mfmap.export.cabin import Cabin, measure_from_log
from mfmap.export.files import tum_text, write_text
from mfmap.export.mapdata import MapAccumulator
from mfmap.export.scans import accumulate, add_depth_cameras
from mfmap.export.write import FloorTrajectory, write_outputs
from mfmap.graph.optimize import GraphResult
from mfmap.multilog.merge import (
    merge_cabins,
    merge_maps,
    merge_segmentations,
    merge_trajectories,
    rename_mapping,
    rename_segmentation,
)
from mfmap.progress import NullProgress
from mfmap.types import F64, FloorSegmentation, MappingResult

if TYPE_CHECKING:
    from mfmap.multilog.logs import LogRun
    from mfmap.multilog.place import Placement
    from mfmap.report import BuildReport


@dataclasses.dataclass
class _LogMaps:
    """One log's part of the building's outputs."""

    seg: FloorSegmentation
    mapping: MappingResult
    graph: GraphResult
    trajectory: FloorTrajectory
    maps: MapAccumulator
    cabins: list[Cabin]


def write_building_outputs(partial: Path, runs: list[LogRun], placement: Placement,
                           poses: dict[int, dict[int, F64]], cfg: MfmapConfig,
                           report: BuildReport) -> dict[str, Any]:
    """Every output file into `partial` (`poses`: per log, its keyframes' building-frame
    poses); returns floors.json's document."""
    final = placement.renumbered()
    floor_z = building_floor_z(runs, placement, poses, final)
    parts = [_log_maps(run, placement, final, poses[run.index], floor_z, cfg) for run in runs]
    maps = parts[0].maps
    for part in parts[1:]:
        merge_maps(maps, part.maps)
    seg = merge_segmentations([p.seg for p in parts])
    trajectory = merge_trajectories([p.trajectory for p in parts])
    # The building frame is the first log's start: elevations are relative to its floor.
    summary = write_outputs(
        partial, seg, parts[0].mapping, parts[0].graph, trajectory, maps, report,
        dump_config(cfg), title="mfmap build of " + ", ".join(r.name for r in runs),
        html=cfg.export.html_report, cabins=merge_cabins([c for p in parts for c in p.cabins]))
    for run, part in zip(runs, parts, strict=True):
        name = f"{run.index}-{run.path.stem}.tum"
        write_text(partial / "trajectories" / name,
                   tum_text(part.trajectory.stamps_ns, part.trajectory.poses))
    return summary.floors_doc


def _log_maps(run: LogRun, placement: Placement, final: dict[int, int], poses: dict[int, F64],
              floor_z: dict[int, float], cfg: MfmapConfig) -> _LogMaps:
    """One log's scans at the building's poses: its trajectory, its floors' maps, its cabins."""
    floors = {j: final[k] for j, k in placement.floors[run.index].items()}
    dz = float(placement.transforms[run.index][2, 3])
    seg = rename_segmentation(run.floors.seg, floors, {}, dz)
    mapping = rename_mapping(run.mapping, floors)
    graph = GraphResult(
        poses=poses, initial_poses=run.graph.poses, bias_m={}, stats={},
        floor_matches=[], floor_z_m=dict(floor_z), iterations=run.graph.iterations,
        error_initial=0.0, error_final=0.0, seconds=0.0)
    stages = run.stages
    progress = NullProgress()
    trajectory, maps = accumulate(run.src, seg, mapping, graph, stages.extrinsics, stages.cfg,
                                  progress, None)
    add_depth_cameras(run.src, stages.cameras, seg, trajectory, maps, stages.cfg,
                      stages.colour_cameras)
    cabins, _warnings = measure_from_log(run.src, seg, trajectory.stamps_ns, trajectory.poses,
                                         stages.extrinsics)
    return _LogMaps(seg, mapping, graph, trajectory, maps, cabins)


def building_floor_z(runs: list[LogRun], placement: Placement, poses: dict[int, dict[int, F64]],
                     final: dict[int, int]) -> dict[int, float]:
    """Each building floor's level: the median z of every log's keyframes on it."""
    zs: dict[int, list[float]] = {}
    for run in runs:
        floors = placement.floors[run.index]
        for kf in run.graph.keyframes:
            if kf.floor_id >= 0 and kf.floor_id in floors:
                zs.setdefault(final[floors[kf.floor_id]], []).append(
                    float(poses[run.index][kf.id][2, 3]))
    return {k: float(np.median(v)) for k, v in sorted(zs.items())}


__all__ = ["building_floor_z", "write_building_outputs"]
