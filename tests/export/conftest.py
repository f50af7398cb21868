"""Builds of the simulator's multi-floor logs, shared by the building-export tests."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from mfmap import pipeline
from mfmap.config import MfmapConfig


@pytest.fixture(scope="session")
def sim_build(sim_run: Callable[..., Path], tmp_path_factory: pytest.TempPathFactory) -> Callable[[str], tuple[Path, Path]]:
    """sim_build(scenario) -> (simulated folder, build folder), each scenario built once.

    These tests judge the files a build writes and where it puts the lift, not the default
    configuration's accuracy (the regression sets judge that): every sixth scan registered, a
    keyframe per 2 m and a scan in the clouds per 25 cm make the builds cheaper."""
    built: dict[str, tuple[Path, Path]] = {}
    config = MfmapConfig.model_validate({
        "mapping": {"scan_stride": 6, "keyframes": {"distance_m": 2.0}},
        "export": {"scan_min_motion_m": 0.25},
    })

    def get(scenario: str) -> tuple[Path, Path]:
        if scenario not in built:
            sim = sim_run(scenario)
            out = tmp_path_factory.mktemp(f"build-{scenario}") / "out"
            pipeline.build(sim / "log.mcap", out, config)
            built[scenario] = (sim, out)
        return built[scenario]

    return get
