"""Helpers for the mapping tests: a FloorSegmentation from a simulation's gt_floors.json.

Using the true floors isolates the mapping stage from the floors stage's errors.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from mfmap.eval.odometry import read_tum
from mfmap.types import Floor, FloorSegmentation, Transition, TransitionKind


def gt_segmentation(folder: Path) -> FloorSegmentation:
    data = json.loads((folder / "gt_floors.json").read_text())

    def ns(t_s: float) -> int:
        return round(t_s * 1e9)

    floors = tuple(
        Floor(f["id"], f["elevation_m"], f["pressure_pa"],
              tuple((ns(a), ns(b)) for a, b in f["visits"]))
        for f in data["floors"]
    )
    transitions = tuple(
        Transition(TransitionKind(t["kind"]), t["from"], t["to"], ns(t["t_start"]), ns(t["t_end"]),
                   t["height_change_m"])
        for t in data["transitions"]
    )
    # The filtered height trace: the true base height at the trajectory's stamps.
    stamps, poses = read_tum(folder / "gt_trajectory.tum")
    height = poses[:, 2, 3].copy()
    floor_of = np.full(len(stamps), -1, dtype=np.int32)
    for f in floors:
        for a, b in f.visits:
            floor_of[(stamps >= a) & (stamps <= b)] = f.id
    return FloorSegmentation(floors, transitions, stamps, height, height, floor_of)


@pytest.fixture(scope="session")
def gt_floors() -> Callable[[Path], FloorSegmentation]:
    """gt_floors(folder) -> the simulation's true floor segmentation."""
    return gt_segmentation
