"""`mfmap build`: log -> floors -> per-floor mapping -> building graph -> exports.

Reads like the pipeline it runs. Outputs are written into `OUT.partial-XXXX/` next to OUT and
renamed into place only when everything is written, so an interrupted build never leaves a
folder that looks complete; an existing OUT is replaced only with `force`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import time
from collections.abc import Iterator, Sequence
from concurrent.futures import Executor, Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from mfmap.config import MfmapConfig, dump_config
from mfmap.errors import MissingDataError
from mfmap.export.scans import accumulate
from mfmap.logs import WarningCollector, collect_warnings
from mfmap.mapping.source import read_scans
from mfmap.progress import NullProgress, Progress
from mfmap.report import (
    BuildReport,
    BuildResult,
    ReportSummary,
    connector_rows,
    floor_rows,
    transition_rows,
)
from mfmap.runfolder import RunFolder, input_size, log_folders
from mfmap.threads import unlimited_threads
from mfmap.types import (
    EdgeKind,
    Extrinsics,
    FloorSegmentation,
    ImuSeries,
    OdomSeries,
    PressureSeries,
    Role,
)

if TYPE_CHECKING:
    from contextlib import ExitStack

    from mfmap.export.cabin import Cabin
    from mfmap.export.mapdata import MapAccumulator
    from mfmap.export.write import FloorTrajectory
    from mfmap.graph.config import GraphConfig
    from mfmap.graph.optimize import GraphResult
    from mfmap.ingest.colour import ColourCamera
    from mfmap.ingest.depth import Camera
    from mfmap.ingest.source import LogSource
    from mfmap.mapping.config import MappingConfig
    from mfmap.types import MappingResult

logger = logging.getLogger(__name__)
# The stages' returned warnings, reported under their stage's name.
_ingest_log = logging.getLogger("mfmap.ingest")
_floors_log = logging.getLogger("mfmap.floors")
_mapping_log = logging.getLogger("mfmap.mapping")
_export_log = logging.getLogger("mfmap.export")


def build(
    log: Path,
    out: Path,
    cfg: MfmapConfig,
    force: bool = False,
    progress: Progress | None = None,
    inputs: Sequence[Path] = (),
) -> BuildResult:
    """Build the building map of `log` into the folder `out`.

    `out` is checked before any work (see `mfmap.runfolder.check_output`): never an input or a
    folder holding one (`inputs`: the config file and other files the caller read), never the
    working directory, and an existing one is replaced only with `force` when mfmap wrote it.

    Bit-for-bit reproducible only when the process called `mfmap.limit_threads()` before it
    imported this module (as `mfmap build` does); otherwise the report carries a warning.
    """
    started = time.perf_counter()
    progress = progress or NullProgress()
    log, out = Path(log), Path(out)
    # Checked before the heavy imports, so a refused output folder costs no time.
    run = RunFolder.create(out, [log, *inputs], log_folders(log), force, input_size(log))
    # The build's notes and the log's warnings lead the report; the others follow as they arose.
    with collect_warnings(first=("build", "ingest")) as collected, run.writing() as partial:
        for note in _notes(run):
            logger.warning(note)
        from mfmap.export.write import write_outputs
        from mfmap.ingest import open_log

        with open_log(log, cfg.ingest) as src, contextlib.ExitStack() as workers:
            stages = _Stages.start(log, src, cfg, progress, collected, workers)
            floors, mapping = stages.mapping(stages.floors())
            pressure_png = stages.pressure_figure(floors.seg)
            graph = stages.graph(mapping, floors)
            trajectory, maps, camera_images = stages.maps(floors.seg, mapping, graph)
            cabins = stages.cabins(floors.seg, trajectory)
            t0 = time.perf_counter()
            report = stages.report(floors, mapping, graph, maps, camera_images)
            with progress.stage("export", total=None):
                summary = write_outputs(
                    partial, floors.seg, mapping, graph, trajectory, maps, report,
                    dump_config(cfg),  # the user's configuration; the report has the decisions
                    title=f"mfmap build of {log.name}",
                    html=stages.cfg.export.html_report, pool=stages.pool,
                    pressure_png=pressure_png, cabins=cabins,
                )
        stages.timings["export"] = time.perf_counter() - t0
        elapsed = time.perf_counter() - started
        report.finish(elapsed)
        files = run.commit(report.to_json())
    doc = summary.floors_doc
    return BuildResult(
        log=log, out=out, log_duration_s=stages.log_duration_s, elapsed_s=elapsed,
        timings_s=stages.timings, floors=floor_rows(doc), transitions=transition_rows(doc),
        connectors=connector_rows(doc), counts=report.counts, graph=report.graph, files=files,
        warnings=report.warnings,
    )


def _notes(run: RunFolder) -> list[str]:
    """The build's own warnings: the output folder's notes, threads the build cannot limit."""
    threads = unlimited_threads()
    return [*run.notes, *([threads] if threads is not None else [])]


# ----- stages ------------------------------------------------------------------------------


@contextlib.contextmanager
def _timed(timings: dict[str, float], stage: str) -> Iterator[None]:
    t0 = time.perf_counter()
    yield
    timings[stage] = time.perf_counter() - t0


@dataclass(frozen=True)
class _Floors:
    """The floors stage's result and the configuration the later stages use with it."""

    pressure: PressureSeries | None
    seg: FloorSegmentation
    cfg: MfmapConfig  # with floors.temperature_k from the barometer's thermometer
    scale_sigma: float | None  # of the barometer's height scale; None: the graph's default


