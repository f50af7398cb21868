"""PNG of a floor segmentation: raw and filtered height, floor levels, transitions shaded."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mfmap.atomic import atomic_path
from mfmap.errors import OutputError
from mfmap.types import FloorSegmentation, TransitionKind

_KIND_COLOUR = {TransitionKind.ELEVATOR: "#9467bd", TransitionKind.STAIRS: "#2ca02c", TransitionKind.UNKNOWN: "#7f7f7f"}


def plot_segmentation(seg: FloorSegmentation, png_path: Path, title: str = "") -> Path:
    """Write the plot atomically and return its path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    start_ns = int(seg.stamp_ns[0])
    t_s = (seg.stamp_ns - start_ns) / 1e9
    # The raw trace is relative to the first second; shift it so the start floor is at 0 too.
    first = seg.floor_of_sample[0]
    on_start = seg.floor_of_sample == first
    offset = float(np.median(seg.height_raw_m[on_start] - seg.height_filtered_m[on_start])) if first >= 0 else 0.0
    fig, ax = plt.subplots(figsize=(12, 4.8))
    ax.plot(t_s, seg.height_raw_m - offset, color="#aec7e8", linewidth=0.5, label="raw (hypsometric)")
    ax.plot(t_s, seg.height_filtered_m - offset, color="#1f77b4", linewidth=1.3, label="filtered")
    _plot_floors(ax, seg, start_ns)
    _shade_transitions(ax, seg, start_ns)
    ax.set_xlabel("time since the first barometer sample (s)")
    ax.set_ylabel("height above the start floor (m)")
    ax.set_title(title or "barometer floors", fontsize=10)
    ax.grid(True, linewidth=0.3)
    ax.legend(loc="upper left", fontsize=8, ncol=4)
    fig.tight_layout()
    fig.subplots_adjust(right=0.86)
    try:
        with atomic_path(png_path) as tmp:
            fig.savefig(tmp, dpi=110)
    except OSError as err:
        raise OutputError(f"cannot write the plot ({err.strerror or err})", png_path) from err
    finally:
        plt.close(fig)
    return png_path


def _plot_floors(ax: Any, seg: FloorSegmentation, start_ns: int) -> None:
    """Each floor's level, thin, and its visits, thick, labelled at the right."""
    # Floor levels come from the change across each transition, not from the trace (which drifts
    # with the weather): thin lines for the levels, thick ones for each visit.
    first_visit = True
    for f in seg.floors:
        ax.axhline(f.elevation_m, color="#d62728", linewidth=0.6, linestyle="--", alpha=0.6)
        for a, b in f.visits:
            ax.hlines(
                f.elevation_m,
                (a - start_ns) / 1e9,
                (b - start_ns) / 1e9,
                color="#d62728",
                linewidth=2.5,
                label="floor visits (drift-free levels)" if first_visit else "_nolegend_",
            )
            first_visit = False
        ax.annotate(
            f"floor {f.id}  {f.elevation_m:+.2f} m",
            (1.0, f.elevation_m),
            xycoords=("axes fraction", "data"),
            xytext=(4, 0),
            textcoords="offset points",
            va="center",
            fontsize=8,
            color="#d62728",
        )


def _shade_transitions(ax: Any, seg: FloorSegmentation, start_ns: int) -> None:
    """Each transition shaded in its kind's colour."""
    seen: set[TransitionKind] = set()
    for tr in seg.transitions:
        colour = _KIND_COLOUR[tr.kind]
        ax.axvspan(
            (tr.start_ns - start_ns) / 1e9,
            (tr.end_ns - start_ns) / 1e9,
            color=colour,
            alpha=0.25,
            label=tr.kind.value if tr.kind not in seen else None,
        )
        seen.add(tr.kind)
