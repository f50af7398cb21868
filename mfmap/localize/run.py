"""`mfmap localize`: a new log of a mapped building, placed in the map's frame scan by scan.

After "3D Multi-floor Precision Mapping and Localization for Indoor Autonomous Robots"
(Algorithm 2: the map's points in a band around the robot's floor, each scan registered against
them), with what a log from another day needs besides:

1. The log's floors from its barometer (the floors stage), on the map's floors by one unknown
   offset, the day's weather: the offsets that put the log's levels on floors of the map are
   the hypotheses (`levels`). Where they disagree on which visits have a floor in the map, a
   probe of each visit they place decides.
2. Global search with no initial pose: the first second of scans against every floor
   (`search`); a fix only when no distinct place, on any floor, fits nearly as well. The fix
   picks the hypothesis, and so the offset: from then on the barometer says the floor.
3. Tracking: a scan registered against its floor's cloud from the motion prior whenever the
   robot moved or turned enough since the last one; an elevator ride holds x, y and yaw and takes z from the barometer, stairs
   follow the motion prior; the floor reached is the hypothesis's. A track that fits no more
   is lost, those scans unposed, and the floor searched again.
4. Nothing is posed that was not localised: spans without a fix (another building, a floor the
   map lacks, an ambiguous place) are reported with the best fitness any search found there.
"""

from __future__ import annotations

import contextlib
import logging
import math
import resource
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from enum import IntEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mfmap.config import MfmapConfig
from mfmap.errors import MfmapError, MissingDataError
from mfmap.progress import NullProgress, Progress
from mfmap.types import F64, FloorSegmentation, Role, TransitionKind

if TYPE_CHECKING:
    from rich.console import RenderableType

    from mfmap.ingest.source import LogSource
    from mfmap.localize.levels import FloorHypothesis
    from mfmap.localize.mapfolder import BuildingMap
    from mfmap.localize.search import Candidate
    from mfmap.localize.track import ScanPrep

logger = logging.getLogger(__name__)


class Status(IntEnum):
    """What a scan's pose rests on (scans.csv's `status`)."""

    TRACKED = 0  # registered against its floor
    PREDICTED = 1  # between registered scans: the motion prior, corrected by the next one
    FIXED = 2  # in the query window of a global fix: the motion prior from the fix
    RIDE = 3  # in an elevator: x, y, yaw held, z from the barometer
    STAIRS = 4  # on stairs: the motion prior, z from the barometer
    NO_FIX = 5  # no global fix yet (searching)
    LOST = 6  # the track stopped fitting: not posed
    NO_FLOOR = 7  # on a floor the map does not have
    AMBIGUOUS = 8  # the barometer's hypotheses disagree about this visit's floor

    @property
    def localised(self) -> bool:
        return self <= Status.STAIRS

    @property
    def label(self) -> str:
        return self.name.lower().replace("_", " ")


@dataclass(frozen=True)
class Hint:
    """`--initial-pose x y yaw` and/or `--floor N`: where the log starts, in the map's frame."""

    floor: int | None = None
    x_m: float | None = None
    y_m: float | None = None
    yaw_deg: float | None = None

    @property
    def has_pose(self) -> bool:
        return self.x_m is not None and self.y_m is not None and self.yaw_deg is not None


@dataclass
class LocalizeResult:
    """What `mfmap localize` did and where its outputs are."""

    log: Path
    map: Path
    out: Path
    log_duration_s: float
    elapsed_s: float
    cpu_s: float
    scans: int
    localised_share: float
    first_fix_s: float | None  # log time from the log's start to the first fix
    offset_m: float | None  # map elevation - the log's barometric level
    floors: list[dict[str, Any]]
    spans: list[dict[str, Any]]  # not localised
    searches: int
    files: list[str]
    warnings: list[str] = field(default_factory=list)
    cpu_timings_s: dict[str, float] = field(default_factory=dict)

    @property
    def realtime_factor(self) -> float:
        """Log duration / wall time (above 1: faster than real time)."""
        return self.log_duration_s / self.elapsed_s if self.elapsed_s > 0 else math.inf

    @property
    def cpu_realtime_factor(self) -> float:
        """Log duration / CPU time: what the run costs, whatever else the machine runs."""
        return self.log_duration_s / self.cpu_s if self.cpu_s > 0 else math.inf


@dataclass
class _Track:
    """Per-scan results, filled as the scans stream by."""

    stamps_ns: list[int] = field(default_factory=list)
    poses: list[F64] = field(default_factory=list)
    floor: list[int] = field(default_factory=list)
    status: list[Status] = field(default_factory=list)
    fitness: list[float] = field(default_factory=list)

    def add(self, stamp_ns: int, status: Status, pose: F64 | None = None, floor: int = -1) -> int:
        self.stamps_ns.append(stamp_ns)
        self.poses.append(pose if pose is not None else np.full((4, 4), np.nan))
        self.floor.append(floor)
        self.status.append(status)
        self.fitness.append(math.nan)
        return len(self.stamps_ns) - 1


@dataclass
class _Query:
    """Scans gathered for a global search, each with its pose in the first one's frame."""

    start_ns: int
    chains: dict[int, F64] = field(default_factory=dict)  # scan index -> pose in the query frame
    clouds: list[tuple[int, F64]] = field(default_factory=list)  # (scan index, base points)
    last_ns: int = 0


