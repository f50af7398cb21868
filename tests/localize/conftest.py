"""Maps built from the simulator's session logs and other days' logs localised in them (each
built or localised once per test session)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from mfmap import pipeline
from mfmap.config import MfmapConfig


@pytest.fixture(scope="session")
def sim_map(sim_run: Callable[..., Path], tmp_path_factory: pytest.TempPathFactory
            ) -> Callable[[str], Path]:
    """sim_map(scenario) -> the build folder of that simulated log (built once)."""
    built: dict[str, Path] = {}

    def get(scenario: str) -> Path:
        if scenario not in built:
            out = tmp_path_factory.mktemp(f"map-{scenario}") / "map"
            pipeline.build(sim_run(scenario) / "log.mcap", out, MfmapConfig())
            built[scenario] = out
        return built[scenario]

    return get


@pytest.fixture(scope="session")
def localized(sim_run: Callable[..., Path], sim_map: Callable[[str], Path],
              tmp_path_factory: pytest.TempPathFactory) -> Callable[..., tuple[Path, Path, Any]]:
    """localized(map scenario, log scenario) -> (the log's sim folder, the output folder, the
    LocalizeResult), each pair localised once."""
    from mfmap.localize import localize

    done: dict[tuple[str, str], tuple[Path, Path, Any]] = {}

    def get(map_scenario: str, log_scenario: str) -> tuple[Path, Path, Any]:
        key = (map_scenario, log_scenario)
        if key not in done:
            sim = sim_run(log_scenario)
            out = tmp_path_factory.mktemp(f"loc-{log_scenario}-in-{map_scenario}") / "out"
            result = localize(sim / "log.mcap", sim_map(map_scenario), out, MfmapConfig())
            done[key] = (sim, out, result)
        return done[key]

    return get
