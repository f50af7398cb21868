"""`mfmap build`: log -> floors -> per-floor mapping -> building graph -> exports.

Reads like the pipeline it runs. Outputs are written into `OUT.partial-XXXX/` next to OUT and
renamed into place only when everything is written, so an interrupted build never leaves a
folder that looks complete; an existing OUT is replaced only with `force`.
"""

from __future__ import annotations

import contextlib
import logging
import math
import resource
import time
from collections.abc import Iterator, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mfmap.atomic import disk_error, is_disk_error
from mfmap.config import MfmapConfig, dump_config
from mfmap.errors import MissingDataError, OutputError
from mfmap.mapping.geometry import (
    deskew,
    gyro_bias,
    inverse,
    rotation_angle_rad,
    rotations_to,
    still_mask,
    twist,
)
from mfmap.progress import NullProgress, Progress, StageProgress
from mfmap.runfolder import RunFolder, input_size
from mfmap.threads import unlimited_threads
from mfmap.types import (
    F64,
    I64,
    Extrinsics,
    Floor,
    FloorSegmentation,
    ImuSeries,
    Keyframe,
    OdomSeries,
    PressureSeries,
    Role,
    TransitionKind,
)

if TYPE_CHECKING:
    from rich.console import RenderableType

    from mfmap.export.mapdata import MapAccumulator
    from mfmap.export.write import Trajectory
    from mfmap.graph.optimize import GraphResult
    from mfmap.ingest.colour import ColourCamera
    from mfmap.ingest.depth import Camera
    from mfmap.ingest.source import LogSource
    from mfmap.mapping.config import MappingConfig
    from mfmap.types import MappingResult

logger = logging.getLogger(__name__)


