"""A log without barometer in which the robot rides an elevator: floors from the IMU's rides."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest

from mfmap import pipeline
from mfmap.config import MfmapConfig
from mfmap.eval.api import evaluate
from mfmap.graph.ride import find_rides
from mfmap.ingest import open_log
from tests.logcopy import copy_log


def test_elevator_ride_without_barometer_builds_floors_from_the_imu(
        sim_run: Callable[..., Path], tmp_path: Path) -> None:
    tiny = sim_run("tiny")
    log = tmp_path / "nobaro.mcap"
    copy_log(tiny / "log.mcap", log, {"/baro/pressure"})
    out = tmp_path / "out"
    pipeline.build(log, out, MfmapConfig())
    report = json.loads((out / "report.json").read_text())
    assert any("no barometer in the log: floors from the IMU's 1 elevator ride(s)" in w
               for w in report["warnings"])
    scores = evaluate(out, points=tiny / "gt_points.csv", floors=tiny / "gt_floors.json").metrics
    assert scores["floors.count_correct"] == 1.0
    assert scores["floors.time_correct_share"] > 0.99
    # The ride's height is the IMU's: within 2 cm of the truth's 3.5 m.
    assert scores["floors.floor1.elevation_error_m"] < 0.02
    assert scores["points.floor1.rmse_m"] < 0.05
    # No barometer measured the floors' pressures: null, not a pressure of 0 Pa.
    floors = json.loads((out / "floors.json").read_text())["floors"]
    assert len(floors) == 2 and all(f["pressure_pa"] is None for f in floors)


def test_find_rides_measures_each_ride(sim_run: Callable[..., Path]) -> None:
    run = sim_run("tiny")
    truth = json.loads((run / "gt_floors.json").read_text())["transitions"]
    with open_log(run / "log.mcap") as src:
        imu = src.imu()
    rides = find_rides(imu, 2.0)
    assert len(rides) == len(truth) == 1
    (ride,), (tr,) = rides, truth
    assert ride.height_change_m == pytest.approx(tr["height_change_m"], abs=0.02)
    # The detected window lies within the ride's stand-stills, around the true ride.
    assert tr["t_start"] - 3.0 < ride.start_ns / 1e9 < tr["t_end"]
    assert tr["t_start"] < ride.end_ns / 1e9 < tr["t_end"] + 3.0
    # Below the floor height nothing counts as a ride.
    assert find_rides(imu, 4.0) == []
