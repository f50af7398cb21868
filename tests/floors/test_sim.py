"""Every `mfmap simulate` scenario: the simulator's own barometer (drift, door/HVAC steps, noise,
quantisation, 25 Hz) and motion, scored against its gt_floors.json."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from mfmap.floors.config import FloorsConfig
from mfmap.floors.motion import motion_from_odometry
from mfmap.floors.segment import segment_pressure
from mfmap.sim.traces import sim_barometer
from mfmap.types import FloorSegmentation

SCENARIOS = ["tiny", "two-floor", "three-floor-revisit", "three-floor-drift", "stairs", "single-floor", "long"]


def _score(seg: FloorSegmentation, gt: dict, timing_s: float = 1.0) -> None:
    floors = sorted(gt["floors"], key=lambda f: f["elevation_m"])
    assert len(seg.floors) == len(floors)
    assert len(seg.transitions) == len(gt["transitions"])
    start_s = gt["sim"]["start_ns"] / 1e9
    start_floor = next(f for f in gt["floors"] if any(abs(v[0] - start_s) < 1.0 for v in f["visits"]))
    rank = {f["id"]: i for i, f in enumerate(floors)}
    for floor, want in zip(seg.floors, floors, strict=True):
        assert abs(floor.elevation_m - (want["elevation_m"] - start_floor["elevation_m"])) < 0.3
    for tr, want in zip(seg.transitions, gt["transitions"], strict=True):
        assert abs(tr.start_ns / 1e9 - want["t_start"]) < timing_s
        assert abs(tr.end_ns / 1e9 - want["t_end"]) < timing_s
        assert tr.kind.value == want["kind"]
        assert (tr.from_floor, tr.to_floor) == (rank[want["from"]], rank[want["to"]])
    # Exact floor id for every sample outside the transitions (and their 1 s tolerance).
    t_s = seg.stamp_ns / 1e9
    truth = np.full(t_s.shape[0], -1)
    for f in gt["floors"]:
        for v0, v1 in f["visits"]:
            truth[(t_s >= v0 + timing_s) & (t_s <= v1 - timing_s)] = rank[f["id"]]
    for f in gt["floors"]:  # the trace's own ends are not near any transition
        for v0, v1 in f["visits"]:
            if abs(v0 - start_s) < 1.0:
                truth[(t_s >= v0) & (t_s <= v1 - timing_s)] = rank[f["id"]]
            if v1 >= t_s[-1] - 1.0:
                truth[(t_s >= v0 + timing_s)] = rank[f["id"]]
    away = truth >= 0
    assert np.count_nonzero(away) > 0.8 * t_s.shape[0]
    assert np.array_equal(seg.floor_of_sample[away], truth[away])


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("scenario", SCENARIOS)
def test_every_sim_scenario(scenario: str, seed: int, cfg: FloorsConfig) -> None:
    sim = sim_barometer(scenario, seed)
    seg = segment_pressure(sim.pressure, motion_from_odometry(sim.odometry, cfg), cfg)
    _score(seg, sim.gt_floors)


def test_sim_scenarios_from_the_barometer_alone(cfg: FloorsConfig) -> None:
    """Without motion the kinds are unknown, but floors, ids and elevations are the same."""
    sim = sim_barometer("three-floor-drift", 0)
    seg = segment_pressure(sim.pressure, None, cfg)
    assert [t.kind.value for t in seg.transitions] == ["unknown"] * 3
    assert len(seg.floors) == 3
    assert [v[0] for v in seg.visits()] == [0, 1, 2, 0]


def test_segment_path_on_the_simulated_tiny_log(sim_run: Callable[..., Path], cfg: FloorsConfig) -> None:
    """End to end through ingest: the real MCAP the simulator writes, its odometry for kinds."""
    from mfmap.config import MfmapConfig
    from mfmap.floors import segment_path
    from mfmap.floors.io import read_floors_json

    folder = sim_run("tiny")
    seg = segment_path(folder / "log.mcap", MfmapConfig())
    _score(seg, read_floors_json(folder / "gt_floors.json"))