@dataclass
class BuildResult:
    """What `mfmap build` did and where its outputs are."""

    log: Path
    out: Path
    log_duration_s: float
    elapsed_s: float
    timings_s: dict[str, float]
    floors: list[dict[str, Any]]
    transitions: list[dict[str, Any]]
    connectors: list[dict[str, Any]]
    counts: dict[str, int]
    graph: dict[str, Any]
    files: list[str]
    warnings: list[str] = field(default_factory=list)

    @property
    def realtime_factor(self) -> float:
        """Log duration / build time (above 1: faster than real time)."""
        return self.log_duration_s / self.elapsed_s if self.elapsed_s > 0 else math.inf


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
    run = RunFolder.create(out, [log, *inputs], _log_folders(log), force, input_size(log))
    partial = run.partial
    timings: dict[str, float] = {}
    warnings: list[str] = [f"build: {note}" for note in run.notes]
    threads = unlimited_threads()
    if threads is not None:
        warnings.append(f"build: {threads}")
    try:
        from mfmap.export.write import write_outputs
        from mfmap.ingest import open_log

        with open_log(log, cfg.ingest) as src, contextlib.ExitStack() as workers:
            # The ingest warnings are copied last: reading the barometer, the IMU or the scans
            # can warn too, at any stage.
            ingest_at = len(warnings)
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
            given = cfg
            cfg = cfg.model_copy(update={"ingest": src.resolve()})
            extrinsics = src.extrinsics()
            # Before any work: a configured camera's problem stops the build here.
            cameras = find_depth_cameras(src, cfg)
            from mfmap.ingest.colour import colour_cameras as find_colour_cameras

            colour_cameras, colour_warnings = find_colour_cameras(src, cameras, cfg.camera)
            warnings += [f"export: {w}" for w in colour_warnings]
            log_duration_s = max((src.end_ns - src.start_ns) / 1e9, 0.0)

            t0 = time.perf_counter()
            from mfmap.floors.pipeline import barometer_temperature

            stage_cfg, scale_sigma = barometer_temperature(src, cfg, warnings)
            pressure, seg = segment_floors(src, stage_cfg, warnings)
            warnings += [f"floors: {w}" for w in seg.warnings]
            timings["floors"] = time.perf_counter() - t0
            if len(seg.floors) < 2:
                pool = None  # one floor: mapped in this process, its map by this process
            from mfmap.mapping import map_floors

            t0 = time.perf_counter()
            mapping = map_floors(src, seg, cfg.mapping, extrinsics, progress, pool)
            warnings += [f"mapping: {w}" for w in mapping.warnings]
            timings["mapping"] = time.perf_counter() - t0
            if not mapping.keyframes:
                raise MissingDataError("no keyframes: the lidar gave no usable scans", log)
            if pressure is None:
                climb = lidar_floor_change(mapping.keyframes, cfg.floors.min_floor_height_m)
                if climb is not None:
                    raise MissingDataError(
                        f"no barometer in the log, but the lidar odometry {climb}: the robot changed "
                        "floors, and a multi-floor map needs the barometer (topic role 'baro')",
                        log,
                    )

            pressure_png = None
            if pool is not None and cfg.export.html_report and len(seg.stamp_ns) > 1:
                # The report's figures are drawn by a worker, idle while this process runs the
                # graph (matplotlib's import and the drawing: 0.9 s of two-floor's export).
                from mfmap.export.report import pressure_plot_png

                pressure_png = pool.submit(pressure_plot_png, seg)

            t0 = time.perf_counter()
            graph = optimise(mapping, seg, pressure, src.imu(), extrinsics, stage_cfg, progress,
                             odom=src.odometry(), pool=pool, scale_prior_sigma=scale_sigma)
            warnings += graph.warnings
            timings["graph"] = time.perf_counter() - t0

            t0 = time.perf_counter()
            trajectory, maps = accumulate(src, seg, mapping, graph, extrinsics, cfg, progress, pool)
            camera_images = add_depth_cameras(src, cameras, seg, trajectory, maps, cfg, colour_cameras)
            timings["accumulate"] = time.perf_counter() - t0

            from mfmap.export.cabin import measure_from_log

            t0 = time.perf_counter()
            # The scans in the elevator cabins, left out of the maps, measure the cabins.
            cabins, cabin_warnings = measure_from_log(src, seg, trajectory.stamps_ns,
                                                      trajectory.poses, extrinsics)
            warnings += [f"export: {w}" for w in cabin_warnings]
            timings["cabins"] = time.perf_counter() - t0

            t0 = time.perf_counter()
            counts = {
                "floors": len(seg.floors),
                "transitions": len(seg.transitions),
                "keyframes": len(mapping.keyframes),
                "edges": len(mapping.edges),
                "loop_edges": sum(1 for e in mapping.edges if e.kind == "loop"),
                "scans": len(mapping.scan_poses),
                "scans_exported": maps.scans,
                **({"depth_images": maps.images} if camera_images else {}),
                "pressure_samples": len(pressure) if pressure is not None else 0,
            }
            warnings[ingest_at:ingest_at] = [f"ingest: {w}" for w in src.warnings]
            report: dict[str, Any] = {
                "log": str(log),
                "ingest": src.report(),
                "summary": {
                    "floors": len(seg.floors),
                    "transitions": len(seg.transitions),
                    "log_duration_s": round(log_duration_s, 3),
                    "keyframes": len(mapping.keyframes),
                },
                "counts": counts,
                "timings_s": {k: round(v, 3) for k, v in timings.items()},
                "mapping": {k: float(v) for k, v in mapping.stats.items()},
                "graph": graph.to_json(),
                "warnings": warnings,
            }
            with progress.stage("export", total=None):
                summary = write_outputs(
                    partial, seg, mapping, graph, trajectory, maps, report, dump_config(given),
                    title=f"mfmap build of {log.name}", html=cfg.export.html_report,
                    pool=pool, pressure_png=pressure_png, cabins=cabins,
                )
                warnings += summary.warnings
        timings["export"] = time.perf_counter() - t0
        elapsed = time.perf_counter() - started
        _finish_report(partial, timings, elapsed, log_duration_s)
        run.commit()
    except OSError as err:
        run.discard()
        if is_disk_error(err):
            raise disk_error(err, out) from err
        raise
    except OutputError as err:
        run.discard()
        if err.path is not None and partial in err.path.parents:
            # The partial folder is gone: the user knows the output folder by its own name.
            name = err.path.relative_to(partial)
            raise OutputError(f"{err.message} (writing {name}; nothing was left behind)", out) from err
        raise
    except BaseException:
        run.discard()
        raise
    doc = summary.floors_doc
    return BuildResult(
        log=log,
        out=out,
        log_duration_s=log_duration_s,
        elapsed_s=elapsed,
        timings_s=timings,
        floors=doc["floors"],
        transitions=doc["transitions"],
        connectors=doc["connectors"],
        counts=counts,
        graph=graph.to_json(),
        files=summary.files,
        warnings=warnings,
    )


# ----- stages ------------------------------------------------------------------------------


