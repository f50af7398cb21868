"""The localiser's state as the scans stream by, shared by its tracking and its searching."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

import numpy as np

from mfmap.config import MfmapConfig
from mfmap.localize.records import Hint, Query, Status, Timings, Track
from mfmap.progress import Progress
from mfmap.types import F64

if TYPE_CHECKING:
    from mfmap.ingest.source import LogSource
    from mfmap.localize.levels import FloorHypothesis
    from mfmap.localize.mapfolder import BuildingMap
    from mfmap.localize.search import Candidate
    from mfmap.localize.track import ScanPrep, Wheels
    from mfmap.logs import WarningCollector
    from mfmap.mapping.motion import MotionModel
    from mfmap.mapping.timeline import Timeline

logger = logging.getLogger(__name__)
_floors_log = logging.getLogger("mfmap.floors")  # the floors stage's returned warnings

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


def distinct_best(candidates: list[Candidate], count: int) -> list[Candidate]:
    """The best candidates, one per place (several coarse places often refine to one)."""
    out: list[Candidate] = []
    for c in candidates:
        if all(c.distinct(o, 0.2, 2.0) for o in out):
            out.append(c)
        if len(out) == count:
            break
    return out


def clearly_better(fitness: float, rival: float, misfit_ratio: float) -> bool:
    """Whether a place of this fitness beats one of the rival's: the rival leaves at least
    misfit_ratio times as many points unfit."""
    return (1.0 - rival) >= misfit_ratio * (1.0 - fitness)


class LocalizerState:
    """The log, the map, the floors' hypotheses and where the localiser stands."""

    def __init__(self, src: LogSource, building: BuildingMap, cfg: MfmapConfig, hint: Hint | None,
                 collected: WarningCollector, timings: Timings, progress: Progress) -> None:
        from mfmap.localize.levels import best_hypotheses, floor_hypotheses
        from mfmap.mapping.timeline import Timeline
        from mfmap.pipeline import segment_floors

        self.src = src
        self.map = building
        self.cfg = cfg
        self.lc = cfg.localize
        self.hint = hint
        self.collected = collected
        self.timings = timings
        self.progress = progress
        with timings("floors"):
            self.pressure, self.seg = segment_floors(src, cfg)
        for text in self.seg.warnings:
            _floors_log.warning(text)
        self.timeline = Timeline(self.seg)
        self.motion, self.wheels, self.prep = _scan_prep(src, cfg, self.timeline)
        self.tolerance_m = building.floor_tolerance_m(self.lc.floor_tolerance_share,
                                                      self.lc.floor_tolerance_max_m)
        levels = {f.id: f.elevation_m for f in self.seg.floors}
        visit_time = {f.id: sum((e - s) / 1e9 for s, e in f.visits) for f in self.seg.floors}
        self.hypotheses = floor_hypotheses(levels, visit_time, building.elevations, self.tolerance_m)
        self.tops = best_hypotheses(self.hypotheses)
        self.chosen: FloorHypothesis | None = None
        if self.pressure is None:
            logger.warning("no barometer: the floor is not followed through rides or stairs",
                           extra={"stage": ""})
        self.track = Track()
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
        self.query: Query | None = None
        self.next_search_ns = 0
        self.retry_s = self.lc.retry_s
        self.span_best = 0.0
        self.span_bests: dict[int, float] = {}  # first scan of a not-localised span -> best fitness
        self.probed_visits: set[int] = set()
        self.ride_from: tuple[int, int, F64] | None = None  # (map floor, start ns, pose)
        self.profiles: dict[int, Any] = {}  # ride start -> its height profile
        self.attempt_ns: int | None = None  # the last registration tried

    @property
    def warnings(self) -> list[str]:
        """The run's warnings so far (its report's)."""
        return self.collected.lines()

    def _status_unposed(self) -> Status:
        return {"no_floor": Status.NO_FLOOR, "ambiguous": Status.AMBIGUOUS}.get(self.mode,
                                                                                  Status.NO_FIX)

    def _unposed(self, i: int) -> None:
        """Bookkeeping for a scan that is not posed: it belongs to the current span."""
        if i == 0 or self.track.status[i - 1].localised:
            self.span_bests.setdefault(i, 0.0)

    def _height(self, stamp_ns: int) -> float:
        seg = self.seg
        if len(seg.stamp_ns) < 2:
            return 0.0
        return float(np.interp(stamp_ns, seg.stamp_ns, seg.height_filtered_m))


def _scan_prep(src: LogSource, cfg: MfmapConfig, timeline: Timeline) -> tuple[MotionModel, Wheels, ScanPrep]:
    """The motion prior, the wheel odometry and the scans' preparation (deskewing, the cabin
    filter, thinning) for the log."""
    from mfmap.localize.track import ScanPrep, Wheels
    from mfmap.mapping.cabin import CabinFilter
    from mfmap.mapping.config import MotionPrior
    from mfmap.mapping.motion import MotionModel

    extrinsics = src.extrinsics()
    motion = MotionModel(MotionPrior.AUTO, src.odometry(), src.imu(), extrinsics)
    cabin = (CabinFilter(cfg.mapping, list(timeline.transitions), motion)
             if cfg.mapping.cabin.filter else None)
    wheels = Wheels(src.odometry())
    return motion, wheels, ScanPrep(cfg.localize, extrinsics, motion, cabin, wheels)
