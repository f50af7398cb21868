"""Everything in the output folder, written into `folder` (the pipeline's partial folder)."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from concurrent.futures import Executor, Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from mfmap.atomic import atomic_open
from mfmap.export.cabin import Cabin
from mfmap.export.files import tum_text, write_bytes, write_json, write_ply, write_text, write_yaml
from mfmap.export.floorsjson import floors_json
from mfmap.export.foxglove import FloorMap, layout_json, write_mcap
from mfmap.export.grid import OccupancyGrid
from mfmap.export.mapdata import MapAccumulator
from mfmap.export.nav2 import floors_index
from mfmap.export.report import html_report, pressure_plot_png, side_view_png, side_view_sample
from mfmap.export.rmf import building_yaml
from mfmap.export.viewer import view_data, view_html
from mfmap.graph.optimize import GraphResult
from mfmap.report import BuildReport
from mfmap.types import F64, FloorSegmentation, MappingResult

logger = logging.getLogger(__name__)


@dataclass
class FloorTrajectory:
    """The optimised pose of every scan, with the floor of its keyframe."""

    stamps_ns: np.ndarray  # (N,) int64
    poses: np.ndarray  # (N, 4, 4)
    floor: np.ndarray  # (N,) int32, the keyframe's floor


@dataclass
class ExportSummary:
    points_per_floor: dict[int, int] = field(default_factory=dict)
    grid_cells: dict[int, dict[str, int]] = field(default_factory=dict)
    trajectory_poses: int = 0
    floors_doc: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)  # what the exports could not hold


def optimised_trajectory(mapping: MappingResult, poses: dict[int, F64],
                         rides: Sequence[tuple[int, int]] = (),
                         walks: Sequence[tuple[int, int]] = ()) -> FloorTrajectory:
    """Base pose at every lidar scan: optimised keyframe pose * ScanPose.relative.

    `rides` are elevator rides and `walks` stair walks (start_ns, end_ns). Their scans hang off
    the last keyframe before them, and the next floor's off its first keyframe: where the graph
    moved the two apart (floor registration against the lidar's own chain) the trajectory would
    jump at the end. A ride's scans, metres below the cabin's end, would also swing centimetres
    sideways with a tenth of a degree of tilt in that keyframe. So a ride's scans are put
    between the poses just before and just after it (x, y and rotation interpolated in time, z
    along the ride's own height profile scaled to the ends), and a walk's end jump is spread
    over the walk, growing with time.
    """
    floor_of = {k.id: k.floor_id for k in mapping.keyframes}
    items = sorted((sp for sp in mapping.scan_poses if sp.keyframe in poses), key=lambda s: s.stamp_ns)
    if not items:
        return FloorTrajectory(np.zeros(0, np.int64), np.zeros((0, 4, 4)), np.zeros(0, np.int32))
    stamps = np.array([sp.stamp_ns for sp in items], dtype=np.int64)
    out = np.stack([poses[sp.keyframe] @ sp.relative for sp in items])
    floor = np.array([floor_of.get(sp.keyframe, -1) for sp in items], dtype=np.int32)
    for start_ns, end_ns in rides:
        _between_ride_ends(stamps, out, start_ns, end_ns)
    for start_ns, end_ns in walks:
        _spread_walk_jump(stamps, out, floor, start_ns, end_ns)
    return FloorTrajectory(stamps, out, floor)


def _slerp(r0: np.ndarray, r1: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Rotation matrices from r0 (t = 0) to r1 (t = 1) at the fractions t."""
    return np.asarray(Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([r0, r1])))(t).as_matrix())


def _between_ride_ends(stamps: np.ndarray, out: np.ndarray, start_ns: int, end_ns: int) -> None:
    lo = int(np.searchsorted(stamps, start_ns, side="left"))
    hi = int(np.searchsorted(stamps, end_ns, side="right"))
    if lo == 0 or hi >= len(stamps) or hi <= lo:
        return
    a, b = out[lo - 1].copy(), out[hi].copy()
    t = (stamps[lo:hi] - stamps[lo - 1]) / float(stamps[hi] - stamps[lo - 1])
    rot = _slerp(a[:3, :3], b[:3, :3], t)
    profile = out[lo:hi, 2, 3] - a[2, 3]
    span = float(out[hi - 1, 2, 3] - a[2, 3])
    rise = float(b[2, 3] - a[2, 3])
    z = a[2, 3] + (profile * (rise / span) if abs(span) > 0.05 * max(abs(rise), 1e-3) else t * rise)
    out[lo:hi, :3, :3] = rot
    out[lo:hi, :2, 3] = a[None, :2, 3] + t[:, None] * (b[:2, 3] - a[:2, 3])[None, :]
    out[lo:hi, 2, 3] = z