def segment_floors(
    src: LogSource, cfg: MfmapConfig, warnings: list[str]
) -> tuple[PressureSeries | None, FloorSegmentation]:
    """Barometer -> floors; a log without barometer becomes one floor, with a warning."""
    from mfmap.floors.motion import motion_from_imu, motion_from_odometry
    from mfmap.floors.segment import segment_pressure

    try:
        pressure = src.pressure()
    except MissingDataError:
        from mfmap.graph.ride import find_rides

        # Inside a closed cabin the lidar cannot see a ride; the accelerometer can.
        rides = find_rides(src.imu(), cfg.floors.min_floor_height_m)
        if rides:
            ride = rides[0]
            raise MissingDataError(
                f"no barometer in the log, but the IMU feels {len(rides)} elevator ride(s), the first "
                f"{ride.height_change_m:+.1f} m at {(ride.start_ns - src.start_ns) / 1e9:.0f} s: the "
                "robot changed floors, and a multi-floor map needs the barometer (topic role 'baro')",
                src.path,
            ) from None
        warnings.append("no barometer in the log: building a single-floor map")
        return None, single_floor(src.start_ns, src.end_ns)
    odom = src.odometry()
    imu = src.imu()
    motion = None
    if odom is not None and len(odom) > 1:
        motion = motion_from_odometry(odom, cfg.floors)
    elif imu is not None and len(imu) > 1:
        motion = motion_from_imu(imu, cfg.floors)
    return pressure, segment_pressure(pressure, motion, cfg.floors)


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
    for _stamp, _frame, xyz, _t in _scans(src, planar):
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


def lidar_floor_change(keyframes: Sequence[Keyframe], min_floor_height_m: float) -> str | None:
    """What the lidar odometry says about a change of floor in a log without barometer.

    Without a barometer the log is mapped as one floor, which is only right when the robot stayed
    on it: stairs show up in the lidar odometry as a climb (z is free there). Returns a phrase
    describing the largest climb or descent of at least `min_floor_height_m`, else None.
    """
    kfs = sorted(keyframes, key=lambda k: k.stamp_ns)
    if len(kfs) < 2:
        return None
    z = np.array([k.pose[2, 3] for k in kfs], dtype=np.float64)
    lo, hi = int(np.argmin(z)), int(np.argmax(z))
    if z[hi] - z[lo] < min_floor_height_m:
        return None
    first, last = sorted((lo, hi))
    verb = "climbs" if z[last] > z[first] else "descends"
    t0_s = (kfs[first].stamp_ns - kfs[0].stamp_ns) / 1e9
    t1_s = (kfs[last].stamp_ns - kfs[0].stamp_ns) / 1e9
    return f"{verb} {abs(z[last] - z[first]):.1f} m between {t0_s:.0f} s and {t1_s:.0f} s"


def single_floor(start_ns: int, end_ns: int) -> FloorSegmentation:
    """One floor spanning the whole log (no barometer)."""
    stamps = np.array([start_ns, end_ns], dtype=np.int64)
    zeros = np.zeros(2)
    return FloorSegmentation(
        floors=(Floor(0, 0.0, 0.0, ((start_ns, end_ns),)),),
        transitions=(),
        stamp_ns=stamps,
        height_raw_m=zeros,
        height_filtered_m=zeros,
        floor_of_sample=np.zeros(2, dtype=np.int32),
    )


def gravity_at_keyframes(
    imu: ImuSeries | None,
    keyframes: list[Keyframe],
    extrinsics: Extrinsics,
    window_s: float = 1.0,
    odom: OdomSeries | None = None,
) -> dict[int, F64]:
    """The up direction in the base frame at each keyframe: the IMU's mean specific force over
    +- window_s, each sample first turned into the base frame of the keyframe's instant with the
    gyro's rotation since then.

    The robot rocks while it drives: its true tilt swings by half a degree within a second, and
    a plain mean is the window's average attitude, not the keyframe's. Two-floor's keyframes,
    against the truth: 0.35 degrees RMS as a plain mean over +- 0.5 s, 0.17 turned into each
    keyframe's frame over +- 1 s (the gyro's bias, from the stand-stills, taken off first).

    With wheel odometry, minus the IMU's own mean acceleration over the same window: the change
    of its velocity (the odometry's body-frame twist, the lever arm of an IMU off the base's
    origin included), both ends turned into the keyframe's frame. A keyframe is taken while the
    robot drives and turns, where 0.1 m/s^2 is 0.6 degrees of false tilt.
    """
    if imu is None or len(imu) < 2:
        return {}
    imu_to_base = extrinsics.get(imu.frame_id)
    if imu_to_base is None:
        imu_to_base = np.eye(4)
    lever = imu_to_base[:3, 3]
    order = np.argsort(imu.stamp_ns, kind="stable")
    stamp_ns = imu.stamp_ns[order]
    accel = imu.accel_m_s2[order] @ imu_to_base[:3, :3].T
    rate = imu.gyro_rad_s[order] @ imu_to_base[:3, :3].T
    rate = rate - gyro_bias(stamp_ns, rate, still_mask(stamp_ns, odom))
    velocity = None if odom is None else _imu_velocity(odom, stamp_ns, rate, lever)
    half = int(window_s * 1e9)
    out: dict[int, F64] = {}
    for kf in keyframes:
        lo = int(np.searchsorted(stamp_ns, kf.stamp_ns - half))
        hi = int(np.searchsorted(stamp_ns, kf.stamp_ns + half, side="right"))
        if hi - lo < 5:
            continue
        t_ns = stamp_ns[lo:hi]
        span_s = (int(t_ns[-1]) - int(t_ns[0])) / 1e9
        if span_s <= 0.0:
            continue  # samples all stamped alike: no time to average over
        to_kf = rotations_to(t_ns, rate[lo:hi], kf.stamp_ns)  # samples' frames in the keyframe's
        force = np.einsum("nij,nj->ni", to_kf, accel[lo:hi])
        step_s = np.diff(t_ns).astype(np.float64)[:, None] / 1e9
        mean = ((force[1:] + force[:-1]) * step_s).sum(axis=0) / (2.0 * span_s)  # trapezoid
        if velocity is not None:
            first, last = velocity[lo], velocity[hi - 1]
            if np.isnan(first[0]) or np.isnan(last[0]):
                continue  # no odometry around it: the mean may hold the robot's acceleration
            mean = mean - (to_kf[-1] @ last - to_kf[0] @ first) / span_s
        norm = float(np.linalg.norm(mean))
        # Only when the robot is close to unaccelerated is the mean a direction of gravity.
        if abs(norm - 9.81) < 0.5:
            out[kf.id] = mean / norm
    return out