@dataclass
class _Stages:
    """One build's stages over an open log, and what they share: the resolved configuration,
    the mounts, the worker pool, the build's warnings and the timings."""

    log: Path
    src: LogSource
    cfg: MfmapConfig  # the user's, with every decision about how the sensors read
    extrinsics: Extrinsics
    cameras: list[Camera]
    colour_cameras: list[ColourCamera]
    progress: Progress
    pool: Executor | None
    collected: WarningCollector
    log_duration_s: float
    timings: dict[str, float] = field(default_factory=dict)

    @classmethod
    def start(cls, log: Path, src: LogSource, cfg: MfmapConfig, progress: Progress,
              collected: WarningCollector, workers: ExitStack) -> _Stages:
        """Check the lidar, start the worker pool, take the sensor decisions, find the cameras."""
        if Role.LIDAR not in src.roles and Role.SCAN2D not in src.roles:
            raise MissingDataError("the log has no lidar (neither PointCloud2 nor LaserScan)", log)
        check_lidar_density(src, cfg.mapping)
        pool = None
        if max(cfg.mapping.workers, cfg.export.workers) > 1:
            # With several floors, mapping (runs between rides) and the maps (floor groups)
            # run in processes, one pool for both. Started before the log's small streams
            # are read (every chunk of the file) and the floors are found: its first worker
            # imports open3d on a CPU of its own meanwhile, the second with its first job
            # (two-floor: the first chunk starts 3.0 s into the build instead of 3.8-4.1 s;
            # the median of five builds 21.78 s against 22.48 s, the same bytes).
            from mfmap.mapping.workers import MAPPING_MODULES, worker_pool

            pool = workers.enter_context(
                worker_pool(max(cfg.mapping.workers, cfg.export.workers), warm=1,
                            warm_modules=(*MAPPING_MODULES, "mfmap.export.mapdata")))
        # Every decision about how the sensors read (per-point time, beam order, mounts),
        # taken once here, so the worker processes read the log the same way; config.yaml
        # keeps the user's configuration, report.json the decisions.
        cfg = cfg.model_copy(update={"ingest": src.resolve()})
        extrinsics = src.extrinsics()
        # Before any work: a configured camera's problem stops the build here.
        cameras = find_depth_cameras(src, cfg)
        from mfmap.ingest.colour import colour_cameras as find_colour_cameras

        colour_cameras, colour_warnings = find_colour_cameras(src, cameras, cfg.camera)
        for text in colour_warnings:
            _export_log.warning(text)
        log_duration_s = max((src.end_ns - src.start_ns) / 1e9, 0.0)
        return cls(log, src, cfg, extrinsics, cameras, list(colour_cameras), progress, pool,
                   collected, log_duration_s)

    def floors(self) -> _Floors:
        from mfmap.floors.pipeline import barometer_temperature

        with _timed(self.timings, "floors"):
            stage_cfg, scale_sigma = barometer_temperature(self.src, self.cfg)
            pressure, seg = segment_floors(self.src, stage_cfg)
            for text in seg.warnings:
                _floors_log.warning(text)
        if len(seg.floors) < 2:
            self.pool = None  # one floor: mapped in this process, its map by this process
        return _Floors(pressure, seg, stage_cfg, scale_sigma)

    def mapping(self, floors: _Floors) -> tuple[_Floors, MappingResult]:
        """The floors' maps; without a barometer, the floors again from the lidar's stair walks
        when it climbed within a visit, and the maps of those floors."""
        from mfmap.floors.nobaro import floors_with_walks

        mapping = self._map(floors.seg)
        if floors.pressure is None:
            seg = floors_with_walks(floors.seg, mapping.keyframes, self.src.imu(), self.cfg.floors,
                                    self.src.start_ns, self.src.end_ns)
            if seg is not floors.seg:
                floors = dataclasses.replace(floors, seg=seg)
                mapping = self._map(seg)  # its warnings, not the first pass's
            self._refuse_climbs(mapping)
        for text in mapping.warnings:
            _mapping_log.warning(text)
        return floors, mapping

    def _map(self, seg: FloorSegmentation) -> MappingResult:
        from mfmap.mapping import map_floors

        t0 = time.perf_counter()
        mapping = map_floors(self.src, seg, self.cfg.mapping, self.extrinsics, self.progress,
                             self.pool)
        self.timings["mapping"] = self.timings.get("mapping", 0.0) + time.perf_counter() - t0
        if not mapping.keyframes:
            raise MissingDataError("no keyframes: the lidar gave no usable scans", self.log)
        return mapping

    def _refuse_climbs(self, mapping: MappingResult) -> None:
        """A climb of a floor's height left within one visit (no level to end it on): the floors
        cannot be told apart."""
        from mfmap.floors.nobaro import climb_left

        climb = climb_left(mapping.keyframes, self.cfg.floors.min_floor_height_m)
        if climb is not None:
            raise MissingDataError(
                f"no barometer in the log, and the lidar odometry {climb} with no floor to end "
                "on: the floors cannot be told apart without the barometer (topic role 'baro')",
                self.log,
            )

    def pressure_figure(self, seg: FloorSegmentation) -> Future[bytes] | None:
        """report.html's pressure figure, drawn by a worker, idle while this process runs the
        graph (matplotlib's import and the drawing: 0.9 s of two-floor's export)."""
        if self.pool is None or not self.cfg.export.html_report or len(seg.stamp_ns) <= 1:
            return None
        from mfmap.export.report import pressure_plot_png

        return self.pool.submit(pressure_plot_png, seg)

    def graph(self, mapping: MappingResult, floors: _Floors) -> GraphResult:
        with _timed(self.timings, "graph"):
            graph = optimise(mapping, floors.seg, floors.pressure, self.src.imu(), self.extrinsics,
                             floors.cfg, self.progress, odom=self.src.odometry(), pool=self.pool,
                             scale_prior_sigma=floors.scale_sigma)
        return graph

    def maps(self, seg: FloorSegmentation, mapping: MappingResult,
             graph: GraphResult) -> tuple[FloorTrajectory, MapAccumulator, dict[str, int]]:
        """The second pass over the scans (and the depth cameras): the floors' clouds and grids."""
        from mfmap.export.scans import add_depth_cameras

        with _timed(self.timings, "accumulate"):
            trajectory, maps = accumulate(self.src, seg, mapping, graph, self.extrinsics, self.cfg,
                                          self.progress, self.pool)
            camera_images = add_depth_cameras(self.src, self.cameras, seg, trajectory, maps, self.cfg,
                                              self.colour_cameras)
        return trajectory, maps, camera_images

    def cabins(self, seg: FloorSegmentation, trajectory: FloorTrajectory) -> list[Cabin]:
        """The scans in the elevator cabins, left out of the maps, measure the cabins."""
        from mfmap.export.cabin import measure_from_log

        with _timed(self.timings, "cabins"):
            cabins, cabin_warnings = measure_from_log(self.src, seg, trajectory.stamps_ns,
                                                      trajectory.poses, self.extrinsics)
            for text in cabin_warnings:
                _export_log.warning(text)
        return cabins

    def report(self, floors: _Floors, mapping: MappingResult, graph: GraphResult,
               maps: MapAccumulator, camera_images: dict[str, int]) -> BuildReport:
        """report.json as far as the stages know it (the exports add theirs)."""
        seg, pressure = floors.seg, floors.pressure
        counts = {
            "floors": len(seg.floors),
            "transitions": len(seg.transitions),
            "keyframes": len(mapping.keyframes),
            "edges": len(mapping.edges),
            "loop_edges": sum(1 for e in mapping.edges if e.kind == EdgeKind.LOOP),
            "scans": len(mapping.scan_poses),
            "scans_exported": maps.scans,
            **({"depth_images": maps.images} if camera_images else {}),
            "pressure_samples": len(pressure) if pressure is not None else 0,
        }
        # Reading the barometer, the IMU or the scans can warn at any stage: the log's
        # warnings are complete only now.
        for text in self.src.warnings:
            _ingest_log.warning(text)
        summary = ReportSummary(len(seg.floors), len(seg.transitions), self.log_duration_s,
                                len(mapping.keyframes))
        return BuildReport(
            log=str(self.log), ingest=self.src.report(), summary=summary, counts=counts,
            timings_s=self.timings, mapping={k: float(v) for k, v in mapping.stats.items()},
            graph=graph.to_json(), warnings=self.collected.lines(),
        )