def _spread_walk_jump(stamps: np.ndarray, out: np.ndarray, floor: np.ndarray, start_ns: int,
                      end_ns: int) -> None:
    lo = int(np.searchsorted(stamps, start_ns, side="left"))
    changes = np.flatnonzero(floor[lo + 1:] != floor[lo:-1]) + lo + 1
    if lo == 0 or len(changes) == 0:
        return
    hi = int(changes[0])  # the first scan on the next floor's keyframes
    if hi - lo < 2 or stamps[hi - 1] > end_ns + 10 * (end_ns - start_ns):
        return  # too few scans, or no keyframe on the next floor anywhere near the walk's end
    # Where the walk's last scan says the next one is (its own motion, constant velocity)...
    step = np.linalg.inv(out[hi - 2]) @ out[hi - 1]
    gaps = np.diff(stamps[hi - 2:hi + 1]).astype(np.float64)
    if not 0.5 <= gaps[1] / max(gaps[0], 1.0) <= 2.0:
        step = np.eye(4)
    jump = out[hi] @ np.linalg.inv(out[hi - 1] @ step)
    # ...and the world correction that puts it there, grown from none at the walk's start.
    t = (stamps[lo:hi] - stamps[lo - 1]) / float(stamps[hi - 1] - stamps[lo - 1])
    rot = _slerp(np.eye(3), jump[:3, :3], t)
    corr = np.tile(np.eye(4), (len(t), 1, 1))
    corr[:, :3, :3] = rot
    corr[:, :3, 3] = t[:, None] * jump[None, :3, 3]
    out[lo:hi] = corr @ out[lo:hi]


def elevations(graph: GraphResult, mapping: MappingResult) -> dict[int, float]:
    """Floor elevations from the optimised keyframes, relative to the starting floor."""
    if not graph.floor_z_m or not mapping.keyframes:
        return {}
    first = min(mapping.keyframes, key=lambda k: k.stamp_ns)
    ref = graph.floor_z_m.get(first.floor_id, 0.0)
    return {f: z - ref for f, z in graph.floor_z_m.items()}


def cabin_json(cabin: Cabin) -> dict[str, Any]:
    """A measured cabin for report.json."""
    return {"x": cabin.x_m, "y": cabin.y_m, "yaw_rad": cabin.yaw_rad,
            "inner_width_m": cabin.inner_width_m, "inner_depth_m": cabin.inner_depth_m,
            "floors": list(cabin.floors), "rides": cabin.rides, "scans": cabin.scans,
            "doors": {str(f): {"side": d.side, "offset_m": d.offset_m, "width_m": d.width_m,
                               "open_share": d.open_share} for f, d in sorted(cabin.doors.items())}}


def write_building(folder: Path, title: str, floors_doc: dict[str, Any], clouds: dict[int, np.ndarray],
                   grids: dict[int, OccupancyGrid], elevation: dict[int, float],
                   cabins: Sequence[Cabin], trajectory: FloorTrajectory) -> list[str]:
    """map.mcap and its Foxglove layout, building.yaml, floors/index.yaml; their warnings."""
    floors = [FloorMap(f, elevation.get(f, 0.0), clouds[f], grids.get(f)) for f in sorted(clouds)]
    with atomic_open(folder / "map.mcap", "wb") as f:
        write_mcap(f, floors, floors_doc, list(cabins), trajectory.stamps_ns, trajectory.poses)
    write_text(folder / "foxglove_layout.json", layout_json(floors))
    index, warnings = floors_index(floors_doc, {f: f"{f}/grid.yaml" for f in grids},
                                   trajectory.stamps_ns, trajectory.poses)
    write_yaml(folder / "floors" / "index.yaml", index)
    images = {f: {"image": f"floors/{f}/grid.pgm", "resolution": g.resolution_m,
                  "origin": [float(g.origin_xy[0]), float(g.origin_xy[1])], "height": g.shape[0]}
              for f, g in grids.items()}
    building, more = building_yaml(title, floors_doc, images, list(cabins), index)
    write_yaml(folder / "building.yaml", building)
    return warnings + more


