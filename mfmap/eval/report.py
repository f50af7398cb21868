"""Rich tables of an EvalResult, laid out like the seeds' accuracy tables."""

from __future__ import annotations

from typing import Any

from rich.console import Group, RenderableType
from rich.table import Table
from rich.text import Text

from mfmap.eval.metrics import EvalResult


def _xyz(v: list[float]) -> str:
    return "(" + ", ".join(f"{c:.2f}" for c in v) + ")"


def _num(value: Any, digits: int = 3) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def points_table(result: EvalResult) -> Table:
    """Table I of the LeGO-LOAM elevator paper: ground truth and the estimate on each floor, per checkpoint."""
    data = result.tables["points"]
    floors: list[int] = data["floors"]
    m = result.metrics
    table = Table(title="Checkpoints: ground truth and estimated position (Table I layout of the LeGO-LOAM elevator paper)")
    table.add_column("Point")
    table.add_column("Ground truth (m)")
    for fid in floors:
        table.add_column(f"Floor {fid} estimate (m)")
        table.add_column(f"err {fid} (m)", justify="right")
    for row in data["rows"]:
        cells = [row.get(f"floor{fid}") for fid in floors]
        present = [c for c in cells if c is not None]
        xy = {(round(c["gt"][0], 3), round(c["gt"][1], 3)) for c in present}
        if len(xy) == 1:
            x, y = present[0]["gt"][:2]
            zs = " / ".join(f"{c['gt'][2]:.2f}" for c in present)
            truth = f"({x:.2f}, {y:.2f}, {zs})"
        else:
            truth = " / ".join(_xyz(c["gt"]) for c in present)
        out = [str(row["label"]), truth]
        for c in cells:
            out += ["-", "-"] if c is None else [_xyz(c["est"]), f"{c['error_m']:.3f}"]
        table.add_row(*out)
    footer = ["RMSE", f"all {m['points.rmse_m']:.3f} m"]
    for fid in floors:
        footer += ["", f"{m[f'points.floor{fid}.rmse_m']:.3f}"]
    table.add_row(*footer, style="bold")
    table.caption = (
        f"{m['points.count']:.0f} points; RMSE {m['points.rmse_m']:.3f} m, "
        f"z RMSE {m['points.z_rmse_m']:.3f} m, max {m['points.max_m']:.3f} m; "
        f"Hilti score {m['points.hilti_score']:.1f}/100"
    )
    return table


def trajectory_table(result: EvalResult) -> Table:
    m = result.metrics
    table = Table(title="Trajectory: absolute pose error")
    for name in ("alignment", "pairs", "APE RMSE (m)", "mean", "median", "max", "rot RMSE (°)", "rot max (°)", "tilt RMSE (°)",
                 "z RMSE (m)"):
        table.add_column(name, justify="left" if name == "alignment" else "right")
    for prefix, label in (("trajectory", "none"), ("trajectory.se3", "SE(3)"), ("trajectory.4dof", "4-DoF")):
        if f"{prefix}.ape_rmse_m" not in m:
            continue
        keys = ("ape_rmse_m", "ape_mean_m", "ape_median_m", "ape_max_m", "rot_rmse_deg", "rot_max_deg", "tilt_rmse_deg",
                "z_rmse_m")
        table.add_row(label, f"{m[prefix + '.pairs']:.0f}", *(_num(m[f"{prefix}.{k}"], 4) for k in keys))
    floors = sorted(int(k.split(".")[1][5:]) for k in m if k.startswith("trajectory.floor") and k.endswith(".pairs"))
    for fid in floors:
        p = f"trajectory.floor{fid}"
        table.add_row(
            f"none, floor {fid}", f"{m[p + '.pairs']:.0f}", _num(m[p + ".ape_rmse_m"], 4),
            "", "", "", "", "", "", _num(m[p + ".z_rmse_m"], 4),
        )  # fmt: skip
    return table