def _imu_velocity(odom: OdomSeries, stamp_ns: I64, rate_rad_s: F64, lever: F64) -> F64:
    """Velocity (base frame) at each IMU stamp of the IMU, at `lever` on the base: the
    odometry's body-frame linear velocity plus w x r; NaN where the odometry does not reach."""
    at = stamp_ns.astype(np.float64)
    if len(odom) < 2:
        return np.full((len(at), 3), np.nan)
    t = odom.stamp_ns.astype(np.float64)
    v = np.column_stack([np.interp(at, t, odom.linear_m_s[:, a]) for a in range(3)])
    v += np.cross(rate_rad_s, lever)
    tolerance_ns = 100_000_000
    v[(at < t[0] - tolerance_ns) | (at > t[-1] + tolerance_ns)] = np.nan
    return v


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
    from mfmap.graph.optimize import optimize_building

    gravity = gravity_at_keyframes(imu, mapping.keyframes, extrinsics,
                                   odom=odom if cfg.graph.gravity_minus_odometry else None)
    return optimize_building(
        mapping.keyframes,
        mapping.edges,
        seg if pressure is not None else None,
        pressure,
        cfg.graph,
        temperature_k=cfg.floors.temperature_k,
        gravity_body=gravity,
        progress=progress,
        imu=imu,
        executor=pool,
        scale_prior_sigma=scale_prior_sigma,
    )


def accumulate(
    src: LogSource,
    seg: FloorSegmentation,
    mapping: MappingResult,
    graph: GraphResult,
    extrinsics: Extrinsics,
    cfg: MfmapConfig,
    progress: Progress,
    pool: Executor | None = None,
) -> tuple[Trajectory, MapAccumulator]:
    """Each floor's cloud and grid from every scan at its optimised pose (or the keyframes).

    With `cfg.export.workers` > 1 the floors are shared out over processes: those of `pool` when
    given (started by `mapping.workers.worker_pool`), else a pool of their own.
    """
    from mfmap.export.config import CloudSource
    from mfmap.export.mapdata import MapAccumulator
    from mfmap.export.write import optimised_trajectory

    rides = [(tr.start_ns, tr.end_ns) for tr in seg.transitions
             if tr.kind == TransitionKind.ELEVATOR]
    walks = [(tr.start_ns, tr.end_ns) for tr in seg.transitions
             if tr.kind != TransitionKind.ELEVATOR]
    trajectory = optimised_trajectory(mapping, graph.poses, rides, walks)
    maps = MapAccumulator(cfg.export, dict(graph.floor_z_m))
    if cfg.export.cloud_source == CloudSource.KEYFRAMES or trajectory.stamps_ns.shape[0] == 0:
        maps.min_hits = 1  # a keyframe cloud already merges several scans
        for kf in sorted(mapping.keyframes, key=lambda k: k.stamp_ns):
            maps.add(kf.floor_id, graph.poses[kf.id], kf.cloud, force_view=True)
        return trajectory, maps
    cabins = _cabins(seg, trajectory, cfg)
    used = _used_scans(seg, trajectory, cabins, cfg)
    job = _MapsJob(src.path, cfg, Role.LIDAR not in src.roles, trajectory, used,
                   _distinct_cabins(cabins), extrinsics, dict(graph.floor_z_m))
    groups = _floor_groups(used, trajectory, cfg.export.workers)
    with progress.stage("maps", total=len(used)) as bar, contextlib.ExitStack() as stack:
        if len(groups) < 2:
            return trajectory, _accumulate_scans(src, job, bar)
        # One floor group per process (a floor's cloud and grid never depend on another floor,
        # so the maps are those of one pass).
        if pool is None:
            from mfmap.mapping.workers import worker_pool

            pool = stack.enter_context(worker_pool(len(groups), warm=False))
        futures = [pool.submit(_maps_worker, job.for_floors(g)) for g in groups]
        maps = futures[0].result()
        bar.advance(maps.scans)
        for future in futures[1:]:
            part = future.result()
            bar.advance(part.scans)
            maps.merge(part)
    return trajectory, maps


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


