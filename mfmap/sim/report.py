"""Terminal rendering of a simulation result (the CLI prints it)."""

from __future__ import annotations

from rich.table import Table

from mfmap.sim.run import SimResult


def render_simulation(result: SimResult) -> Table:
    table = Table(title=f"simulated '{result.scenario}' (seed {result.seed}, {result.fmt})")
    table.add_column("item")
    table.add_column("value", justify="right")
    table.add_row("log", str(result.log_path))
    table.add_row("size", f"{result.log_bytes / 1e6:.1f} MB")
    table.add_row("duration", f"{result.duration_s:.0f} s")
    table.add_row("floors", str(result.n_floors))
    for topic, count in sorted(result.message_counts.items()):
        table.add_row(topic, f"{count} msgs")
    for path in (result.gt_trajectory, result.gt_points, result.gt_floors, result.gt_cloud, *result.plots):
        table.add_row("wrote", str(path))
    rate = result.duration_s / max(result.wall_time_s, 1e-9)
    table.add_row("wall time", f"{result.wall_time_s:.1f} s ({rate:.1f} s of log per s)")
    return table