def floors_tables(result: EvalResult) -> list[RenderableType]:
    """Floor count and elevation, then the multi-floor precision mapping paper's Table 1 (x, y, yaw) and Table 2 (z)."""
    m = result.metrics
    data = result.tables["floors"]
    share = m.get("floors.time_correct_share")
    head = Text(
        f"Floors: {m['floors.count_est']:.0f} in the build, {m['floors.count_gt']:.0f} in the ground truth "
        f"({'right' if m['floors.count_correct'] else 'WRONG'}); time on the right floor "
        + ("-" if share is None else f"{100 * share:.1f} %")
        + f"; transitions missed {m['floors.transitions_missed']:.0f}, extra {m['floors.transitions_extra']:.0f}"
    )
    elev = Table(title="Floor elevations (relative to the start floor)")
    for name in ("GT floor", "GT elevation (m)", "build floor", "build elevation (m)", "error (m)"):
        elev.add_column(name, justify="right")
    for row in data["floors"]:
        elev.add_row(
            str(row["id"]),
            _num(row["gt_elevation_m"]),
            str(row.get("est_id", "-")),
            _num(row.get("est_elevation_m")),
            _num(row.get("error_m")),
        )
    t1 = Table(title="X-axis, y-axis and yaw error between floors (multi-floor precision mapping paper, Table 1)")
    t2 = Table(title="Z-axis error between floors (multi-floor precision mapping paper, Table 2)")
    for name in ("floors", "rides", "X error (m)", "Y error (m)", "Yaw error (°)"):
        t1.add_column(name, justify="right")
    for name in ("floors", "Z error (m)", "Error rate (%)"):
        t2.add_column(name, justify="right")
    for pair in data["pairs"]:
        label = f"{pair['lower']} - {pair['upper']}"
        t1.add_row(label, str(pair["rides"]), _num(pair.get("dx_m")), _num(pair.get("dy_m")), _num(pair.get("dyaw_deg"), 2))
        t2.add_row(label, _num(pair.get("dz_m")), _num(pair.get("dz_pct"), 1))
    t1.add_row("Average", "", _num(m.get("floors.inter.dx_m")), _num(m.get("floors.inter.dy_m")), _num(m.get("floors.inter.dyaw_deg"), 2), style="bold")
    t2.add_row("Average", _num(m.get("floors.inter.dz_m")), _num(m.get("floors.inter.dz_pct"), 1), style="bold")
    return [head, elev, t1, t2]


def cloud_table(result: EvalResult) -> Table:
    m = result.metrics
    labels = sorted(
        {k.rsplit("_", 1)[1] for k in m if k.startswith("cloud.fscore_") and "miss" not in k},
        key=lambda s: float(s[:-2].replace("p", ".")),
    )
    table = Table(title="Cloud: map vs reference")
    table.add_column("part")
    for name in ("map pts", "ref pts", "accuracy (m)", "completeness (m)"):
        table.add_column(name, justify="right")
    for label in labels:
        table.add_column(f"F@{label.replace('p', '.')}", justify="right")
    prefixes = ["cloud", *sorted({k.rsplit(".", 1)[0] for k in m if k.startswith("cloud.floor")}, key=lambda p: int(p.split("floor")[1]))]
    for prefix in prefixes:
        name = "all" if prefix == "cloud" else prefix.split(".", 1)[1]
        table.add_row(
            name,
            f"{m.get(prefix + '.map_points', 0):.0f}",
            f"{m.get(prefix + '.ref_points', 0):.0f}",
            _num(m.get(prefix + ".accuracy_m"), 4),
            _num(m.get(prefix + ".completeness_m"), 4),
            *(_num(m.get(f"{prefix}.fscore_{label}")) for label in labels),
        )
    return table


def render_eval(result: EvalResult) -> RenderableType:
    """Every table this evaluation has, in the order points, trajectory, floors, cloud."""
    parts: list[RenderableType] = []
    if "points" in result.tables:
        parts.append(points_table(result))
    if "trajectory.ape_rmse_m" in result.metrics:
        parts.append(trajectory_table(result))
    if "floors" in result.tables:
        parts += floors_tables(result)
    if "cloud.map_points" in result.metrics:
        parts.append(cloud_table(result))
    for warning in result.warnings:
        parts.append(Text(f"warning: {warning}", style="yellow"))
    return Group(*parts)
