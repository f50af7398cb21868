"""A log without barometer in which the robot climbs stairs must not become a one-floor map."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest

from mfmap import pipeline
from mfmap.config import MfmapConfig
from mfmap.errors import MissingDataError
from tests.logcopy import copy_log


def test_stairs_without_barometer_fail_clearly(sim_run: Callable[..., Path], tmp_path: Path) -> None:
    stairs = sim_run("stairs")
    doc = json.loads((stairs / "gt_floors.json").read_text())
    first = doc["transitions"][0]
    assert first["kind"] == "stairs"
    t0_s = min(v[0] for f in doc["floors"] for v in f["visits"])
    # The log up to a few seconds after the first flight: one climb of one floor height.
    log = tmp_path / "nobaro.mcap"
    copy_log(stairs / "log.mcap", log, {"/baro/pressure"}, end_s=first["t_end"] - t0_s + 5.0)
    out = tmp_path / "out"
    with pytest.raises(MissingDataError, match=r"no barometer .* lidar odometry climbs 3\.[0-7] m") as err:
        pipeline.build(log, out, MfmapConfig())
    assert str(log) in str(err.value)
    assert not out.exists()