def add_depth_cameras(src: LogSource, cameras: list[Camera], seg: FloorSegmentation,
                      trajectory: Trajectory, maps: MapAccumulator, cfg: MfmapConfig,
                      colour: Sequence[ColourCamera] = ()) -> dict[str, int]:
    """The depth cameras' images into the floor maps (images used per depth topic), then the
    colour cameras' paint on the clouds, left out where the lidar scans are: rides, stair walks
    and elevator cabins."""
    if not cameras and not colour:
        return {}
    from mfmap.export.camera import add_cameras

    margin = int(cfg.export.transition_margin_s * 1e9)
    spans = [(tr.start_ns - margin, tr.end_ns + margin) for tr in seg.transitions]
    shafts = _distinct_cabins(_cabins(seg, trajectory, cfg))

    def usable(stamp_ns: int, pose: F64) -> bool:
        return (seg.floor_at(stamp_ns) >= 0 and not _near_transition(stamp_ns, spans)
                and not _in_cabin(pose, stamp_ns, shafts))

    def outside(points_base: np.ndarray, pose: F64, stamp_ns: int) -> np.ndarray:
        # A camera by an open landing door sees the cabin (and the shaft) as the lidar does.
        if not shafts or points_base.shape[0] == 0:
            return np.ones(points_base.shape[0], dtype=bool)
        return _outside_cabins(points_base, pose, stamp_ns, shafts)

    used = add_cameras(src, cameras, trajectory, maps, cfg.camera, cfg.export.grid_band_m, usable,
                       outside)
    from mfmap.export.lidar_colour import paint_clouds

    paint_clouds(src, list(colour), trajectory, maps, cfg.camera, usable)
    return used


@dataclass(frozen=True)
class _MapsJob:
    """What the second pass over the log needs (sent to a worker process for a floor group)."""

    path: Path  # the log, re-opened by a worker
    cfg: MfmapConfig
    planar: bool
    trajectory: Trajectory
    used: dict[int, int]  # stamp -> trajectory index of the scans to use
    shafts: list[_Cabin]
    extrinsics: Extrinsics
    floor_z_m: dict[int, float]

    def for_floors(self, floors: set[int]) -> _MapsJob:
        floor = self.trajectory.floor
        used = {s: i for s, i in self.used.items() if int(floor[i]) in floors}
        return _MapsJob(self.path, self.cfg, self.planar, self.trajectory, used, self.shafts,
                        self.extrinsics, self.floor_z_m)


def _accumulate_scans(src: LogSource, job: _MapsJob, bar: StageProgress) -> MapAccumulator:
    """Deskew, clean and add the planned scans to a fresh accumulator."""
    from mfmap.export.mapdata import MapAccumulator

    maps = MapAccumulator(job.cfg.export, job.floor_z_m)
    trajectory, todo, deskew = job.trajectory, dict(job.used), job.cfg.export.deskew
    for stamp_ns, frame_id, xyz, t_offset_ns in _scans_of(src, job.planar, trajectory, job.used):
        i = todo.pop(stamp_ns, None)
        if i is None:
            continue  # a scan the plan leaves out (or a second copy of one)
        bar.advance()
        pose = trajectory.poses[i]
        to_base = job.extrinsics.get(frame_id)
        pts = xyz.astype(np.float64)
        if to_base is not None:
            pts = pts @ to_base[:3, :3].T + to_base[:3, 3]
        if deskew and t_offset_ns is not None and len(t_offset_ns) == len(pts):
            pts = _deskew(pts, t_offset_ns, trajectory, i)
        pts = _drop_cabin(pts, pose, stamp_ns, job.shafts)
        maps.add(int(trajectory.floor[i]), pose, pts)
    return maps


def _maps_worker(job: _MapsJob) -> MapAccumulator:
    from mfmap.ingest import open_log

    with open_log(job.path, job.cfg.ingest) as src, NullProgress().stage("maps") as bar:
        return _accumulate_scans(src, job, bar)