def localize(
    log: Path,
    map_dir: Path,
    out: Path,
    cfg: MfmapConfig,
    hint: Hint | None = None,
    force: bool = False,
    progress: Progress | None = None,
) -> LocalizeResult:
    """Localise `log` in the map built into `map_dir`; write the results into `out`."""
    from mfmap.ingest import open_log
    from mfmap.localize.mapfolder import load_map
    from mfmap.localize.output import write_outputs
    from mfmap.pipeline import _log_folders
    from mfmap.runfolder import RunFolder, check_output, input_size

    started = time.perf_counter()
    cpu0 = time.process_time()
    progress = progress or NullProgress()
    log, map_dir, out = Path(log), Path(map_dir), Path(out)
    # Checked before any work: never an input (the log, the map) nor inside one.
    check_output(out, [log, map_dir], [*_log_folders(log), map_dir], force)
    lc = cfg.localize
    timings = _Timings()
    warnings: list[str] = []
    with timings("map"):
        building = load_map(map_dir, lc.map_voxel_m, 3.0 * lc.map_voxel_m, lc.band_m)
    warnings += [f"map: {w}" for w in building.warnings]
    if hint is not None and hint.floor is not None and hint.floor not in building.floors:
        raise MfmapError(f"--floor {hint.floor}: the map has floors "
                         f"{', '.join(str(f) for f in sorted(building.floors))}")
    folder = RunFolder.create(out, [log, map_dir], [*_log_folders(log), map_dir], force,
                              input_size(log))
    warnings += [f"localize: {note}" for note in folder.notes]
    partial = folder.partial
    with folder:
        with timings("open"):
            src = open_log(log, cfg.ingest)
        with src:
            warnings += [f"ingest: {w}" for w in src.warnings]
            if Role.LIDAR not in src.roles:
                what = "only 2D LaserScan" if Role.SCAN2D in src.roles else "no lidar"
                raise MissingDataError(f"localize needs a 3D lidar (PointCloud2); the log has {what}",
                                       log)
            run = _Localizer(src, building, cfg, hint, warnings, timings, progress)
            run.run()
        log_duration_s = max((src.end_ns - src.start_ns) / 1e9, 0.0)
        elapsed = time.perf_counter() - started
        summary = run.summary(log, map_dir, log_duration_s, elapsed, time.process_time() - cpu0)
        with timings("output"):
            files = write_outputs(partial, run, summary, cfg, building)
        summary.update(_finish_report(partial / "report.json", timings, started, cpu0,
                                      log_duration_s))
        folder.commit()
    return LocalizeResult(
        log=log, map=map_dir, out=out, log_duration_s=log_duration_s,
        elapsed_s=summary["elapsed_s"], cpu_s=summary["cpu_s"], scans=summary["scans"],
        localised_share=summary["localised_share"], first_fix_s=summary["first_fix_s"],
        offset_m=summary["offset_m"], floors=summary["floors"], spans=summary["not_localised"],
        searches=summary["searches"], files=files, warnings=warnings,
        cpu_timings_s=dict(timings.cpu_s),
    )


def _finish_report(path: Path, timings: _Timings, started: float, cpu0: float,
                   log_duration_s: float) -> dict[str, Any]:
    """The whole run's time, outputs included, into report.json (still in the partial folder)."""
    import json

    from mfmap.export.files import write_json

    elapsed, cpu = time.perf_counter() - started, time.process_time() - cpu0
    final = {"elapsed_s": round(elapsed, 3), "cpu_s": round(cpu, 3),
             "realtime_factor": round(log_duration_s / elapsed, 2) if elapsed > 0 else None,
             "cpu_realtime_factor": round(log_duration_s / cpu, 2) if cpu > 0 else None}
    doc = json.loads(path.read_text())
    doc.update(final)
    doc["summary"].update(final)
    doc["timings_s"] = {k: round(v, 3) for k, v in timings.wall_s.items()}
    doc["cpu_timings_s"] = {k: round(v, 3) for k, v in timings.cpu_s.items()}
    write_json(path, doc)
    return final


class _Timings:
    """Wall and CPU seconds per stage (the CPU's do not depend on what else the machine runs)."""

    def __init__(self) -> None:
        self.wall_s: dict[str, float] = {}
        self.cpu_s: dict[str, float] = {}

    @contextlib.contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        wall, cpu = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            self.wall_s[name] = self.wall_s.get(name, 0.0) + time.perf_counter() - wall
            self.cpu_s[name] = self.cpu_s.get(name, 0.0) + time.process_time() - cpu


# Search timing: without a fix, the next search waits longer each time (up to MAX_RETRY_S), so
# a log that never fits (another building) costs a few searches, not one every retry_s.
RETRY_GROWTH = 1.5
MAX_RETRY_S = 20.0
# Below these the wheels' way or turn between two registrations is too small to share out.
WHEELS_MIN_M = 0.02
WHEELS_MIN_DEG = 0.5
# Within this share of a ride's height change from either end the cabin stands at a floor.
RIDE_STILL_SHARE = 0.01
# Without wheel odometry to say how far the robot went, a scan is registered this often.
NO_WHEELS_INTERVAL_NS = 200_000_000
# Coarse places scoring below this share of the best coarse place are not refined.
COARSE_KEEP = 0.6
# Scans gathered into a query: every QUERY_STRIDE-th (consecutive scans add little).
QUERY_STRIDE = 2


def _distinct_best(candidates: list[Candidate], count: int) -> list[Candidate]:
    """The best candidates, one per place (several coarse places often refine to one)."""
    out: list[Candidate] = []
    for c in candidates:
        if all(c.distinct(o, 0.2, 2.0) for o in out):
            out.append(c)
        if len(out) == count:
            break
    return out


def _clearly_better(fitness: float, rival: float, misfit_ratio: float) -> bool:
    """Whether a place of this fitness beats one of the rival's: the rival leaves at least
    misfit_ratio times as many points unfit."""
    return (1.0 - rival) >= misfit_ratio * (1.0 - fitness)


