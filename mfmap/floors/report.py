"""Terminal rendering of `mfmap floors` (rich renderables; the CLI prints them)."""

from __future__ import annotations

import math

from rich.console import Group, RenderableType
from rich.text import Text

from mfmap.tables import table
from mfmap.types import FloorSegmentation

_PLAIN = dict(show_header=True, header_style="bold", box=None, pad_edge=False)


def _rel_s(stamp_ns: int, start_ns: int) -> str:
    return f"{(stamp_ns - start_ns) / 1e9:.1f}"


def render_floors(seg: FloorSegmentation) -> RenderableType:
    """A table of floors (elevation, pressure, visits) and one of transitions, times in seconds
    from the first barometer sample."""
    start_ns = int(seg.stamp_ns[0]) if len(seg.stamp_ns) else 0
    duration_s = (int(seg.stamp_ns[-1]) - start_ns) / 1e9 if len(seg.stamp_ns) else 0.0
    head = Text.assemble(
        (f"{len(seg.floors)} floors, {len(seg.transitions)} transitions", "bold"),
        f"  over {duration_s:.1f} s of barometer ({len(seg.stamp_ns)} samples); times in s from the first",
    )
    floors = table(
        [("floor", "right"), ("elevation m", "right"), ("pressure Pa", "right"), ("visits", "left")],
        **_PLAIN,
    )
    for f in sorted(seg.floors, key=lambda f: -f.elevation_m):
        visits = ", ".join(f"{_rel_s(a, start_ns)}-{_rel_s(b, start_ns)}" for a, b in f.visits)
        floors.add_row(str(f.id), f"{f.elevation_m:+.2f}", f"{f.pressure_pa:.1f}" if math.isfinite(f.pressure_pa) else "-", visits)
    trans = table(
        [
            ("kind", "left"),
            ("from", "right"),
            ("to", "right"),
            ("start s", "right"),
            ("end s", "right"),
            ("duration s", "right"),
            ("height m", "right"),
        ],
        **_PLAIN,
    )
    for t in seg.transitions:
        trans.add_row(
            t.kind.value,
            str(t.from_floor),
            str(t.to_floor),
            _rel_s(t.start_ns, start_ns),
            _rel_s(t.end_ns, start_ns),
            f"{(t.end_ns - t.start_ns) / 1e9:.1f}",
            f"{t.height_change_m:+.2f}",
        )
    parts: list[RenderableType] = [head, Text(""), floors]
    if seg.transitions:
        parts += [Text(""), trans]
    return Group(*parts)
