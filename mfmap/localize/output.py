"""The localisation's output folder.

| file | content |
|---|---|
| `trajectory.tum` | base pose in the map's frame at every localised scan: `t x y z qx qy qz qw` |
| `floors.json` | the map's floors with this log's visits (localised time on each), its transitions |
| `scans.csv` | every scan: `t,status,floor,fitness,x,y,z,yaw_deg` (empty where not posed) |
| `floors/<id>/path.png` | the floor's grid with this log's path on it |
| `report.json` | fix, offset, floors, spans not localised (why, best fitness), searches, timings |
| `report.html` | the same for people, with the grids |
| `config.yaml` | the resolved configuration |

`mfmap eval OUT --trajectory GT.tum --floors GT.json` scores the folder like a build's.
"""

from __future__ import annotations

import base64
import html
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mfmap.config import MfmapConfig, dump_config
from mfmap.export.files import tum_text, write_bytes, write_json, write_text
from mfmap.localize.records import Status

if TYPE_CHECKING:
    from mfmap.localize.mapfolder import BuildingMap
    from mfmap.localize.run import _Localizer

OUTPUT_FILES = ("trajectory.tum", "floors.json", "scans.csv", "report.json", "report.html",
                "config.yaml")


def write_outputs(folder: Path, run: _Localizer, summary: dict[str, Any], cfg: MfmapConfig,
                  building: BuildingMap) -> list[str]:
    """Everything into `folder` (the partial folder); the names written."""
    stamps, poses, floor, status, fitness = run.arrays()
    posed = status <= int(Status.STAIRS)
    files: list[str] = []

    write_text(folder / "trajectory.tum", tum_text(stamps[posed], poses[posed]) if posed.any() else "")
    files.append("trajectory.tum")
    write_json(folder / "floors.json", floors_document(run, summary, building))
    files.append("floors.json")
    write_text(folder / "scans.csv", scans_csv(stamps, poses, floor, status, fitness))
    files.append("scans.csv")
    pngs: dict[int, bytes] = {}
    for fid, fm in sorted(building.floors.items()):
        if fm.grid is None:
            continue
        on_floor = posed & (floor == fid)
        png = path_png(fm.grid, poses[on_floor, :2, 3])
        pngs[fid] = png
        (folder / "floors" / str(fid)).mkdir(parents=True, exist_ok=True)
        write_bytes(folder / "floors" / str(fid) / "path.png", png)
        files.append(f"floors/{fid}/path.png")
    write_text(folder / "config.yaml", dump_config(cfg))
    files.append("config.yaml")
    report = {"summary": {k: summary[k] for k in _SUMMARY_KEYS}, **summary,
              "warnings": run.warnings}
    if cfg.localize.html_report:
        write_text(folder / "report.html", html_report(report, pngs, stamps, status, fitness))
        files.append("report.html")
    write_json(folder / "report.json", report)
    files.append("report.json")
    return files


_SUMMARY_KEYS = ("log_duration_s", "elapsed_s", "cpu_s", "realtime_factor", "cpu_realtime_factor", "scans",
                 "localised_share", "first_fix_s", "first_fix_floor", "offset_m",
                 "pressure_offset_pa", "searches", "peak_rss_mb")


def floors_document(run: _Localizer, summary: dict[str, Any], building: BuildingMap) -> dict[str, Any]:
    """floors.json: the map's floors and connectors, this log's visits and transitions."""
    hyp = run.chosen
    transitions = []
    for tr in run.segmentation.transitions:
        a = hyp.floor_of(tr.from_floor) if hyp is not None else None
        b = hyp.floor_of(tr.to_floor) if hyp is not None else None
        if a is None or b is None:
            continue  # an end on a floor the map lacks (or before any fix): not in the map's ids
        transitions.append({"kind": tr.kind.value, "from": a, "to": b, "t_start": tr.start_ns / 1e9,
                            "t_end": tr.end_ns / 1e9,
                            "height_change_m": round(building.floors[b].elevation_m
                                                     - building.floors[a].elevation_m, 4)})
    floors = []
    for item in summary["floors"]:
        connectors = [c.get("id") for c in building.connectors if item["id"] in c.get("floors", [])]
        floors.append({**item, "connectors": connectors})
    return {"floors": floors, "transitions": transitions, "connectors": building.connectors}


def scans_csv(stamps: np.ndarray, poses: np.ndarray, floor: np.ndarray, status: np.ndarray,
              fitness: np.ndarray) -> str:
    lines = ["t,status,floor,fitness,x,y,z,yaw_deg"]
    for k in range(len(stamps)):
        st = Status(int(status[k]))
        fit = "" if math.isnan(fitness[k]) else f"{fitness[k]:.4f}"
        stamp = int(stamps[k])
        t = f"{stamp // 1_000_000_000}.{stamp % 1_000_000_000:09d}"
        if st.localised:
            p = poses[k]
            yaw = math.degrees(math.atan2(p[1, 0], p[0, 0]))
            fl = str(int(floor[k])) if floor[k] >= 0 else ""
            lines.append(f"{t},{st.label},{fl},{fit},{p[0, 3]:.4f},{p[1, 3]:.4f},{p[2, 3]:.4f},{yaw:.3f}")
        else:
            lines.append(f"{t},{st.label},,{fit},,,,")
    return "\n".join(lines) + "\n"


