"""report.html: one self-contained page (inline PNGs) a person reads after a build."""

from __future__ import annotations

import base64
import html
import io
from typing import Any

import numpy as np

from mfmap.types import FloorSegmentation


def _png_tag(png: bytes, alt: str, width: str = "100%") -> str:
    data = base64.b64encode(png).decode()
    return f'<img alt="{html.escape(alt)}" style="max-width:{width}" src="data:image/png;base64,{data}">'


def _figure_png(fig: Any) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return buf.getvalue()


def pressure_plot_png(seg: FloorSegmentation) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 3.2))
    t_s = (seg.stamp_ns - seg.stamp_ns[0]) / 1e9 if len(seg.stamp_ns) else np.zeros(0)
    ax.plot(t_s, seg.height_raw_m, color="0.75", lw=0.6, label="raw")
    ax.plot(t_s, seg.height_filtered_m, color="k", lw=1.0, label="filtered")
    for floor in seg.floors:
        for s, e in floor.visits:
            x0 = (s - seg.stamp_ns[0]) / 1e9
            x1 = (e - seg.stamp_ns[0]) / 1e9
            ax.axvspan(x0, x1, color=f"C{floor.id % 10}", alpha=0.15)
            ax.text((x0 + x1) / 2, floor.elevation_m, f"F{floor.id}", ha="center", va="bottom")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("barometric height [m]")
    ax.legend(loc="upper right")
    return _figure_png(fig)


def side_view_sample(points: np.ndarray, floor: np.ndarray, max_points: int = 60_000) -> tuple[np.ndarray, np.ndarray]:
    """Every k-th point (and its floor) so that about `max_points` are drawn."""
    step = max(1, points.shape[0] // max_points)
    return points[::step], floor[::step]


def side_view_png(pts: np.ndarray, fl: np.ndarray) -> bytes:
    """x-z scatter of the points (`side_view_sample`), coloured by floor."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 4))
    if pts.shape[0]:
        for f in np.unique(fl):
            sel = fl == f
            ax.scatter(pts[sel, 0], pts[sel, 2], s=0.2, color=f"C{int(f) % 10}", label=f"floor {int(f)}")
        ax.legend(loc="upper right", markerscale=20)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("z [m]")
    ax.set_aspect("equal")
    ax.set_title("side view of the stacked floors")
    return _figure_png(fig)


def _table(rows: list[list[Any]], header: list[str]) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>" for row in rows
    )
    return f"<table><tr>{head}</tr>{body}</table>"


def _heights_section(graph: dict[str, Any]) -> list[str]:
    """Per ride and walk: each sensor's height change, which the graph used and why."""
    rides = [r for r in graph.get("rides", []) if "heights" in r]
    if not rides:
        return []

    def cm(r: dict[str, Any], key: str) -> str:
        return f"{r[key]:+.3f}" if key in r else "-"

    rows = []
    for r in rides:
        true_key = "imu_height_change_m" if r["kind"] == "elevator" else "lidar_height_change_m"
        rows.append([r["kind"], r["from_floor"], r["to_floor"], cm(r, true_key), cm(r, "baro_height_change_m"),
                     cm(r, "graph_height_change_m"), ", ".join(r.get("heights_used", [])) or "none",
                     r["heights"]])
    model = graph.get("heights", {})
    text = ""
    if model:
        scale = model.get("graph_scale", model.get("scale"))
        used = "used" if model.get("barometer_heights_used", True) else "not used (it disagrees with every scale-true height)"
        text = (f"<p>Barometer's height scale {scale} (prior {model.get('scale_prior')}; from {model.get('pairs', 0)} "
                f"transitions measured both ways), floors' pressure offsets spread {model.get('offset_sigma_m')} m; "
                f"its heights {html.escape(used)}.</p>")
    return [
        "<h2>Heights</h2>",
        "<p>Scale-true heights (an elevator ride's from the IMU, a stair walk's from the lidar) place "
        "the floors; the barometer's are scaled and weighed in.</p>",
        text,
        _table(rows, ["transition", "from", "to", "IMU / lidar [m]", "barometer [m]", "graph [m]", "used", "why"]),
    ]


def html_report(
    title: str,
    report: dict[str, Any],
    floors_doc: dict[str, Any],
    pressure_png: bytes | None,
    grid_pngs: dict[int, bytes],
    side_png: bytes,
    view: str | None = None,
) -> str:
    """The page: numbers, the 3D view (`viewer.view_html`), pressure trace, side view, grids."""
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        f"<title>{html.escape(title)}</title>",
        "<style>body{font-family:sans-serif;margin:2em;max-width:1100px}"
        "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:3px 8px;"
        "text-align:right}th{background:#eee}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
    ]
    summary = report.get("summary", {})
    parts.append(_table([[k, v] for k, v in summary.items()], ["", "value"]))
    if view is not None:
        parts.append(view)
    parts += _floors_section(floors_doc)
    parts += _graph_section(report.get("graph", {}))
    parts += _closing_sections(report, pressure_png, side_png, grid_pngs)
    parts.append("</body></html>")
    return "\n".join(parts)


