"""Builds of the simulator's multi-floor logs, shared by the building-export tests."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from mfmap import pipeline
from mfmap.config import MfmapConfig


@pytest.fixture(scope="session")
def sim_build(sim_run: Callable[..., Path], tmp_path_factory: pytest.TempPathFactory) -> Callable[[str], tuple[Path, Path]]:
    """sim_build(scenario) -> (simulated folder, build folder), each scenario built once."""
    built: dict[str, tuple[Path, Path]] = {}

    def get(scenario: str) -> tuple[Path, Path]:
        if scenario not in built:
            sim = sim_run(scenario)
            out = tmp_path_factory.mktemp(f"build-{scenario}") / "out"
            pipeline.build(sim / "log.mcap", out, MfmapConfig())
            built[scenario] = (sim, out)
        return built[scenario]

    return get
