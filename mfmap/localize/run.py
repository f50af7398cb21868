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

import logging
import math
import resource
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mfmap.config import MfmapConfig
from mfmap.errors import MfmapError, MissingDataError
from mfmap.localize.records import Hint, LocalizeResult, Status, Timings
from mfmap.localize.searching import Probing
from mfmap.localize.tracking import Tracking
from mfmap.logs import collect_warnings
from mfmap.progress import NullProgress, Progress
from mfmap.types import F64, FloorSegmentation, Role

if TYPE_CHECKING:
    from rich.console import RenderableType

logger = logging.getLogger(__name__)
_ingest_log = logging.getLogger("mfmap.ingest")  # the log's own warnings, read off the LogSource


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
    from mfmap.runfolder import RunFolder, check_output, input_size
    from mfmap.runfolder import log_folders as _log_folders

    started = time.perf_counter()
    cpu0 = time.process_time()
    progress = progress or NullProgress()
    log, map_dir, out = Path(log), Path(map_dir), Path(out)
    # Checked before any work: never an input (the log, the map) nor inside one.
    check_output(out, [log, map_dir], [*_log_folders(log), map_dir], force)
    lc = cfg.localize
    timings = Timings()
    # Every warning of the run, in the order they arose, into its report.
    with collect_warnings() as collected:
        with timings("map"):
            building = load_map(map_dir, lc.map_voxel_m, 3.0 * lc.map_voxel_m, lc.band_m)
        if hint is not None and hint.floor is not None and hint.floor not in building.floors:
            raise MfmapError(f"--floor {hint.floor}: the map has floors "
                             f"{', '.join(str(f) for f in sorted(building.floors))}")
        folder = RunFolder.create(out, [log, map_dir], [*_log_folders(log), map_dir], force,
                                  input_size(log))
        for note in folder.notes:
            logger.warning(note)
        partial = folder.partial
        with folder:
            with timings("open"):
                src = open_log(log, cfg.ingest)
            with src:
                for text in src.warnings:
                    _ingest_log.warning(text)
                if Role.LIDAR not in src.roles:
                    what = "only 2D LaserScan" if Role.SCAN2D in src.roles else "no lidar"
                    raise MissingDataError(f"localize needs a 3D lidar (PointCloud2); the log has {what}",
                                           log)
                run = _Localizer(src, building, cfg, hint, collected, timings, progress)
                run.run()
            log_duration_s = max((src.end_ns - src.start_ns) / 1e9, 0.0)
            elapsed = time.perf_counter() - started
            summary = run.summary(log, map_dir, log_duration_s, elapsed, time.process_time() - cpu0)
            with timings("output"):
                files = write_outputs(partial, run, summary, cfg, building)
            summary.update(_finish_report(partial / "report.json", timings, started, cpu0,
                                          log_duration_s))
            folder.commit()
        return LocalizeResult.of(log, map_dir, out, log_duration_s, summary, files, collected.lines(),
                                 dict(timings.cpu_s))


def _finish_report(path: Path, timings: Timings, started: float, cpu0: float,
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


class _Localizer(Tracking, Probing):
    """One pass over the log's scans, and what it found."""

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
            logger.warning("no extrinsic for lidar frame(s) %s: used identity",
                           ", ".join(sorted(self.prep.missing_frames)), extra={"stage": ""})

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
