"""Terminal rendering of `mfmap info` (rich renderables; the CLI prints them)."""

from __future__ import annotations

from datetime import datetime, timezone

from rich.console import Group, RenderableType
from rich.text import Text

from mfmap.ingest.source import LogSummary
from mfmap.tables import table


def _clock(ns: int | None, date: bool = False) -> str:
    if ns is None:
        return "-"
    fmt = "%Y-%m-%d %H:%M:%S.%f" if date else "%H:%M:%S.%f"
    return datetime.fromtimestamp(ns / 1e9, tz=timezone.utc).strftime(fmt)[:-3]


def render_info(summary: LogSummary) -> RenderableType:
    """Table of topics (type, role, count, rate, first/last time) under a one-line header."""
    head = Text.assemble(
        (str(summary.path), "bold"),
        f"  format {summary.format}  duration {summary.duration_s:.3f} s  "
        f"{summary.message_count} messages  {_clock(summary.start_ns, True)} .. {_clock(summary.end_ns, True)} UTC",
    )
    topics = table(
        [
            ("topic", "left"),
            ("type", "left"),
            ("role", "left"),
            ("count", "right"),
            ("rate Hz", "right"),
            ("first (UTC)", "left"),
            ("last (UTC)", "left"),
        ],
        show_header=True,
        header_style="bold",
        box=None,
        pad_edge=False,
    )
    for t in summary.topics:
        if t.role is not None:
            role = Text(t.role.value, style="green")
        elif t.candidate_for is not None:
            role = Text(f"({t.candidate_for.value}: not chosen)", style="yellow")
        else:
            role = Text("-", style="dim")
        topics.add_row(
            t.name,
            t.msgtype or "?",
            role,
            str(t.count),
            f"{t.rate_hz:.2f}",
            _clock(t.first_ns),
            _clock(t.last_ns),
        )
    if not summary.sensors:
        return Group(head, topics)
    sensors = table(
        [("sensor", "left"), ("frame", "left"), ("transform", "left"), ("fields", "left"),
         ("time", "left"), ("deskew", "left")],
        show_header=True, header_style="bold", box=None, pad_edge=False,
        title="sensors", title_justify="left",
    )
    for row in summary.sensors:
        transform = str(row.get("transform", "-"))
        style = "red" if transform == "missing" else "yellow" if transform.startswith("identity") else ""
        mount = row.get("mount")
        sensors.add_row(
            f"{row['role']} {row['topic']}",
            row.get("frame") or "-",
            Text(transform + (f" ({mount})" if mount else ""), style=style),
            row.get("fields", "-"),
            row.get("time", "-"),
            row.get("deskew", "-"),
        )
    return Group(head, topics, Text(""), sensors)
