"""What a build did: report.json (`BuildReport`, which report.html also shows) and the result
`mfmap build` returns and the terminal shows (`BuildResult`, `render_summary`)."""

from __future__ import annotations

import math
import resource
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mfmap.types import TransitionKind

if TYPE_CHECKING:
    from rich.console import RenderableType


@dataclass(frozen=True)
class BuildTotals:
    """The whole build's time and memory, known only once everything is written."""

    build_s: float
    realtime_factor: float | None  # log duration / build time; None for a build of no time
    peak_rss_mb: float

    @classmethod
    def measure(cls, elapsed_s: float, log_duration_s: float) -> BuildTotals:
        """The totals of a build that took `elapsed_s`, with this process's peak memory."""
        factor = round(log_duration_s / elapsed_s, 2) if elapsed_s > 0 else None
        peak_mb = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
        return cls(round(elapsed_s, 3), factor, peak_mb)


@dataclass
class ReportSummary:
    """report.json's `summary`: the building in four numbers, then the totals."""

    floors: int
    transitions: int
    log_duration_s: float
    keyframes: int
    totals: BuildTotals | None = None

    def to_json(self) -> dict[str, Any]:
        doc: dict[str, Any] = {
            "floors": self.floors,
            "transitions": self.transitions,
            "log_duration_s": round(self.log_duration_s, 3),
            "keyframes": self.keyframes,
        }
        if self.totals is not None:
            doc["build_s"] = self.totals.build_s
            doc["realtime_factor"] = self.totals.realtime_factor
            doc["peak_rss_mb"] = self.totals.peak_rss_mb
        return doc


@dataclass
class BuildReport:
    """report.json: the log, how it was read, counts, per-stage timings, mapping and graph
    figures, warnings, and what the exports hold.

    `timings_s` are the stages' seconds as measured (rounded in `to_json`); `total_s` and the
    summary's totals are set by `finish` once the outputs are written.
    """

    log: str
    ingest: dict[str, Any]
    summary: ReportSummary
    counts: dict[str, int]
    timings_s: dict[str, float]
    mapping: dict[str, float]
    graph: dict[str, Any]
    warnings: list[str] = field(default_factory=list)
    exports: dict[str, Any] | None = None
    total_s: float | None = None

    def finish(self, elapsed_s: float) -> None:
        """The build is complete: its whole time and peak memory."""
        self.total_s = elapsed_s
        self.summary.totals = BuildTotals.measure(elapsed_s, self.summary.log_duration_s)

    def to_json(self) -> dict[str, Any]:
        timings = {k: round(v, 3) for k, v in self.timings_s.items()}
        if self.total_s is not None:
            timings["total"] = round(self.total_s, 3)
        doc: dict[str, Any] = {
            "log": self.log,
            "ingest": self.ingest,
            "summary": self.summary.to_json(),
            "counts": self.counts,
            "timings_s": timings,
            "mapping": self.mapping,
            "graph": self.graph,
            "warnings": self.warnings,
        }
        if self.exports is not None:
            doc["exports"] = self.exports
        return doc




# ----- the build's result, as the terminal shows it ------------------------------------------


@dataclass(frozen=True)
class FloorRow:
    """One floor of floors.json."""

    id: int
    elevation_m: float
    visits: int
    connectors: tuple[int, ...]  # ids of the elevators and stairwells that reach it


@dataclass(frozen=True)
class TransitionRow:
    """One ride or stair walk of floors.json."""

    kind: TransitionKind
    from_floor: int
    to_floor: int
    height_change_m: float
    duration_s: float
    xy_m: tuple[float, float] | None  # where it started, when the trajectory reaches it


@dataclass(frozen=True)
class ConnectorRow:
    """One elevator shaft or stairwell of floors.json."""

    id: int
    kind: TransitionKind
    x_m: float
    y_m: float
    floors: tuple[int, ...]


def floor_rows(floors_doc: dict[str, Any]) -> list[FloorRow]:
    """The floors of a floors.json document."""
    return [FloorRow(f["id"], f["elevation_m"], len(f["visits"]), tuple(f["connectors"]))
            for f in floors_doc["floors"]]


def transition_rows(floors_doc: dict[str, Any]) -> list[TransitionRow]:
    """The transitions of a floors.json document."""
    return [TransitionRow(TransitionKind(t["kind"]), t["from"], t["to"], t["height_change_m"],
                          t["t_end"] - t["t_start"], (t["x"], t["y"]) if "x" in t else None)
            for t in floors_doc["transitions"]]


def connector_rows(floors_doc: dict[str, Any]) -> list[ConnectorRow]:
    """The connectors of a floors.json document."""
    return [ConnectorRow(c["id"], TransitionKind(c["kind"]), c["x"], c["y"], tuple(c["floors"]))
            for c in floors_doc["connectors"]]


@dataclass
class BuildResult:
    """What `mfmap build` did and where its outputs are."""

    log: Path
    out: Path
    log_duration_s: float
    elapsed_s: float
    timings_s: dict[str, float]
    floors: list[FloorRow]
    transitions: list[TransitionRow]
    connectors: list[ConnectorRow]
    counts: dict[str, int]
    graph: dict[str, Any]  # report.json's `graph`
    files: list[str]
    warnings: list[str] = field(default_factory=list)

    @property
    def realtime_factor(self) -> float:
        """Log duration / build time (above 1: faster than real time)."""
        return self.log_duration_s / self.elapsed_s if self.elapsed_s > 0 else math.inf


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
        floors.add_row(str(f.id), f"{f.elevation_m:+.3f}", str(f.visits),
                       ",".join(str(c) for c in f.connectors) or "-")
    transitions = table(
        right("kind", "from", "to", "height change [m]", "duration [s]", "x, y"),
        title="transitions",
        title_justify="left",
    )
    for t in result.transitions:
        xy = f"{t.xy_m[0]:.2f}, {t.xy_m[1]:.2f}" if t.xy_m is not None else "-"
        transitions.add_row(t.kind.value, str(t.from_floor), str(t.to_floor), f"{t.height_change_m:+.3f}",
                            f"{t.duration_s:.1f}", xy)
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


__all__ = [
    "BuildReport", "BuildResult", "BuildTotals", "ConnectorRow", "FloorRow", "ReportSummary", "TransitionRow",
    "connector_rows", "floor_rows", "render_summary", "transition_rows",
]
