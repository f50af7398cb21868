"""The localiser while it searches: a query of scans against every floor allowed, a fix only
when no distinct place fits nearly as well; and the probes that decide between the barometer's
hypotheses. The coarse search and the refinement are mfmap.localize.search."""

from __future__ import annotations

import logging
import math
from typing import TYPE_CHECKING

import numpy as np

from mfmap.localize.records import Hint, Query, Status
from mfmap.localize.state import (
    COARSE_KEEP,
    MAX_RETRY_S,
    QUERY_STRIDE,
    RETRY_GROWTH,
    LocalizerState,
    clearly_better,
    distinct_best,
)
from mfmap.types import F64

if TYPE_CHECKING:
    from mfmap.localize.levels import FloorHypothesis
    from mfmap.localize.search import Candidate

logger = logging.getLogger(__name__)


class Searching(LocalizerState):
    """Global search for a fix, and tracking started from it."""

    def _search_scan(self, stamp_ns: int, frame_id: str, xyz: np.ndarray,
                     t_offset_ns: np.ndarray | None) -> None:
        status = self._status_unposed()
        i = self.track.add(stamp_ns, status)
        self._unposed(i)
        if self.mode in ("no_floor", "ambiguous") and self.visit in self.probed_visits:
            return
        q = self.query
        if q is None:
            q = self.query = Query(stamp_ns)
            q.chains[i] = np.eye(4)
        else:
            last = max(q.chains)
            q.chains[i] = q.chains[last] @ self.prep.delta(q.last_ns, stamp_ns, quick=True)
        q.last_ns = stamp_ns
        if len(q.chains) % QUERY_STRIDE == 1 and not self.prep.in_cabin(stamp_ns, q.chains[i]):
            q.clouds.append((i, self.prep.points(stamp_ns, frame_id, xyz, t_offset_ns, q.chains[i],
                                                 self.lc.search.query_voxel_m)))
        window_ns = int(self.lc.search.query_window_s * 1e9)
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

    def _search(self, i: int, q: Query) -> None:
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
                      "fitness": round(c.fitness, 4)} for c in distinct_best(candidates, 3)],
        })
        if report_only:
            self.probed_visits.add(self.visit)
            self.query = None
            return
        if fix is None and self.hint is not None and self.hint.has_pose:
            logger.warning("the initial pose does not fit (fitness %.2f): searching without it", best)
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

    def _level(self, q: Query) -> F64:
        """The query frame's tilt to gravity (3x3), from the accelerometer over the window."""
        start = self.track.stamps_ns[q.clouds[0][0]]
        return np.asarray(self.motion.level(np.eye(4), start, q.last_ns)[:3, :3])

    def _query_points(self, q: Query, i: int) -> F64:
        """The query's points in the base frame of scan i."""
        from mfmap.mapping.geometry import inverse, transform
        from mfmap.mapping.registration import downsample

        to_last = inverse(q.chains[i])
        parts = [transform(pts, to_last @ q.chains[k]) for k, pts in q.clouds]
        return downsample(np.concatenate(parts), self.lc.search.query_voxel_m)

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
            found = coarse_places(floor.search_field(lc.search.resolution_m), band,
                                  lc.search.yaw_step_deg, lc.search.range_m,
                                  lc.search.candidates, lc.distinct_m, lc.distinct_deg)
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
        if best.fitness < lc.fix_fitness or not clearly_better(best.fitness, rival, lc.fix_misfit_ratio):
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

    def _start_tracking(self, i: int, q: Query, fix: Candidate) -> None:
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


class Probing(Searching):
    """Probes: when the hypotheses disagree about which visits the map has."""

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
                if not clearly_better(best, e, self.lc.fix_misfit_ratio)]
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
        window = int(self.lc.search.query_window_s * 1e9)
        mid = (start_ns + end_ns) // 2
        lo, hi = max(start_ns, mid - window // 2), min(end_ns, mid + window // 2)
        q = Query(lo)
        prev: int | None = None
        last = -1
        for k, cloud in enumerate(self.src.clouds(lo, hi)):
            chain = (np.eye(4) if prev is None
                     else q.chains[last] @ self.prep.delta(prev, cloud.stamp_ns, quick=True))
            q.chains[k] = chain
            last, prev = k, cloud.stamp_ns
            if k % QUERY_STRIDE == 0:
                q.clouds.append((k, self.prep.points(cloud.stamp_ns, cloud.frame_id, cloud.xyz,
                                                     cloud.t_offset_ns, chain, self.lc.search.query_voxel_m)))
        if len(q.clouds) < 2:
            return 0.0
        q.last_ns = prev if prev is not None else lo
        from mfmap.mapping.geometry import inverse, transform
        from mfmap.mapping.registration import downsample

        to_last = inverse(q.chains[last])
        points = downsample(np.concatenate([transform(p, to_last @ q.chains[k]) for k, p in q.clouds]),
                            self.lc.search.query_voxel_m)
        start = q.start_ns
        level = np.asarray(self.motion.level(np.eye(4), start, q.last_ns)[:3, :3])
        candidates = self._candidates(points, level, [floor])
        self.searches += 1
        return candidates[0].fitness if candidates else 0.0