def _floors_section(floors_doc: dict[str, Any]) -> list[str]:
    """The floors and the transitions between them."""
    parts = ["<h2>Floors</h2>"]
    parts.append(
        _table(
            [[f["id"], f["elevation_m"], "-" if f["pressure_pa"] is None else f["pressure_pa"],
              len(f["visits"]), f["connectors"]]
             for f in floors_doc["floors"]],
            ["floor", "elevation [m]", "pressure [Pa]", "visits", "connectors"],
        )
    )
    parts.append(
        _table(
            [[t["kind"], t["from"], t["to"], round(t["t_end"] - t["t_start"], 1), t["height_change_m"],
              t.get("x", ""), t.get("y", "")] for t in floors_doc["transitions"]],
            ["transition", "from", "to", "duration [s]", "height change [m]", "x", "y"],
        )
    )
    return parts


def _graph_section(graph: dict[str, Any]) -> list[str]:
    """The factor graph's factors, the heights and the inter-floor matches."""
    factors = graph.get("factors", {})
    parts = ["<h2>Factor graph</h2>"]
    parts.append(
        _table(
            [[k, v["count"], v["error_initial"], v["error_final"], v["outliers"], v["rejected"]]
             for k, v in factors.items()],
            ["factor", "count", "error before", "error after", "outliers", "rejected"],
        )
    )
    parts += _heights_section(graph)
    if graph.get("inter_floor"):
        parts.append(
            _table(
                [[m["lower"], m["upper"], m["accepted"], m["reason"], m["fitness"], m["dx_m"], m["dy_m"],
                  m["dyaw_deg"]] for m in graph["inter_floor"]],
                ["lower", "upper", "accepted", "reason", "fitness", "dx [m]", "dy [m]", "dyaw [deg]"],
            )
        )
    return parts


def _closing_sections(
    report: dict[str, Any], pressure_png: bytes | None, side_png: bytes, grid_pngs: dict[int, bytes]
) -> list[str]:
    """Timings, warnings and the images."""
    timings = report.get("timings_s", {})
    parts = ["<h2>Timings</h2>"]
    parts.append(_table([[k, v] for k, v in timings.items()], ["stage", "seconds"]))
    if report.get("warnings"):
        parts.append("<h2>Warnings</h2><ul>")
        parts += [f"<li>{html.escape(w)}</li>" for w in report["warnings"]]
        parts.append("</ul>")
    if pressure_png is not None:
        parts.append("<h2>Pressure trace and floors</h2>" + _png_tag(pressure_png, "pressure trace"))
    parts.append("<h2>Side view</h2>" + _png_tag(side_png, "side view"))
    for floor_id, png in sorted(grid_pngs.items()):
        parts.append(f"<h2>Floor {floor_id} grid</h2>" + _png_tag(png, f"floor {floor_id} grid"))
    return parts