def _floor_groups(used: dict[int, int], trajectory: Trajectory, workers: int) -> list[set[int]]:
    """Floors in at most `workers` groups of about equal scan counts (largest first, greedy)."""
    counts: dict[int, int] = {}
    for i in used.values():
        counts[int(trajectory.floor[i])] = counts.get(int(trajectory.floor[i]), 0) + 1
    groups: list[tuple[int, set[int]]] = [(0, set()) for _ in range(min(workers, len(counts)))]
    for floor_id, n in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])):
        k = min(range(len(groups)), key=lambda j: (groups[j][0], j))
        groups[k] = (groups[k][0] + n, groups[k][1] | {floor_id})
    return [g for _, g in sorted(groups, key=lambda ng: (-ng[0], min(ng[1], default=0))) if g]


def _used_scans(seg: FloorSegmentation, trajectory: Trajectory, cabins: list[_Cabin],
                cfg: MfmapConfig) -> dict[int, int]:
    """Stamp -> trajectory index of the scans the maps use, decided from the poses alone.

    Left out: scans in (or at the ends of) a ride or stair walk, scans before the robot moved
    or turned enough since the last one used on its floor (standing still adds nothing), and
    scans from inside an elevator cabin (its walls, and mirror ghosts behind them). Deciding
    before reading lets the second pass decode only the scans it uses.
    """
    margin = int(cfg.export.transition_margin_s * 1e9)
    rides = [(tr.start_ns - margin, tr.end_ns + margin) for tr in seg.transitions]
    last_used: dict[int, F64] = {}
    used: dict[int, int] = {}
    for i, stamp in enumerate(trajectory.stamps_ns.tolist()):
        if stamp in used or seg.floor_at(stamp) < 0 or _near_transition(stamp, rides):
            continue
        pose = trajectory.poses[i]
        floor_id = int(trajectory.floor[i])
        if not _moved(last_used.get(floor_id), pose, cfg) or _in_cabin(pose, stamp, cabins):
            continue
        used[stamp] = i
        last_used[floor_id] = pose
    return used


def _scans_of(src: LogSource, planar: bool, trajectory: Trajectory, used: dict[int, int],
              max_skip: int = 20) -> Iterator[tuple[int, str, np.ndarray, np.ndarray | None]]:
    """The log's scans in windows around the used ones (runs of skipped scans are not decoded)."""
    idx = sorted(used.values())
    stamps = trajectory.stamps_ns
    start = 0
    for k in range(1, len(idx) + 1):
        if k == len(idx) or idx[k] - idx[k - 1] > max_skip:
            yield from _scans(src, planar, int(stamps[idx[start]]), int(stamps[idx[k - 1]]))
            start = k


def _moved(last: F64 | None, pose: F64, cfg: MfmapConfig) -> bool:
    if last is None:
        return True
    delta = inverse(last) @ pose
    turn_deg = math.degrees(rotation_angle_rad(delta))
    return bool(
        np.linalg.norm(delta[:3, 3]) >= cfg.export.scan_min_motion_m
        or turn_deg >= cfg.export.scan_min_turn_deg
    )


def _near_transition(stamp_ns: int, spans: list[tuple[int, int]]) -> bool:
    return any(lo <= stamp_ns <= hi for lo, hi in spans)


def _scans(src: LogSource, planar: bool, start_ns: int | None = None,
           end_ns: int | None = None) -> Iterator[tuple[int, str, np.ndarray, np.ndarray | None]]:
    if planar:
        for scan in src.scans2d(start_ns, end_ns):
            xyz = np.column_stack([scan.xy, np.zeros(len(scan.xy), dtype=np.float32)])
            yield scan.stamp_ns, scan.frame_id, xyz, scan.t_offset_ns
    else:
        for cloud in src.clouds(start_ns, end_ns):
            yield cloud.stamp_ns, cloud.frame_id, cloud.xyz, cloud.t_offset_ns


def _deskew(points_base: F64, t_offset_ns: np.ndarray, trajectory: Trajectory, i: int,
            max_gap_ns: int = 250_000_000) -> F64:
    """Points measured at stamp + t_offset, expressed in the base frame at the scan's stamp.

    A spinning lidar fires each column at its own time, while the scan's pose is the base at the
    stamp (mapping deskews at mid-sweep and moves the pose back to the stamp). The motion over
    the sweep comes from the optimised trajectory: the relative pose to the next scan (or from
    the previous one, at a gap), interpolated per point with a slerp of the rotation (Rodrigues,
    vectorised) and a linear translation.
    """
    stamps, poses, floor = trajectory.stamps_ns, trajectory.poses, trajectory.floor
    n = stamps.shape[0]
    if n < 2 or points_base.shape[0] == 0 or not np.any(t_offset_ns):
        return points_base
    if i + 1 < n and stamps[i + 1] - stamps[i] <= max_gap_ns and floor[i + 1] == floor[i]:
        a, b = i, i + 1
    elif i > 0 and stamps[i] - stamps[i - 1] <= max_gap_ns and floor[i - 1] == floor[i]:
        a, b = i - 1, i
    else:
        return points_base  # an isolated scan: no motion to interpolate
    # The motion to the next scan (or from the previous one, at a gap) as a constant twist.
    span_s = (stamps[b] - stamps[a]) / 1e9
    angular, linear = twist(inverse(poses[a]) @ poses[b], span_s)
    return deskew(points_base, t_offset_ns.astype(np.float64) / 1e9, angular, linear)


