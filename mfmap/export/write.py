"""Everything in the output folder, written into `folder` (the pipeline's partial folder)."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mfmap.export.files import tum_text, write_bytes, write_json, write_ply, write_text, write_yaml
from mfmap.export.floorsjson import floors_json
from mfmap.export.grid import OccupancyGrid
from mfmap.export.mapdata import MapAccumulator
from mfmap.export.report import html_report, pressure_plot_png, side_view_png
from mfmap.graph.optimize import GraphResult
from mfmap.types import F64, FloorSegmentation, MappingResult

logger = logging.getLogger(__name__)


@dataclass
class Trajectory:
    stamps_ns: np.ndarray  # (N,) int64
    poses: np.ndarray  # (N, 4, 4)
    floor: np.ndarray  # (N,) int32, the keyframe's floor


@dataclass
class ExportSummary:
    files: list[str] = field(default_factory=list)
    points_per_floor: dict[int, int] = field(default_factory=dict)
    grid_cells: dict[int, dict[str, int]] = field(default_factory=dict)
    trajectory_poses: int = 0
    floors_doc: dict[str, Any] = field(default_factory=dict)


def optimised_trajectory(mapping: MappingResult, poses: dict[int, F64]) -> Trajectory:
    """Base pose at every lidar scan: optimised keyframe pose * ScanPose.relative."""
    floor_of = {k.id: k.floor_id for k in mapping.keyframes}
    items = sorted((sp for sp in mapping.scan_poses if sp.keyframe in poses), key=lambda s: s.stamp_ns)
    if not items:
        return Trajectory(np.zeros(0, np.int64), np.zeros((0, 4, 4)), np.zeros(0, np.int32))
    stamps = np.array([sp.stamp_ns for sp in items], dtype=np.int64)
    out = np.stack([poses[sp.keyframe] @ sp.relative for sp in items])
    floor = np.array([floor_of.get(sp.keyframe, -1) for sp in items], dtype=np.int32)
    return Trajectory(stamps, out, floor)


def elevations(graph: GraphResult, mapping: MappingResult) -> dict[int, float]:
    """Floor elevations from the optimised keyframes, relative to the starting floor."""
    if not graph.floor_z_m or not mapping.keyframes:
        return {}
    first = min(mapping.keyframes, key=lambda k: k.stamp_ns)
    ref = graph.floor_z_m.get(first.floor_id, 0.0)
    return {f: z - ref for f, z in graph.floor_z_m.items()}


def write_outputs(
    folder: Path,
    seg: FloorSegmentation,
    mapping: MappingResult,
    graph: GraphResult,
    trajectory: Trajectory,
    maps: MapAccumulator,
    report: dict[str, Any],
    config_yaml: str,
    title: str,
    html: bool = True,
) -> ExportSummary:
    """Write map.ply, trajectory.tum, floors.json, floors/<id>/..., report.json/html, config.yaml."""
    summary = ExportSummary()
    folder.mkdir(parents=True, exist_ok=True)

    write_text(folder / "trajectory.tum", tum_text(trajectory.stamps_ns, trajectory.poses))
    summary.trajectory_poses = int(trajectory.stamps_ns.shape[0])

    floors_doc = floors_json(seg, elevations(graph, mapping), trajectory.stamps_ns,
                             trajectory.poses[:, :3, 3] if len(trajectory.poses) else np.zeros((0, 3)))
    write_json(folder / "floors.json", floors_doc)
    summary.floors_doc = floors_doc

    clouds: list[np.ndarray] = []
    labels: list[np.ndarray] = []
    grid_pngs: dict[int, bytes] = {}
    for floor_id in maps.floor_ids():
        cloud = maps.cloud(floor_id)
        sub = folder / "floors" / str(floor_id)
        write_ply(sub / "cloud.ply", cloud)
        clouds.append(cloud)
        labels.append(np.full(cloud.shape[0], floor_id, dtype=np.int32))
        summary.points_per_floor[floor_id] = int(cloud.shape[0])
        on_floor = trajectory.floor == floor_id
        traj_xy = trajectory.poses[on_floor, :2, 3] if on_floor.any() else None
        grid: OccupancyGrid = maps.grid(floor_id, traj_xy)
        write_bytes(sub / "grid.pgm", grid.pgm_bytes())
        write_yaml(sub / "grid.yaml", grid.yaml_dict("grid.pgm"))
        png = grid.png_bytes(traj_xy)
        write_bytes(sub / "grid.png", png)
        grid_pngs[floor_id] = png
        summary.grid_cells[floor_id] = {
            "width": grid.shape[1],
            "height": grid.shape[0],
            "occupied": int(grid.occupied.sum()),
            "free": int(grid.free.sum()),
        }
    xyz = np.concatenate(clouds) if clouds else np.zeros((0, 3), np.float32)
    floor = np.concatenate(labels) if labels else np.zeros(0, np.int32)
    write_ply(folder / "map.ply", xyz, floor)

    report = dict(report)
    report["exports"] = {
        "points_per_floor": {str(k): v for k, v in summary.points_per_floor.items()},
        "grids": {str(k): v for k, v in summary.grid_cells.items()},
        "trajectory_poses": summary.trajectory_poses,
    }
    write_json(folder / "report.json", report)
    if html:
        pressure_png = pressure_plot_png(seg) if len(seg.stamp_ns) > 1 else None
        page = html_report(title, report, floors_doc, pressure_png, grid_pngs, side_view_png(xyz, floor))
        write_text(folder / "report.html", page)
    write_text(folder / "config.yaml", config_yaml)
    summary.files = sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())
    return summary