def write_outputs(
    folder: Path,
    seg: FloorSegmentation,
    mapping: MappingResult,
    graph: GraphResult,
    trajectory: FloorTrajectory,
    maps: MapAccumulator,
    report: BuildReport,
    config_yaml: str,
    title: str,
    html: bool = True,
    pool: Executor | None = None,
    pressure_png: Future[bytes] | None = None,
    cabins: Sequence[Cabin] = (),
) -> ExportSummary:
    """Write map.ply, trajectory.tum, floors.json, floors/<id>/..., map.mcap, building.yaml,
    floors/index.yaml, report.html, config.yaml; `report` gains the exports' warnings and
    figures (report.json is the run folder's last file, see `RunFolder.commit`).

    With `pool`, report.html's side view is drawn by a worker while the files are written;
    `pressure_png` is the pressure figure, already submitted to one.
    """
    summary = ExportSummary()
    folder.mkdir(parents=True, exist_ok=True)

    write_text(folder / "trajectory.tum", tum_text(trajectory.stamps_ns, trajectory.poses))
    summary.trajectory_poses = int(trajectory.stamps_ns.shape[0])

    floors_doc = floors_json(seg, elevations(graph, mapping), trajectory.stamps_ns,
                             trajectory.poses[:, :3, 3] if len(trajectory.poses) else np.zeros((0, 3)))
    write_json(folder / "floors.json", floors_doc)
    summary.floors_doc = floors_doc

    clouds = {floor_id: maps.cloud(floor_id) for floor_id in maps.floor_ids()}
    colours = {floor_id: maps.colours(floor_id) for floor_id in maps.floor_ids()}
    xyz = np.concatenate(list(clouds.values())) if clouds else np.zeros((0, 3), np.float32)
    floor = (np.concatenate([np.full(c.shape[0], f, dtype=np.int32) for f, c in clouds.items()])
             if clouds else np.zeros(0, np.int32))
    side_view: Future[bytes] | None = None
    if html and pool is not None:
        side_view = pool.submit(side_view_png, *side_view_sample(xyz, floor))
    grids, grid_pngs = _write_floors(folder, maps, clouds, colours, trajectory, summary)
    write_ply(folder / "map.ply", xyz, floor, _map_colours(clouds, colours))
    elevation = {f["id"]: float(f["elevation_m"]) for f in floors_doc["floors"]}
    export_warnings = write_building(folder, title, floors_doc, clouds, grids, elevation, cabins,
                                     trajectory)

    summary.warnings = [f"export: {w}" for w in export_warnings]
    _add_exports(report, summary, cabins)
    if html:
        pressure = pressure_png.result() if pressure_png is not None else _pressure_figure(seg)
        side = side_view.result() if side_view is not None else side_view_png(*side_view_sample(xyz, floor))
        view = view_html(view_data(clouds, elevation, trajectory.poses[:, :3, 3] if len(trajectory.poses)
                                   else np.zeros((0, 3)), floors_doc, cabins))
        page = html_report(title, report.to_json(), floors_doc, pressure, grid_pngs, side, view)
        write_text(folder / "report.html", page)
    write_text(folder / "config.yaml", config_yaml)
    return summary


def _add_exports(report: BuildReport, summary: ExportSummary, cabins: Sequence[Cabin]) -> None:
    """The exports' warnings and figures into the report."""
    report.warnings = [*report.warnings, *summary.warnings]
    report.exports = {
        "points_per_floor": {str(k): v for k, v in summary.points_per_floor.items()},
        "grids": {str(k): v for k, v in summary.grid_cells.items()},
        "trajectory_poses": summary.trajectory_poses,
        "cabins": [cabin_json(c) for c in cabins],
    }


def _pressure_figure(seg: FloorSegmentation) -> bytes | None:
    return pressure_plot_png(seg) if len(seg.stamp_ns) > 1 else None


def _write_floors(folder: Path, maps: MapAccumulator, clouds: dict[int, np.ndarray],
                  colours: dict[int, np.ndarray | None], trajectory: FloorTrajectory,
                  summary: ExportSummary) -> tuple[dict[int, OccupancyGrid], dict[int, bytes]]:
    """floors/<id>/cloud.ply and the grid files; the grids and their PNGs (for report.html)."""
    grid_pngs: dict[int, bytes] = {}
    grids: dict[int, OccupancyGrid] = {}
    for floor_id, cloud in clouds.items():
        sub = folder / "floors" / str(floor_id)
        write_ply(sub / "cloud.ply", cloud, rgb=colours[floor_id])
        summary.points_per_floor[floor_id] = int(cloud.shape[0])
        on_floor = trajectory.floor == floor_id
        traj_xy = trajectory.poses[on_floor, :2, 3] if on_floor.any() else None
        grid: OccupancyGrid = maps.grid(floor_id, traj_xy)
        grids[floor_id] = grid
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
    return grids, grid_pngs


def _map_colours(clouds: dict[int, np.ndarray], colours: dict[int, np.ndarray | None]) -> np.ndarray | None:
    """map.ply's colours: the floors' own, grey for a floor without; None when no floor has any."""
    if not any(c is not None for c in colours.values()):
        return None
    grey = np.full((0, 3), 128, np.uint8)
    return np.concatenate([c if c is not None else np.full((clouds[f].shape[0], 3), 128, np.uint8)
                           for f, c in colours.items()] or [grey])