@dataclass(frozen=True)
class _Cabin:
    start_ns: int
    end_ns: int
    pose: F64  # base pose in the cabin (world)
    half_xy_m: tuple[float, float]


def _cabins(seg: FloorSegmentation, trajectory: Trajectory, cfg: MfmapConfig) -> list[_Cabin]:
    """Where the robot stood in each elevator, with the window in which its walls are seen."""
    if not cfg.mapping.cabin_filter or trajectory.stamps_ns.shape[0] == 0:
        return []
    window = int(cfg.mapping.cabin_window_s * 1e9)
    half = (cfg.mapping.cabin_size_m[0] / 2, cfg.mapping.cabin_size_m[1] / 2)
    out = []
    for tr in seg.transitions:
        if tr.kind != TransitionKind.ELEVATOR:
            continue
        for stamp in (tr.start_ns, tr.end_ns):
            i = int(np.clip(np.searchsorted(trajectory.stamps_ns, stamp), 0, len(trajectory.stamps_ns) - 1))
            lo = tr.start_ns - window if stamp == tr.start_ns else tr.end_ns
            hi = tr.start_ns if stamp == tr.start_ns else tr.end_ns + window
            out.append(_Cabin(lo, hi, trajectory.poses[i], half))
    return out


def _distinct_cabins(cabins: list[_Cabin], radius_m: float = 0.5) -> list[_Cabin]:
    """One cabin per elevator shaft (rides from the same spot share it), for the mirror filter."""
    out: list[_Cabin] = []
    for cabin in cabins:
        if all(np.hypot(*(cabin.pose[:2, 3] - c.pose[:2, 3])) > radius_m for c in out):
            out.append(cabin)
    return out


def _in_cabin(pose: F64, stamp_ns: int, cabins: list[_Cabin], margin_m: float = 0.3) -> bool:
    for cabin in cabins:
        if cabin.start_ns <= stamp_ns <= cabin.end_ns:
            local = (pose[:3, 3] - cabin.pose[:3, 3]) @ cabin.pose[:3, :3]
            if abs(local[0]) < cabin.half_xy_m[0] + margin_m and abs(local[1]) < cabin.half_xy_m[1] + margin_m:
                return True
    return False


def _drop_cabin(points_base: np.ndarray, pose: F64, stamp_ns: int, cabins: list[_Cabin]) -> np.ndarray:
    """Drop returns from each elevator cabin and from anything seen through it (see
    `_outside_cabins`)."""
    if not cabins or points_base.shape[0] == 0:
        return points_base
    return points_base[_outside_cabins(points_base, pose, stamp_ns, cabins)]


def _outside_cabins(points_base: np.ndarray, pose: F64, stamp_ns: int, cabins: list[_Cabin]) -> np.ndarray:
    """Mask of the points that are not returns from an elevator cabin or seen through it.

    Cabin walls are often mirrors (the LeGO-LOAM elevator paper): what a ray shows after crossing the cabin is a
    reflection, not the building. In the base frame of the scan, per cabin: points inside the
    cabin box, and points whose ray from the sensor leaves the box before reaching them.
    """
    del stamp_ns  # the cabin stays where it is; its walls matter at any time
    keep = np.ones(points_base.shape[0], dtype=bool)
    range2 = np.einsum("ij,ij->i", points_base[:, :2], points_base[:, :2])
    for cabin in cabins:
        box_in_base = np.linalg.inv(pose) @ cabin.pose
        rot, origin = box_in_base[:3, :3], box_in_base[:3, 3]
        sensor = (-origin[:2]) @ rot[:2, :2]  # the base origin in the box frame
        half = np.array(cabin.half_xy_m)
        # Only points at least as far as the box (from the base origin) can be in it or behind it.
        gap = float(np.linalg.norm(np.maximum(np.abs(sensor) - half, 0.0)))
        near = np.flatnonzero(range2 >= (gap - 1e-6) ** 2) if gap > 0 else np.arange(len(range2))
        if near.shape[0] == 0:
            continue
        local = (points_base[near, :2] - origin[:2]) @ rot[:2, :2]
        d = local - sensor
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (-half - sensor) / d
            t2 = (half - sensor) / d
        # fmin/fmax skip the NaN of a ray parallel to a slab (faster than nanmin/nanmax).
        t_near = np.fmax(np.fmin(t1[:, 0], t2[:, 0]), np.fmin(t1[:, 1], t2[:, 1]))
        t_far = np.fmin(np.fmax(t1[:, 0], t2[:, 0]), np.fmax(t1[:, 1], t2[:, 1]))
        crosses = (t_near <= t_far) & (t_far > 0.0) & (t_near < 1.0)
        inside = np.all(np.abs(local) < half, axis=1)
        keep[near[inside | (crosses & (t_far < 1.0))]] = False
    return keep