class _Localizer:
    def __init__(self, src: LogSource, building: BuildingMap, cfg: MfmapConfig, hint: Hint | None,
                 warnings: list[str], timings: _Timings, progress: Progress) -> None:
        from mfmap.localize.levels import best_hypotheses, floor_hypotheses
        from mfmap.localize.track import ScanPrep, Wheels
        from mfmap.mapping.cabin import CabinFilter
        from mfmap.mapping.config import MotionPrior
        from mfmap.mapping.motion import MotionModel
        from mfmap.mapping.timeline import Timeline
        from mfmap.pipeline import segment_floors

        self.src = src
        self.map = building
        self.cfg = cfg
        self.lc = cfg.localize
        self.hint = hint
        self.warnings = warnings
        self.timings = timings
        self.progress = progress
        with timings("floors"):
            self.pressure, self.seg = segment_floors(src, cfg, warnings)
        warnings += [f"floors: {w}" for w in self.seg.warnings]
        self.timeline = Timeline(self.seg)
        extrinsics = src.extrinsics()
        self.motion = MotionModel(MotionPrior.AUTO, src.odometry(), src.imu(), extrinsics)
        cabin = (CabinFilter(cfg.mapping, list(self.timeline.transitions), self.motion)
                 if cfg.mapping.cabin_filter else None)
        self.wheels = Wheels(src.odometry())
        self.prep: ScanPrep = ScanPrep(self.lc, extrinsics, self.motion, cabin, self.wheels)
        self.tolerance_m = building.floor_tolerance_m(self.lc.floor_tolerance_share,
                                                      self.lc.floor_tolerance_max_m)
        levels = {f.id: f.elevation_m for f in self.seg.floors}
        visit_time = {f.id: sum((e - s) / 1e9 for s, e in f.visits) for f in self.seg.floors}
        self.hypotheses = floor_hypotheses(levels, visit_time, building.elevations, self.tolerance_m)
        self.tops = best_hypotheses(self.hypotheses)
        self.chosen: FloorHypothesis | None = None
        if self.pressure is None:
            warnings.append("no barometer: the floor is not followed through rides or stairs")
        self.track = _Track()
        self.searches = 0
        self.search_log: list[dict[str, Any]] = []
        self.first_fix_ns: int | None = None
        self.fix_pressure_pa: float | None = None
        self.fix_floor: int | None = None
        # The tracking state.
        self.mode = "search"
        self.floor: int | None = None  # the map floor being tracked or searched
        self.visit = -1
        # The last scan whose pose is settled (a registration, a fix, a ride's scan): the scans
        # after it wait for the next registration and are posed between the two.
        self.anchor: tuple[int, int, F64] | None = None  # (scan index, stamp, pose)
        self.bad_since_ns: int | None = None
        self.wide_next = False
        self.since_visit = 0
        self.query: _Query | None = None
        self.next_search_ns = 0
        self.retry_s = self.lc.retry_s
        self.span_best = 0.0
        self.span_bests: dict[int, float] = {}  # first scan of a not-localised span -> best fitness
        self.probed_visits: set[int] = set()
        self.ride_from: tuple[int, int, F64] | None = None  # (map floor, start ns, pose)
        self.profiles: dict[int, Any] = {}  # ride start -> its height profile
        self.attempt_ns: int | None = None  # the last registration tried

    # ----- the pass over the log -----------------------------------------------------------

    def run(self) -> None:
        with self.timings("probes"):
            self._tie_break()
        with self.timings("track"), self.progress.stage("localize",
                                                        total=self.src.count(Role.LIDAR)) as bar:
            for cloud in self.src.clouds():
                self._scan(cloud.stamp_ns, cloud.frame_id, cloud.xyz, cloud.t_offset_ns)
                bar.advance()
            if self.mode == "track":
                self._flush()
        if self.prep.missing_frames:
            self.warnings.append("no extrinsic for lidar frame(s) "
                                 f"{', '.join(sorted(self.prep.missing_frames))}: used identity")

    def _scan(self, stamp_ns: int, frame_id: str, xyz: np.ndarray, t_offset_ns: np.ndarray | None
              ) -> None:
        segment = self.timeline.at(stamp_ns)
        if segment.kind != "visit":
            self._transition_scan(stamp_ns, segment.transition)
            return
        if segment.visit != self.visit:
            self._new_visit(segment.visit, segment.floor_id, stamp_ns)
        self.since_visit += 1
        if self.mode == "track":
            self._track_scan(stamp_ns, frame_id, xyz, t_offset_ns)
        else:
            self._search_scan(stamp_ns, frame_id, xyz, t_offset_ns)

    def _status_unposed(self) -> Status:
        return {"no_floor": Status.NO_FLOOR, "ambiguous": Status.AMBIGUOUS}.get(self.mode,
                                                                                  Status.NO_FIX)

    # ----- rides and stairs ------------------------------------------------------------------

    def _transition_scan(self, stamp_ns: int, tr: Any) -> None:
        if self.mode != "track" or self.floor is None or self.anchor is None:
            self._unposed(self.track.add(stamp_ns, self._status_unposed()))
            self.query = None
            return
        self._flush()
        if self.ride_from is None or self.ride_from[1] != tr.start_ns:
            self.ride_from = (self.floor, tr.start_ns, self.anchor[2].copy())
        floor, start_ns, _ = self.ride_from
        # x, y and yaw by the motion prior: the wheels stand still in the cabin, and drive
        # when the barometer (lagging in the cabin) still says the ride goes on.
        _, anchor_ns, anchor_pose = self.anchor
        pose = anchor_pose @ self.prep.delta(anchor_ns, stamp_ns)
        label = -1
        if tr.kind == TransitionKind.ELEVATOR:
            pose[2, 3], label = self._ride_z(tr, floor, stamp_ns)
            status = Status.RIDE
        else:
            pose[2, 3] = (self.map.floors[floor].elevation_m + self._height(stamp_ns)
                          - self._height(start_ns))
            status = Status.STAIRS
        i = self.track.add(stamp_ns, status, pose, label)
        self.anchor = (i, stamp_ns, pose)

    def _ride_z(self, tr: Any, floor: int, stamp_ns: int) -> tuple[float, int]:
        """The base's height in a ride, and its floor while the cabin stands (-1 while it
        moves): the accelerometer's profile between the two floors' elevations, else the
        barometer's height change (and -1 throughout)."""
        from mfmap.localize.rides import ride_profile

        start = self.map.floors[floor].elevation_m
        assert self.chosen is not None
        to = self.chosen.floor_of(tr.to_floor)
        if tr.start_ns not in self.profiles:
            imu = self.src.imu()
            to_base = self.prep.extrinsics.get(imu.frame_id) if imu is not None else None
            self.profiles[tr.start_ns] = ride_profile(
                imu, to_base if to_base is not None else np.eye(4), tr.start_ns, tr.end_ns)
        profile = self.profiles[tr.start_ns]
        if to is None or profile is None:
            return start + self._height(stamp_ns) - self._height(tr.start_ns), -1
        share = float(np.interp(stamp_ns, profile[0], profile[1]))
        # The barometer in the closed cabin lags the ride: before and after the cabin moves
        # (by the accelerometer) the robot stands on a floor, though the barometer's ride goes on.
        label = floor if share < RIDE_STILL_SHARE else to if share > 1.0 - RIDE_STILL_SHARE else -1
        return start + share * (self.map.floors[to].elevation_m - start), label

    def _height(self, stamp_ns: int) -> float:
        seg = self.seg
        if len(seg.stamp_ns) < 2:
            return 0.0
        return float(np.interp(stamp_ns, seg.stamp_ns, seg.height_filtered_m))

    def _new_visit(self, visit: int, log_floor: int, stamp_ns: int) -> None:
        """A new visit of the log's segmentation: its map floor, and how to go on."""
        if self.mode == "track":
            self._flush()
        came_tracking = self.mode == "track" and self.visit >= 0 and self.anchor is not None
        self.visit = visit
        self.since_visit = 0
        self.attempt_ns = None
        self.query = None
        self.next_search_ns = 0
        self.retry_s = self.lc.retry_s
        target = self._map_floor(log_floor)
        if target == "ambiguous":
            self.mode, self.floor = "ambiguous", None
            return
        if target is None:
            self.mode, self.floor = "no_floor", None
            return
        assert isinstance(target, int)
        if came_tracking and self.floor is not None and self.ride_from is not None:
            assert self.anchor is not None
            _, start_ns, _ = self.ride_from
            index, anchor_ns, pose = self.anchor
            rides = [tr for tr in self.timeline.transitions
                     if tr.kind == TransitionKind.ELEVATOR and tr.start_ns == start_ns]
            if rides:
                pose = self.motion.level(pose, rides[0].start_ns, rides[0].end_ns)
            else:
                self.wide_next = True  # off the stairs: the climb may have drifted
            pose = pose.copy()
            pose[2, 3] = self.map.floors[target].elevation_m
            self.anchor = (index, anchor_ns, pose)
            self.floor, self.mode = target, "track"
            self.ride_from = None
            return
        self.mode, self.floor = "search", target if self.chosen is not None else None

    def _map_floor(self, log_floor: int) -> int | str | None:
        """The map floor of a log floor: the chosen hypothesis's; before a fix, -1 (search),
        None when no remaining hypothesis gives it one, "ambiguous" when they disagree."""
        if self.chosen is not None:
            return self.chosen.floor_of(log_floor)
        options = {h.floor_of(log_floor) for h in self.tops}
        if options == {None}:
            return None
        if None in options:
            return "ambiguous"
        return -1

    # ----- tracking --------------------------------------------------------------------------

    def _track_scan(self, stamp_ns: int, frame_id: str, xyz: np.ndarray,
                    t_offset_ns: np.ndarray | None) -> None:
        from mfmap.localize.track import register

        assert self.floor is not None and self.anchor is not None
        i = self.track.add(stamp_ns, Status.PREDICTED, None, self.floor)
        if not (self.wide_next or self._due(stamp_ns)):
            return
        _, anchor_ns, anchor_pose = self.anchor
        delta = self.prep.delta(anchor_ns, stamp_ns, quick=True)
        predicted = anchor_pose @ delta
        if self.prep.in_cabin(stamp_ns, predicted):
            return
        self.attempt_ns = stamp_ns
        points = self.prep.points(stamp_ns, frame_id, xyz, t_offset_ns, predicted)
        if len(points) < 20:
            return
        floor = self.map.floors[self.floor]
        reg = register(self.prep.thin(points), floor.target, predicted, self.lc.fit_distance_m,
                       self.wide_next, self.lc.icp_tolerance)
        self.wide_next = False
        self.track.fitness[i] = reg.fitness
        if reg.fitness >= self.lc.track_fitness:
            self._fill(i, reg.pose)
            self.track.poses[i] = reg.pose
            self.track.status[i] = Status.TRACKED
            self.anchor = (i, stamp_ns, reg.pose)
            self.bad_since_ns = None
            return
        if self.bad_since_ns is None:
            self.bad_since_ns = stamp_ns
        if stamp_ns - self.bad_since_ns > self.lc.lost_after_s * 1e9:
            self._lose(i)

    def _pending(self, upto: int) -> list[int]:
        """The scans after the anchor, before `upto`, waiting for a pose."""
        assert self.anchor is not None
        return [k for k in range(self.anchor[0] + 1, upto)
                if self.track.status[k] == Status.PREDICTED]

    def _fill(self, i: int, pose: F64) -> None:
        """Pose the scans between the anchor and scan i (registered at `pose`) between the two."""
        from mfmap.localize.track import interpolate

        assert self.anchor is not None
        pending = self._pending(i)
        if not pending:
            return
        _, anchor_ns, anchor_pose = self.anchor
        stamps = np.asarray([self.track.stamps_ns[k] for k in pending], dtype=np.int64)
        span = float(self.track.stamps_ns[i] - anchor_ns)
        shares_t = (stamps - anchor_ns) / span
        shares_path, shares_turn = shares_t, shares_t
        if self.wheels.usable:
            # Shares of the way and of the turn as the wheels saw them: the robot does not move
            # evenly in time between two registrations (it starts, stops, turns in place).
            ends = np.concatenate([[anchor_ns], stamps, [self.track.stamps_ns[i]]])
            along = self.wheels.along(ends)
            if along[-1] - along[0] > WHEELS_MIN_M:
                shares_path = (along[1:-1] - along[0]) / (along[-1] - along[0])
            heading = self.wheels.heading(ends)
            if abs(heading[-1] - heading[0]) > math.radians(WHEELS_MIN_DEG):
                shares_turn = (heading[1:-1] - heading[0]) / (heading[-1] - heading[0])
        for k, p in zip(pending, interpolate(anchor_pose, pose, shares_turn, shares_path), strict=True):
            self.track.poses[k] = p

    def _flush(self) -> None:
        """Pose the scans waiting since the anchor by the motion prior (no registration follows:
        a ride or stairs begin, or the log ends)."""
        if self.anchor is None:
            return
        _, anchor_ns, anchor_pose = self.anchor
        for k in self._pending(len(self.track.status)):
            self.track.poses[k] = anchor_pose @ self.prep.delta(anchor_ns, self.track.stamps_ns[k])

    def _due(self, stamp_ns: int) -> bool:
        """Whether the robot moved, turned or waited enough since the last registration."""
        lc = self.lc
        if self.attempt_ns is None:
            return True
        if stamp_ns - self.attempt_ns >= lc.register_interval_s * 1e9:
            return True
        if not self.wheels.usable:
            return stamp_ns - self.attempt_ns >= NO_WHEELS_INTERVAL_NS
        dist, turn = self.wheels.moved(self.attempt_ns, stamp_ns)
        return dist >= lc.register_distance_m or turn >= lc.register_angle_deg

    def _lose(self, i: int) -> None:
        """The track stopped fitting: the scans since the last good one are not posed."""
        assert self.anchor is not None
        first = self.anchor[0] + 1
        best = 0.0
        for k in range(first, i + 1):
            self.track.status[k] = Status.LOST
            self.track.poses[k] = np.full((4, 4), np.nan)
            if not math.isnan(self.track.fitness[k]):
                best = max(best, self.track.fitness[k])
        self.span_bests[first] = best
        self.mode = "search"
        self.query = None
        self.next_search_ns = 0
        self.retry_s = self.lc.retry_s
        self.anchor = None
        self.bad_since_ns = None

    # ----- searching -------------------------------------------------------------------------

    def _search_scan(self, stamp_ns: int, frame_id: str, xyz: np.ndarray,
                     t_offset_ns: np.ndarray | None) -> None:
        status = self._status_unposed()
        i = self.track.add(stamp_ns, status)
        self._unposed(i)
        if self.mode in ("no_floor", "ambiguous") and self.visit in self.probed_visits:
            return
        q = self.query
        if q is None:
            q = self.query = _Query(stamp_ns)
            q.chains[i] = np.eye(4)
        else:
            last = max(q.chains)
            q.chains[i] = q.chains[last] @ self.prep.delta(q.last_ns, stamp_ns, quick=True)
        q.last_ns = stamp_ns
        if len(q.chains) % QUERY_STRIDE == 1 and not self.prep.in_cabin(stamp_ns, q.chains[i]):
            q.clouds.append((i, self.prep.points(stamp_ns, frame_id, xyz, t_offset_ns, q.chains[i],
                                                 self.lc.query_voxel_m)))
        window_ns = int(self.lc.query_window_s * 1e9)
        if stamp_ns - q.start_ns < window_ns or stamp_ns < self.next_search_ns or len(q.clouds) < 3:
            # Keep the query to the last window of scans.
            while len(q.clouds) > 3 and stamp_ns - self.track.stamps_ns[q.clouds[0][0]] > window_ns:
                q.clouds.pop(0)
            for k in [k for k in q.chains if k < q.clouds[0][0]] if q.clouds else []:
                del q.chains[k]
            return
        if self.searches >= self.lc.max_searches:
            return
        with self.timings("search"):
            self._search(i, q)

    def _unposed(self, i: int) -> None:
        """Bookkeeping for a scan that is not posed: it belongs to the current span."""
        if i == 0 or self.track.status[i - 1].localised:
            self.span_bests.setdefault(i, 0.0)

    def _search(self, i: int, q: _Query) -> None:
        """Search the query; on a fix, start tracking from its last scan."""
        stamp_ns = self.track.stamps_ns[i]
        report_only = self.mode in ("no_floor", "ambiguous")
        floors = sorted(self.map.floors) if self.floor is None or report_only else [self.floor]
        level = self._level(q)
        points = self._query_points(q, i)
        candidates = self._candidates(points, level, floors)
        self.searches += 1
        best = candidates[0].fitness if candidates else 0.0
        self._note_best(best)
        fix = None if report_only else self._decide(candidates, stamp_ns)
        self.search_log.append({
            "t": stamp_ns / 1e9, "floors": floors, "fix": fix is not None,
            "best": [{"floor": c.floor, "x": round(float(c.pose[0, 3]), 3),
                      "y": round(float(c.pose[1, 3]), 3), "yaw_deg": round(c.yaw_deg, 2),
                      "fitness": round(c.fitness, 4)} for c in _distinct_best(candidates, 3)],
        })
        if report_only:
            self.probed_visits.add(self.visit)
            self.query = None
            return
        if fix is None and self.hint is not None and self.hint.has_pose:
            self.warnings.append(f"localize: the initial pose does not fit (fitness {best:.2f}): "
                                 "searching without it")
            self.hint = Hint(floor=self.hint.floor)
        if fix is None:
            self.query = None
            self.next_search_ns = stamp_ns + int(self.retry_s * 1e9)
            self.retry_s = min(self.retry_s * RETRY_GROWTH, MAX_RETRY_S)
            return
        self._start_tracking(i, q, fix)

    def _note_best(self, fitness: float) -> None:
        for first in sorted(self.span_bests, reverse=True):
            self.span_bests[first] = max(self.span_bests[first], fitness)
            break

    def _level(self, q: _Query) -> F64:
        """The query frame's tilt to gravity (3x3), from the accelerometer over the window."""
        start = self.track.stamps_ns[q.clouds[0][0]]
        return np.asarray(self.motion.level(np.eye(4), start, q.last_ns)[:3, :3])

    def _query_points(self, q: _Query, i: int) -> F64:
        """The query's points in the base frame of scan i."""
        from mfmap.mapping.geometry import inverse, transform
        from mfmap.mapping.registration import downsample

        to_last = inverse(q.chains[i])
        parts = [transform(pts, to_last @ q.chains[k]) for k, pts in q.clouds]
        return downsample(np.concatenate(parts), self.lc.query_voxel_m)

    def _candidates(self, points: F64, level: F64, floors: list[int]) -> list[Candidate]:
        """The best places on each floor, refined, best first."""
        from mfmap.localize.search import Candidate, coarse_places, pose_xyz_yaw, refine

        lc = self.lc
        levelled = points @ level.T
        band = levelled[(levelled[:, 2] > lc.band_m[0]) & (levelled[:, 2] < lc.band_m[1]), :2]
        hint = self.hint if self.first_fix_ns is None else None
        places: list[tuple[int, float, float, float, float]] = []  # floor, x, y, yaw, score
        for floor_id in floors:
            floor = self.map.floors[floor_id]
            if hint is not None and hint.has_pose:
                assert hint.x_m is not None and hint.y_m is not None and hint.yaw_deg is not None
                if hint.floor is None or hint.floor == floor_id:
                    places.append((floor_id, hint.x_m, hint.y_m, math.radians(hint.yaw_deg), 1.0))
                continue
            found = coarse_places(floor.search_field(lc.search_resolution_m), band,
                                  lc.search_yaw_step_deg, lc.search_range_m,
                                  lc.search_candidates, lc.distinct_m, lc.distinct_deg)
            places += [(floor_id, *place) for place in found]
        # Places far below the best on the coarse field do not become the best by ICP.
        top = max((p[4] for p in places), default=0.0)
        out: list[Candidate] = []
        for floor_id, x, y, yaw, score in places:
            if score < COARSE_KEEP * top:
                continue
            floor = self.map.floors[floor_id]
            start = pose_xyz_yaw(x, y, floor.elevation_m, yaw, level)
            pose, fit = refine(points, floor.target, start, lc.fit_distance_m)
            out.append(Candidate(floor_id, pose, fit, score))
        out.sort(key=lambda c: (-c.fitness, c.floor))
        return out

    def _decide(self, candidates: list[Candidate], stamp_ns: int) -> Candidate | None:
        """The fix: the best place on a floor some hypothesis allows, if it fits well and no
        distinct place (on any floor searched) fits nearly as well."""
        lc = self.lc
        allowed = self._allowed_floors()
        consistent = [c for c in candidates if c.floor in allowed]
        if not consistent:
            return None
        best = consistent[0]
        rival = max((c.fitness for c in candidates
                     if best.distinct(c, lc.distinct_m, lc.distinct_deg)), default=0.0)
        if best.fitness < lc.fix_fitness or not _clearly_better(best.fitness, rival, lc.fix_misfit_ratio):
            logger.debug("no fix at %.1f: best %.3f on %d, rival %.3f", stamp_ns / 1e9,
                         best.fitness, best.floor, rival)
            return None
        return best

    def _allowed_floors(self) -> set[int]:
        if self.floor is not None:
            return {self.floor}
        log_floor = self.timeline.visits[self.visit][0]
        if self.hint is not None and self.hint.floor is not None and self.first_fix_ns is None:
            return {self.hint.floor}
        if self.pressure is None:
            return set(self.map.floors)
        return {m for h in self.tops if (m := h.floor_of(log_floor)) is not None}

    def _start_tracking(self, i: int, q: _Query, fix: Candidate) -> None:
        """Pose the query's scans from the fix and go on tracking from scan i."""
        from mfmap.mapping.geometry import inverse

        to_map = fix.pose @ inverse(q.chains[i])
        for k, chain in q.chains.items():
            self.track.poses[k] = to_map @ chain
            self.track.status[k] = Status.FIXED
            self.track.floor[k] = fix.floor
        self.track.status[i] = Status.TRACKED
        self.track.fitness[i] = fix.fitness
        first = min(q.chains)
        self.span_bests.pop(first, None)
        if self.chosen is None:
            log_floor = self.timeline.visits[self.visit][0]
            self.chosen = next((h for h in self.tops if h.floor_of(log_floor) == fix.floor), None)
            if self.chosen is None:  # no barometer: the log's one level is this floor
                from mfmap.localize.levels import FloorHypothesis

                offset = self.map.floors[fix.floor].elevation_m - self.seg.floors[0].elevation_m
                self.chosen = FloorHypothesis(offset, ((log_floor, fix.floor),), 0.0, 0.0)
        if self.first_fix_ns is None:
            self.first_fix_ns = self.track.stamps_ns[i]
            self.fix_floor = fix.floor
            if self.pressure is not None and len(self.pressure):
                self.fix_pressure_pa = float(np.interp(self.first_fix_ns, self.pressure.stamp_ns,
                                                       self.pressure.pressure_pa))
        self.mode, self.floor = "track", fix.floor
        self.anchor = (i, self.track.stamps_ns[i], fix.pose.copy())
        self.attempt_ns = self.track.stamps_ns[i]
        self.bad_since_ns = None
        self.query = None

    # ----- probes: when the hypotheses disagree about which visits the map has ------------------

    def _tie_break(self) -> None:
        """Keep the hypotheses whose floors fit the log's scans best, probing visits."""
        if len(self.tops) < 2:
            return
        assigned = [frozenset(lid for lid, m in h.assignment if m is not None) for h in self.tops]
        if len(set(assigned)) == 1:
            return  # they differ only in the floor: the first search decides
        evidence: list[float] = []
        cache: dict[tuple[int, int], float] = {}
        for hyp in self.tops:
            scores = []
            for visit, (log_floor, start_ns, end_ns) in self._longest_visits(hyp):
                floor = hyp.floor_of(log_floor)
                assert floor is not None
                if (visit, floor) not in cache:
                    cache[(visit, floor)] = self._probe(start_ns, end_ns, floor)
                scores.append(cache[(visit, floor)])
            evidence.append(sum(scores) / len(scores) if scores else 0.0)
        best = max(evidence)
        kept = [h for h, e in zip(self.tops, evidence, strict=True)
                if not _clearly_better(best, e, self.lc.fix_misfit_ratio)]
        self.probes = [{"offset_m": round(h.offset_m, 3), "evidence": round(e, 4)}
                       for h, e in zip(self.tops, evidence, strict=True)]
        self.tops = kept

    def _longest_visits(self, hyp: FloorHypothesis, count: int = 2
                        ) -> list[tuple[int, tuple[int, int, int]]]:
        visits = [(k, v) for k, v in enumerate(self.timeline.visits)
                  if hyp.floor_of(v[0]) is not None]
        visits.sort(key=lambda kv: -(kv[1][2] - kv[1][1]))
        return visits[:count]

    def _probe(self, start_ns: int, end_ns: int, floor: int) -> float:
        """The best fitness on `floor` of a query from the middle of a visit."""
        window = int(self.lc.query_window_s * 1e9)
        mid = (start_ns + end_ns) // 2
        lo, hi = max(start_ns, mid - window // 2), min(end_ns, mid + window // 2)
        q = _Query(lo)
        prev: int | None = None
        last = -1
        for k, cloud in enumerate(self.src.clouds(lo, hi)):
            chain = (np.eye(4) if prev is None
                     else q.chains[last] @ self.prep.delta(prev, cloud.stamp_ns, quick=True))
            q.chains[k] = chain
            last, prev = k, cloud.stamp_ns
            if k % QUERY_STRIDE == 0:
                q.clouds.append((k, self.prep.points(cloud.stamp_ns, cloud.frame_id, cloud.xyz,
                                                     cloud.t_offset_ns, chain, self.lc.query_voxel_m)))
        if len(q.clouds) < 2:
            return 0.0
        q.last_ns = prev if prev is not None else lo
        from mfmap.mapping.geometry import inverse, transform
        from mfmap.mapping.registration import downsample

        to_last = inverse(q.chains[last])
        points = downsample(np.concatenate([transform(p, to_last @ q.chains[k]) for k, p in q.clouds]),
                            self.lc.query_voxel_m)
        start = q.start_ns
        level = np.asarray(self.motion.level(np.eye(4), start, q.last_ns)[:3, :3])
        candidates = self._candidates(points, level, [floor])
        self.searches += 1
        return candidates[0].fitness if candidates else 0.0

    # ----- the results -----------------------------------------------------------------------

    def summary(self, log: Path, map_dir: Path, log_duration_s: float, elapsed_s: float,
                cpu_s: float) -> dict[str, Any]:
        """report.json's numbers."""
        track = self.track
        status = np.array([int(s) for s in track.status], dtype=np.int64)
        localised = status <= int(Status.STAIRS)
        start_ns = self.src.start_ns
        spans = self.spans()
        floors = self.floor_visits()
        return {
            "log": str(log),
            "map": str(map_dir),
            "log_duration_s": round(log_duration_s, 3),
            "elapsed_s": round(elapsed_s, 3),
            "cpu_s": round(cpu_s, 3),
            "realtime_factor": round(log_duration_s / elapsed_s, 2) if elapsed_s > 0 else None,
            "cpu_realtime_factor": round(log_duration_s / cpu_s, 2) if cpu_s > 0 else None,
            "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
            "scans": len(status),
            "scans_by_status": {s.label: int((status == int(s)).sum()) for s in Status},
            "localised_share": round(float(localised.mean()), 6) if len(status) else 0.0,
            "registered": int(np.isfinite(np.asarray(track.fitness)).sum()),
            "first_fix_s": None if self.first_fix_ns is None else round((self.first_fix_ns - start_ns) / 1e9, 3),
            "first_fix_floor": self.fix_floor,
            "offset_m": None if self.chosen is None else round(self.chosen.offset_m, 4),
            "pressure_offset_pa": self._pressure_offset(),
            "hypotheses": [{"offset_m": round(h.offset_m, 3),
                            "floors": {str(lid): m for lid, m in h.assignment},
                            "time_on_map_s": round(h.time_on_map_s, 1)} for h in self.hypotheses[:6]],
            "probes": getattr(self, "probes", []),
            "searches": self.searches,
            "search_log": self.search_log,
            "floors": floors,
            "not_localised": spans,
            "timings_s": {k: round(v, 3) for k, v in self.timings.wall_s.items()},
            "cpu_timings_s": {k: round(v, 3) for k, v in self.timings.cpu_s.items()},
        }

    def _pressure_offset(self) -> float | None:
        """This log's pressure on the fix's floor less the map's: the two days' weather."""
        if self.fix_pressure_pa is None or self.fix_floor is None:
            return None
        path = self.map.path / "floors.json"
        import json

        doc = json.loads(path.read_text())
        for item in doc.get("floors", []):
            if item.get("id") == self.fix_floor and isinstance(item.get("pressure_pa"), (int, float)):
                return round(self.fix_pressure_pa - float(item["pressure_pa"]), 1)
        return None

    def spans(self) -> list[dict[str, Any]]:
        """Runs of scans that are not posed, with why and the best fitness found in them."""
        track = self.track
        out: list[dict[str, Any]] = []
        k, n = 0, len(track.status)
        while k < n:
            if track.status[k].localised:
                k += 1
                continue
            j = k
            while j + 1 < n and not track.status[j + 1].localised:
                j += 1
            reasons = sorted({track.status[m].label for m in range(k, j + 1)})
            best = max((v for first, v in self.span_bests.items() if k <= first <= j), default=0.0)
            fits = [f for f in track.fitness[k:j + 1] if not math.isnan(f)]
            best = max([best, *fits])
            start = self.src.start_ns
            out.append({"t_start": track.stamps_ns[k] / 1e9, "t_end": track.stamps_ns[j] / 1e9,
                        "from_s": round((track.stamps_ns[k] - start) / 1e9, 3),
                        "to_s": round((track.stamps_ns[j] - start) / 1e9, 3),
                        "scans": j - k + 1, "reason": ", ".join(reasons),
                        "best_fitness": round(best, 4)})
            k = j + 1
        return out

    def floor_visits(self) -> list[dict[str, Any]]:
        """The map's floors with this log's visits (runs of localised scans on each)."""
        track = self.track
        visits: dict[int, list[list[float]]] = {fid: [] for fid in self.map.floors}
        current: tuple[int, int] | None = None  # (floor, first index)
        n = len(track.status)
        for k in range(n + 1):
            floor = track.floor[k] if k < n and track.status[k].localised else -1
            if current is not None and floor != current[0]:
                visits[current[0]].append([track.stamps_ns[current[1]] / 1e9,
                                           track.stamps_ns[k - 1] / 1e9])
                current = None
            if current is None and floor >= 0:
                current = (floor, k)
        return [{"id": fid, "elevation_m": round(self.map.floors[fid].elevation_m, 4),
                 "visits": visits[fid]} for fid in sorted(self.map.floors)]

    def arrays(self) -> tuple[np.ndarray, F64, np.ndarray, np.ndarray, np.ndarray]:
        t = self.track
        return (np.asarray(t.stamps_ns, dtype=np.int64), np.stack(t.poses) if t.poses else np.zeros((0, 4, 4)),
                np.asarray(t.floor, dtype=np.int32), np.asarray([int(s) for s in t.status], dtype=np.int8),
                np.asarray(t.fitness, dtype=np.float64))

    @property
    def segmentation(self) -> FloorSegmentation:
        return self.seg


def render_summary(result: LocalizeResult) -> RenderableType:
    """The terminal summary: floors visited, spans not localised, speed, where the outputs are."""
    from rich.console import Group
    from rich.text import Text

    from mfmap.tables import table

    floors = table([("floor", "right"), ("elevation [m]", "right"), ("visits", "right"),
                    ("time [s]", "right")], title="floors", title_justify="left")
    for f in result.floors:
        time_s = sum(b - a for a, b in f["visits"])
        floors.add_row(str(f["id"]), f"{f['elevation_m']:+.3f}", str(len(f["visits"])), f"{time_s:.1f}")
    spans = table([("from [s]", "right"), ("to [s]", "right"), ("why", "left"),
                   ("best fitness", "right")], title="not localised", title_justify="left")
    for s in result.spans:
        spans.add_row(f"{s['from_s']:.1f}", f"{s['to_s']:.1f}", s["reason"], f"{s['best_fitness']:.2f}")
    fix = "no fix" if result.first_fix_s is None else f"first fix {result.first_fix_s:.1f} s into the log"
    lines = Text(
        f"localised {result.log.name} ({result.log_duration_s:.0f} s of log) in {result.map} in "
        f"{result.elapsed_s:.1f} s ({result.cpu_s:.1f} s of CPU): {result.realtime_factor:.1f}x "
        f"real time ({result.cpu_realtime_factor:.1f}x by CPU); "
        f"{100 * result.localised_share:.1f} % of {result.scans} scans localised, {fix}, "
        f"{result.searches} searches\noutputs: {result.out}/ (trajectory.tum, floors.json, "
        "scans.csv, report.json, report.html, floors/<id>/path.png)"
    )
    parts: list[RenderableType] = [floors]
    if result.spans:
        parts.append(spans)
    parts.append(lines)
    return Group(*parts)


__all__ = ["Hint", "LocalizeResult", "Status", "localize", "render_summary"]
