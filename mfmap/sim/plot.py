"""PNG pictures of a simulation: floor plans with the trajectory, the pressure trace."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from mfmap.atomic import atomic_path
from mfmap.sim.boxes import Kind
from mfmap.sim.building import Building
from mfmap.sim.sensors import Barometer
from mfmap.sim.spec import SLAB_M
from mfmap.sim.trajectory import RATE_HZ, Trajectory

_COLORS = {
    Kind.WALL: "#333333",
    Kind.PILLAR: "#7a3b00",
    Kind.FURNITURE: "#4f81bd",
    Kind.STAIRS: "#9b59b6",
}


def _save(fig: object, path: Path) -> Path:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)  # type: ignore[attr-defined]
    return path


def plot_floorplans(building: Building, traj: Trajectory, path: Path) -> Path:
    """One panel per floor: walls, pillars, furniture, stairs (boxes cut by the floor's plane),
    the robot's path on that floor and its checkpoints."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    n = building.n_floors
    cols = min(n, 3)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(7.5 * cols, 5.6 * rows), squeeze=False)
    floor_of = np.array([building.floor_of_height(z) for z in traj.xyz[::20, 2]])
    xy = traj.xyz[::20, :2]
    for k, floor in enumerate(building.floors):
        ax = axes[k // cols][k % cols]
        e = floor.elevation_m
        for box in floor.boxes:
            if box.kind == Kind.SLAB:
                continue
            # Walls cut at 1 m above the floor; furniture and steps drawn whatever their height.
            if box.kind in (Kind.WALL, Kind.PILLAR) and not (box.lo[2] <= e + 1.0 <= box.hi[2]):
                continue
            ax.add_patch(
                Rectangle(
                    (box.lo[0], box.lo[1]),
                    box.hi[0] - box.lo[0],
                    box.hi[1] - box.lo[1],
                    color=_COLORS.get(box.kind, "#999999"),
                    alpha=0.9 if box.kind in (Kind.WALL, Kind.PILLAR) else 0.45,
                    linewidth=0,
                )
            )
        for hole in [building.shaft_rect, building.stair_hole(k)]:
            if hole is not None and k > 0:
                ax.add_patch(Rectangle((hole[0], hole[2]), hole[1] - hole[0], hole[3] - hole[2], fill=False, hatch="//", color="#bbbbbb", linewidth=0.5))
        on = floor_of == k
        pts = np.where(on[:, None], xy, np.nan)
        ax.plot(pts[:, 0], pts[:, 1], color="#d62728", linewidth=1.2, label="trajectory")
        for c in traj.checkpoints:
            if c.floor == k:
                ax.plot(c.x, c.y, "o", color="#2ca02c", markersize=7)
                ax.annotate(c.label, (c.x, c.y), textcoords="offset points", xytext=(5, 5), fontsize=9)
        ax.set_title(f"floor {k}: elevation {e:+.2f} m, storey {building.storey_height(k):.2f} m (slab {SLAB_M} m)")
        ax.set_aspect("equal")
        fx0, fx1, fy0, fy1 = building.spec.footprint
        ax.set_xlim(fx0 - 1, fx1 + 1)
        ax.set_ylim(fy0 - 1, fy1 + 1)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.grid(alpha=0.2)
    for k in range(n, rows * cols):
        axes[k // cols][k % cols].axis("off")
    fig.tight_layout()
    out = _save(fig, path)
    plt.close(fig)
    return out


def plot_pressure(
    log_path: Path,
    traj: Trajectory,
    baro: Barometer,
    building: Building,
    start_ns: int,
    path: Path,
) -> Path:
    """The barometer trace as written (recomputed without noise is not what the log holds, so
    the samples are regenerated from the same seed) with the true floor of each moment."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # The written samples come from a generator already consumed; draw a fresh, identically
    # seeded barometer so the plot shows exactly the logged values.
    fresh = Barometer(baro.spec, traj, baro.p0_pa, _seed_of(baro), baro.world)
    step = RATE_HZ // baro.spec.rate_hz
    n = round(traj.duration_s) * baro.spec.rate_hz
    ticks = np.arange(n, dtype=np.int64) * step
    chunks = [fresh.samples(ticks[i : i + baro.spec.rate_hz]) for i in range(0, n, baro.spec.rate_hz)]
    p = np.concatenate(chunks) if chunks else np.zeros(0)
    t = ticks / RATE_HZ
    floor = np.array([building.floor_of_height(z) for z in traj.xyz[ticks, 2]])
    fig, ax = plt.subplots(figsize=(11, 4.5))
    ax.plot(t, p, color="#1f77b4", linewidth=0.6, label="barometer (logged)")
    ax.plot(t, fresh.clean(ticks), color="#ff7f0e", linewidth=1.0, label="noise-free")
    for t0, t1, _ in baro.transients:
        ax.axvspan(t0, t1, color="#ffbb78", alpha=0.4)
    ax.set_xlabel(f"time since start [s] (t0 = {start_ns / 1e9:.0f} epoch s)")
    ax.set_ylabel("pressure [Pa]")
    ax2 = ax.twinx()
    ax2.step(t, floor, where="post", color="#2ca02c", linewidth=1.2, label="true floor")
    ax2.set_ylabel("true floor id")
    ax2.set_yticks(range(building.n_floors))
    ax.set_title(f"pressure trace ({log_path.name}); shaded: door/HVAC transients")
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, loc="upper right", fontsize=8)
    fig.tight_layout()
    out = _save(fig, path)
    plt.close(fig)
    return out


def _seed_of(baro: Barometer) -> int:
    return baro.seed