# ----- the output folder -------------------------------------------------------------------


def _log_folders(log: Path) -> list[Path]:
    """The folders that are part of the log: a bag folder or a folder of .mcap files (also when
    the log is named by its metadata.yaml or one of its .db3 files)."""
    if log.is_dir():
        return [log]
    if log.suffix == ".db3" or log.name == "metadata.yaml":
        return [log.parent]
    return []


def _finish_report(folder: Path, timings: dict[str, float], elapsed_s: float, log_s: float) -> None:
    """Add the whole build's time and peak memory to report.json (still in the partial folder)."""
    import json

    from mfmap.export.files import write_json

    path = folder / "report.json"
    doc = json.loads(path.read_text())
    doc["timings_s"] = {k: round(v, 3) for k, v in timings.items()}
    doc["timings_s"]["total"] = round(elapsed_s, 3)
    doc["summary"]["build_s"] = round(elapsed_s, 3)
    doc["summary"]["realtime_factor"] = round(log_s / elapsed_s, 2) if elapsed_s > 0 else None
    doc["summary"]["peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    write_json(path, doc)


# ----- terminal summary --------------------------------------------------------------------


def render_summary(result: BuildResult) -> RenderableType:
    """Floors, elevations, transitions, time taken, real-time factor, where the outputs are."""
    from rich.console import Group
    from rich.text import Text

    from mfmap.tables import Justify, table

    def right(*headers: str) -> list[tuple[str, Justify]]:
        return [(h, "right") for h in headers]

    floors = table(right("floor", "elevation [m]", "visits", "connectors"), title="floors", title_justify="left")
    for f in result.floors:
        floors.add_row(str(f["id"]), f"{f['elevation_m']:+.3f}", str(len(f["visits"])),
                       ",".join(str(c) for c in f["connectors"]) or "-")
    transitions = table(
        right("kind", "from", "to", "height change [m]", "duration [s]", "x, y"),
        title="transitions",
        title_justify="left",
    )
    for t in result.transitions:
        xy = f"{t['x']:.2f}, {t['y']:.2f}" if "x" in t else "-"
        transitions.add_row(t["kind"], str(t["from"]), str(t["to"]), f"{t['height_change_m']:+.3f}",
                            f"{t['t_end'] - t['t_start']:.1f}", xy)
    factors = table(
        right("factor", "count", "final error", "outliers", "rejected"),
        title="factor graph",
        title_justify="left",
    )
    for name, stats in result.graph.get("factors", {}).items():
        factors.add_row(name, str(stats["count"]), f"{stats['error_final']:.3g}", str(stats["outliers"]),
                        str(stats["rejected"]))
    timing = ", ".join(f"{k} {v:.1f} s" for k, v in result.timings_s.items())
    lines = Text(
        f"built {result.log.name} ({result.log_duration_s:.0f} s of log) in {result.elapsed_s:.1f} s: "
        f"{result.realtime_factor:.1f}x real time ({timing})\noutputs: {result.out}/ "
        f"({', '.join(_outputs(result.files))})"
    )
    return Group(floors, transitions, factors, lines)


def _outputs(files: Sequence[str]) -> list[str]:
    """The outputs a build wrote, the floors' files once for all floors."""
    top = [f for f in files if "/" not in f and not f.startswith(".")]
    per_floor = sorted({f.split("/", 2)[2] for f in files if f.startswith("floors/") and f.count("/") == 2})
    grids = [f.removeprefix("grid.") for f in per_floor if f.startswith("grid.")]
    named = [f"floors/<id>/grid.{'|'.join(grids)}"] if grids else []
    named += [f"floors/<id>/{f}" for f in per_floor if not f.startswith("grid.")]
    named += [f for f in files if f.startswith("floors/") and f.count("/") == 1]  # floors/index.yaml
    return top + named


__all__ = ["BuildResult", "accumulate", "build", "optimise", "render_summary", "segment_floors"]