def segment_floors(
    src: LogSource, cfg: MfmapConfig
) -> tuple[PressureSeries | None, FloorSegmentation]:
    """Barometer -> floors. A log without barometer: floors from the IMU's elevator rides, or one
    floor when it feels none; with a warning (logged) either way."""
    from mfmap.floors.imu import ImuTiming
    from mfmap.floors.motion import motion_from_imu, motion_from_odometry
    from mfmap.floors.segment import segment_pressure

    try:
        pressure = src.pressure()
    except MissingDataError:
        from mfmap.floors.nobaro import floors_from_rides
        from mfmap.graph.ride import find_rides

        # Inside a closed cabin the lidar cannot see a ride; the accelerometer can.
        rides = find_rides(src.imu(), cfg.floors.min_floor_height_m)
        changes = [(r.start_ns, r.end_ns, float(r.height_change_m or 0.0)) for r in rides]
        return None, floors_from_rides(changes, src.start_ns, src.end_ns, cfg.floors)
    odom = src.odometry()
    imu = src.imu()
    motion = None
    if odom is not None and len(odom) > 1:
        motion = motion_from_odometry(odom, cfg.floors)
    elif imu is not None and len(imu) > 1:
        motion = motion_from_imu(imu, cfg.floors)
    return pressure, segment_pressure(pressure, motion, cfg.floors, ImuTiming.of(imu))


