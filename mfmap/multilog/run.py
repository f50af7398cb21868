"""`mfmap build A B ... -o OUT`: several logs of one building, one map in the building frame.

1. Each log through the floors, mapping and its own factor graph, as a single-log build
   (`mfmap.multilog.logs`).
2. Each log placed in the building: its floors registered on the floors placed before it, its
   frame found with them (`mfmap.multilog.place`, `mfmap.multilog.match`); logs that share no
   floor clearly are refused by name.
3. One factor graph over all logs (`mfmap.multilog.joint`), optimised.
4. The usual outputs from every log's scans at the building's poses, plus
   `trajectories/<index>-<log>.tum` per log and report.json's `logs`: which log floor became
   which building floor and the registrations with their fitness.

`--extend OUT` rebuilds OUT's logs with the new ones into a new folder; OUT is only read.
"""

from __future__ import annotations

import contextlib
import json
import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mfmap.config import MfmapConfig
from mfmap.errors import MfmapError
from mfmap.logs import collect_warnings
from mfmap.multilog.logs import LogRun, run_log
from mfmap.multilog.match import MatchConfig
from mfmap.multilog.place import Placement, place_logs
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
from mfmap.types import EdgeKind

logger = logging.getLogger(__name__)


def logs_of_build(folder: Path) -> list[Path]:
    """The logs a build folder was made from (its report.json), for `--extend`."""
    path = Path(folder) / "report.json"
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise MfmapError(f"--extend: {folder} is not a build folder (no readable report.json)") from err
    logs = [item["log"] for item in doc.get("logs", [])] or [doc.get("log")]
    missing = [str(p) for p in logs if not p or not Path(p).exists()]
    if missing:
        raise MfmapError(f"--extend: the logs {folder} was built from are needed again and "
                         f"are gone: {', '.join(missing)}")
    return [Path(p) for p in logs]


def build_logs(logs: Sequence[Path], out: Path, cfg: MfmapConfig, force: bool = False,
               progress: Progress | None = None, inputs: Sequence[Path] = (),
               extend: Path | None = None) -> BuildResult:
    """Build one map of the building from several logs of it into the folder `out`."""
    started = time.perf_counter()
    progress = progress or NullProgress()
    logs = [Path(p) for p in logs]
    if extend is not None:
        logs = [*logs_of_build(extend), *logs]
        inputs = [*inputs, Path(extend)]
    _check_distinct(logs)
    # OUT2 may be neither inside a log's folder nor inside the extended build.
    folders = [f for log in logs for f in log_folders(log)] + ([Path(extend)] if extend else [])
    run = RunFolder.create(Path(out), [*logs, *inputs], folders, force,
                           sum(input_size(log) for log in logs))
    with collect_warnings(first=("build", "ingest")) as collected, run.writing() as partial, \
            contextlib.ExitStack() as opened:
        for note in run.notes:
            logger.warning(note)
        from mfmap.ingest import open_log

        runs: list[LogRun] = []
        for index, log in enumerate(logs):
            src = opened.enter_context(open_log(log, cfg.ingest))
            runs.append(run_log(index, log, src, cfg, progress, collected))
        building = _Building.assemble(runs, cfg, progress)
        report = building.write(partial, cfg, collected.lines())
        elapsed = time.perf_counter() - started
        report.finish(elapsed)
        files = run.commit(report.to_json())
    doc = building.floors_doc
    return BuildResult(
        log=logs[0], out=Path(out), log_duration_s=report.summary.log_duration_s,
        elapsed_s=elapsed, timings_s=building.timings, floors=floor_rows(doc),
        transitions=transition_rows(doc), connectors=connector_rows(doc), counts=report.counts,
        graph=report.graph, files=files, warnings=report.warnings)


def _check_distinct(logs: list[Path]) -> None:
    seen: set[Path] = set()
    for log in logs:
        real = log.resolve()
        if real in seen:
            raise MfmapError(f"{log} is given twice: each log is built once")
        seen.add(real)


