"""Terminal rendering of a MappingResult (rich renderables; the CLI prints them)."""

from __future__ import annotations

from rich.table import Table

from mfmap.types import MappingResult


def render_mapping(result: MappingResult) -> Table:
    """Keyframes, edges and speed per visit, plus the stage's counters."""
    table = Table(title="mapping")
    table.add_column("visit", justify="right")
    table.add_column("floor", justify="right")
    table.add_column("keyframes", justify="right")
    table.add_column("loops", justify="right")
    by_visit: dict[int, list[int]] = {}
    floor_of: dict[int, int] = {}
    for kf in result.keyframes:
        by_visit.setdefault(kf.visit, []).append(kf.id)
        floor_of[kf.visit] = kf.floor_id
    visit_of = {kf.id: kf.visit for kf in result.keyframes}
    for visit, ids in sorted(by_visit.items()):
        loops = sum(e.kind == "loop" and visit_of.get(e.j) == visit for e in result.edges)
        table.add_row(str(visit), str(floor_of[visit]), str(len(ids)), str(loops))
    for key in ("scans", "registered", "scans_per_s", "loop_candidates", "max_local_map_points"):
        if key in result.stats:
            table.caption = (table.caption or "") + f"{key}={result.stats[key]:.0f}  "
    return table