def path_png(grid: Any, xy: np.ndarray) -> bytes:
    """The floor's grid with the path drawn on it (the build's drawing of its grids)."""
    from mfmap.export.grid import OccupancyGrid

    image = OccupancyGrid(grid.occupied, grid.free, grid.origin_xy, grid.resolution_m)
    return image.png_bytes(xy if len(xy) > 1 else None)


def _table(rows: list[list[Any]], header: list[str]) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(v))}</td>" for v in row) + "</tr>"
                   for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def fitness_svg(stamps: np.ndarray, status: np.ndarray, fitness: np.ndarray,
                width: int = 1000, height: int = 180) -> str:
    """Per-scan fitness over time, spans not localised shaded red (inline SVG, no libraries)."""
    if len(stamps) < 2:
        return ""
    t = (stamps - stamps[0]) / 1e9
    span = max(float(t[-1]), 1e-9)

    def x(v: float) -> float:
        return 40 + (width - 50) * v / span

    def y(v: float) -> float:
        return 10 + (height - 30) * (1.0 - v)

    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}">']
    bad = status > int(Status.STAIRS)
    k = 0
    while k < len(bad):
        if bad[k]:
            j = k
            while j + 1 < len(bad) and bad[j + 1]:
                j += 1
            parts.append(f'<rect x="{x(t[k]):.1f}" y="10" width="{max(x(t[j]) - x(t[k]), 1):.1f}" '
                         f'height="{height - 30}" fill="#f4c7c3"/>')
            k = j + 1
        else:
            k += 1
    ok = np.isfinite(fitness)
    points = " ".join(f"{x(a):.1f},{y(b):.1f}" for a, b in zip(t[ok], fitness[ok], strict=True))
    parts.append(f'<polyline fill="none" stroke="#1f77b4" stroke-width="1" points="{points}"/>')
    for v in (0.0, 0.5, 1.0):
        parts.append(f'<text x="2" y="{y(v) + 4:.1f}" font-size="11">{v:.1f}</text>')
    parts.append(f'<text x="{width / 2:.0f}" y="{height - 4}" font-size="11">time [s] '
                 f'(0 to {span:.0f}); fitness of each registered scan; red: not localised</text>')
    parts.append("</svg>")
    return "".join(parts)


def html_report(report: dict[str, Any], pngs: dict[int, bytes], stamps: np.ndarray,
                status: np.ndarray, fitness: np.ndarray) -> str:
    title = f"mfmap localize of {Path(report['log']).name} in {Path(report['map']).name}"
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        f"<title>{html.escape(title)}</title>",
        "<style>body{font-family:sans-serif;margin:2em;max-width:1100px}"
        "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:3px 8px;"
        "text-align:right}th{background:#eee}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
        _table([[k, v] for k, v in report["summary"].items()], ["", "value"]),
        "<h2>Floors</h2>",
        _table([[f["id"], f["elevation_m"], len(f["visits"]),
                 round(sum(b - a for a, b in f["visits"]), 1)] for f in report["floors"]],
               ["floor", "elevation [m]", "visits", "time [s]"]),
        "<h2>Not localised</h2>",
        _table([[s["from_s"], s["to_s"], s["scans"], s["reason"], s["best_fitness"]]
                for s in report["not_localised"]],
               ["from [s]", "to [s]", "scans", "why", "best fitness"])
        if report["not_localised"] else "<p>every scan localised</p>",
        "<h2>Fitness</h2>",
        fitness_svg(stamps, status, fitness),
        "<h2>Searches</h2>",
        _table([[round(s["t"] - report["search_log"][0]["t"], 1), s["floors"], s["fix"],
                 "; ".join(f"floor {b['floor']} ({b['x']}, {b['y']}, {b['yaw_deg']} deg) "
                           f"{b['fitness']}" for b in s["best"])] for s in report["search_log"]],
               ["t [s]", "floors", "fix", "best places"]) if report["search_log"] else "",
        "<h2>Timings</h2>",
        _table([[k, v] for k, v in report["timings_s"].items()], ["stage", "seconds"]),
    ]
    if report.get("warnings"):
        parts.append("<h2>Warnings</h2><ul>")
        parts += [f"<li>{html.escape(w)}</li>" for w in report["warnings"]]
        parts.append("</ul>")
    for fid, png in sorted(pngs.items()):
        data = base64.b64encode(png).decode()
        parts.append(f"<h2>Floor {fid}</h2><img alt='floor {fid} path' style='max-width:100%' "
                     f"src='data:image/png;base64,{data}'>")
    parts.append("</body></html>")
    return "\n".join(parts)


__all__ = ["OUTPUT_FILES", "write_outputs"]