@dataclass
class MultiLogReport(BuildReport):
    """report.json of a build from several logs: the usual keys, and `logs`."""

    logs: list[dict[str, Any]] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        doc = super().to_json()
        doc["logs"] = self.logs
        return doc


@dataclass
class MultiLogSummary(ReportSummary):
    """The summary (report.html's first table) with a line per log: its floors and fit."""

    lines: dict[str, str] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {**super().to_json(), **self.lines}


@dataclass
class _Building:
    """The placed logs and the building's optimised poses, and the outputs made of them."""

    runs: list[LogRun]
    placement: Placement
    final: dict[int, int]  # provisional building floor -> final id
    poses: dict[int, dict[int, Any]]  # log index -> keyframe id -> building-frame pose
    graph_json: dict[str, Any]
    timings: dict[str, float]
    floors_doc: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def assemble(cls, runs: list[LogRun], cfg: MfmapConfig, progress: Progress) -> _Building:
        """Place the logs, then optimise the building's graph over all of them."""
        from mfmap.multilog.graph import building_graph

        timings: dict[str, float] = {}
        for name in ("floors", "mapping", "graph"):
            timings[name] = sum(r.stages.timings.get(name, 0.0) for r in runs)
        t0 = time.perf_counter()
        with progress.stage("place", total=None):
            placement = place_logs(runs, MatchConfig())
        timings["place"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        with progress.stage("building", total=None):
            poses, graph_json = building_graph(runs, placement, cfg)
        timings["building_graph"] = time.perf_counter() - t0
        return cls(runs, placement, placement.renumbered(), poses, graph_json, timings)

    def write(self, partial: Path, cfg: MfmapConfig, warnings: list[str]) -> MultiLogReport:
        """Every output into the partial folder; the report (report.json is the caller's)."""
        from mfmap.multilog.outputs import write_building_outputs

        t0 = time.perf_counter()
        report = self.report(warnings)
        self.floors_doc = write_building_outputs(partial, self.runs, self.placement, self.poses,
                                                 cfg, report)
        self.timings["maps_and_export"] = time.perf_counter() - t0
        report.timings_s = self.timings
        return report

    def report(self, warnings: list[str]) -> MultiLogReport:
        runs = self.runs
        counts = {
            "logs": len(runs),
            "floors": len(self.final),
            "transitions": sum(len(r.floors.seg.transitions) for r in runs),
            "keyframes": sum(len(r.mapping.keyframes) for r in runs),
            "edges": sum(len(r.mapping.edges) for r in runs),
            "loop_edges": sum(1 for r in runs for e in r.mapping.edges if e.kind == EdgeKind.LOOP),
            "scans": sum(len(r.mapping.scan_poses) for r in runs),
        }
        duration = sum(r.stages.log_duration_s for r in runs)
        logs = self.placement.to_json(runs, self.final)
        summary = MultiLogSummary(len(self.final), counts["transitions"], duration,
                                  counts["keyframes"], lines=_summary_lines(logs))
        return MultiLogReport(
            log=", ".join(str(r.path) for r in runs),
            ingest={"logs": [r.src.report() for r in runs]}, summary=summary, counts=counts,
            timings_s=self.timings,
            mapping={f"{k}.{r.index}": float(v) for r in runs for k, v in r.mapping.stats.items()},
            graph=self.graph_json, warnings=warnings, logs=logs)


def _summary_lines(logs: list[dict[str, Any]]) -> dict[str, str]:
    """report.html's summary: per log, its floors on the building's and how it was placed."""
    lines: dict[str, str] = {}
    for item in logs:
        floors = ", ".join(f"{j} -> {k}" for j, k in item["floors"].items())
        reg = item["registration"]
        how = reg if isinstance(reg, str) else "; ".join(
            f"floor {r['log_floor']} on {r['building_floor']} at fitness {r['fitness']:.2f}"
            for r in reg)
        path = Path(item["log"])
        lines[f"log {item['index']}"] = f"{path.parent.name}/{path.name}: floors {floors}; {how}"
    return lines


__all__ = ["MultiLogReport", "build_logs", "logs_of_build"]