def check_lidar_density(src: LogSource, cfg: MappingConfig, scans: int = 20) -> None:
    """Refuse a lidar whose scans hold too few usable points for scan registration (a radar's
    cloud, or every return NaN), before any work: from the median of its first `scans` scans.

    A sparse radar once ran through mapping to a trajectory that flew off and a grid too big to
    allocate; an all-NaN lidar to an empty map.ply and no grids.
    """
    planar = Role.LIDAR not in src.roles
    need = cfg.min_beams_per_scan if planar else cfg.min_points_per_scan
    if need <= 0:
        return
    counts: list[int] = []
    for _stamp, _frame, xyz, _t in read_scans(src, planar):
        rng = np.linalg.norm(xyz, axis=1)
        counts.append(int(np.count_nonzero((rng > cfg.min_range_m) & (rng < cfg.max_range_m))))
        if len(counts) >= scans:
            break
    if not counts:
        return  # no scan at all: the mapping stage says so
    median = float(np.median(counts))
    if median < need:
        topic = src.roles.get(Role.SCAN2D if planar else Role.LIDAR)
        what = "returns" if planar else "points"
        raise MissingDataError(
            f"too few points per scan for lidar odometry: the first {len(counts)} scans of "
            f"{topic} hold a median of {median:.0f} {what} between {cfg.min_range_m:g} and "
            f"{cfg.max_range_m:g} m, at least {need} are needed (a radar, or a sensor whose "
            f"returns are all NaN?); mapping.{'min_beams_per_scan' if planar else 'min_points_per_scan'} "
            "sets the limit", src.path)


def optimise(
    mapping: MappingResult,
    seg: FloorSegmentation,
    pressure: PressureSeries | None,
    imu: ImuSeries | None,
    extrinsics: Extrinsics,
    cfg: MfmapConfig,
    progress: Progress,
    odom: OdomSeries | None = None,
    pool: Executor | None = None,
    scale_prior_sigma: float | None = None,
) -> GraphResult:
    from mfmap.graph.gravity import gravity_at_keyframes
    from mfmap.graph.optimize import optimize_building

    gravity = gravity_at_keyframes(imu, mapping.keyframes, extrinsics,
                                   odom=odom if cfg.graph.gravity.minus_odometry else None)
    graph_seg, graph_cfg = graph_floors(seg, pressure, cfg.graph)
    return optimize_building(
        mapping.keyframes,
        mapping.edges,
        graph_seg,
        pressure,
        graph_cfg,
        temperature_k=cfg.floors.temperature_k,
        gravity_body=gravity,
        progress=progress,
        imu=imu,
        executor=pool,
        scale_prior_sigma=scale_prior_sigma,
    )


def graph_floors(seg: FloorSegmentation, pressure: PressureSeries | None,
                 cfg: GraphConfig) -> tuple[FloorSegmentation | None, GraphConfig]:
    """The floors the graph ties together and its configuration for them: none without a
    barometer unless the IMU's rides made floors, whose heights are then the rides', not a
    barometer's to fit."""
    if pressure is not None:
        return seg, cfg
    if not seg.transitions:
        return None, cfg
    return seg, cfg.model_copy(update={
        "ablation": cfg.ablation.model_copy(update={"transition_height": False})})


def find_depth_cameras(src: LogSource, cfg: MfmapConfig) -> list[Camera]:
    """The log's usable depth cameras; a discovered camera that cannot be used is the log's
    warning (the lidar carries the build), a configured one raises CameraProblem."""
    if not cfg.camera.enabled:
        return []
    from mfmap.ingest.depth import find_cameras

    cameras, warnings = find_cameras(src, cfg.camera)
    for text in warnings:
        if text not in src.warnings:
            src.warnings.append(text)
    return cameras


__all__ = ["BuildResult", "accumulate", "build", "graph_floors", "optimise", "segment_floors"]
