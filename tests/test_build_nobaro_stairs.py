"""A log without barometer in which the robot climbs stairs: floors from the lidar's climbs, and
a clear error where the climb ends on no floor."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest

from mfmap import pipeline
from mfmap.config import MfmapConfig
from mfmap.errors import MissingDataError
from tests.logcopy import copy_log


def _first_walk(stairs: Path) -> tuple[dict[str, float], float]:
    doc = json.loads((stairs / "gt_floors.json").read_text())
    first = doc["transitions"][0]
    assert first["kind"] == "stairs"
    return first, min(v[0] for f in doc["floors"] for v in f["visits"])


def test_stairs_without_barometer_make_floors_from_the_lidars_climb(
        sim_run: Callable[..., Path], tmp_path: Path) -> None:
    stairs = sim_run("stairs")
    first, t0_s = _first_walk(stairs)
    # The log up to seconds after the first walk: one climb of one floor's height.
    log = tmp_path / "nobaro.mcap"
    copy_log(stairs / "log.mcap", log, {"/baro/pressure"}, end_s=first["t_end"] - t0_s + 8.0)
    out = tmp_path / "out"
    pipeline.build(log, out, MfmapConfig())
    report = json.loads((out / "report.json").read_text())
    assert any("1 stair walk(s) from the lidar odometry's climbs" in w for w in report["warnings"])
    doc = json.loads((out / "floors.json").read_text())
    floors = {f["id"]: f for f in doc["floors"]}
    assert len(floors) == 2 and all(f["pressure_pa"] is None for f in floors.values())
    # The floor's height is the lidar's climb: within 5 cm of the truth's.
    assert floors[1]["elevation_m"] - floors[0]["elevation_m"] == pytest.approx(
        first["height_change_m"], abs=0.05)
    (walk,) = doc["transitions"]
    assert walk["kind"] == "stairs"
    # Timed by the IMU's flights, within 2 s of the truth's ends.
    assert walk["t_start"] == pytest.approx(first["t_start"], abs=2.0)
    assert walk["t_end"] == pytest.approx(first["t_end"], abs=2.0)


def test_stairs_without_barometer_ending_on_the_flight_fail_clearly(
        sim_run: Callable[..., Path], tmp_path: Path) -> None:
    stairs = sim_run("stairs")
    first, t0_s = _first_walk(stairs)
    # The log stops on the stairs, most of a floor up: no floor to end the climb on.
    log = tmp_path / "nobaro.mcap"
    stop_s = first["t_start"] + 0.9 * (first["t_end"] - first["t_start"]) - t0_s
    copy_log(stairs / "log.mcap", log, {"/baro/pressure"}, end_s=stop_s)
    out = tmp_path / "out"
    with pytest.raises(MissingDataError, match=r"no barometer .* lidar odometry climbs [2-3]\.[0-9] m") as err:
        pipeline.build(log, out, MfmapConfig())
    assert str(log) in str(err.value)
    assert not out.exists()
