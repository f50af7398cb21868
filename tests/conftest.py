"""Shared fixtures: simulated logs cached once per test session, the shared/ folder."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared"


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    if not (SHARED / "realdata").is_dir():
        pytest.skip(f"{SHARED} is absent: the real-data tests need ../shared beside the project")
    return SHARED


@pytest.fixture(scope="session")
def sim_run() -> Callable[..., Path]:
    """sim_run(scenario, fmt="mcap", seed=0, duration_scale=1.0) -> folder holding the log and
    its ground truth, cached across runs as the regression runner caches it (.cache/sim, or
    MFMAP_SIM_CACHE): the simulator is deterministic."""

    def run(scenario: str, fmt: str = "mcap", seed: int = 0, duration_scale: float = 1.0) -> Path:
        from pipelines.regress.manifest import DEFAULT_SIM_CACHE, Simulate
        from pipelines.regress.runner import ensure_simulated
        from tests.simlogs import cache_name, known

        spec = {"scenario": scenario, "fmt": fmt, "seed": seed, "duration_scale": duration_scale}
        if cache_name(spec) not in known():
            pytest.fail(f"add {spec} to SIM_LOGS in tests/simlogs.py: `make test` simulates those "
                        "logs before the tests start")
        # Locked: pytest-xdist's workers may ask for one log at once.
        return ensure_simulated(DEFAULT_SIM_CACHE, Simulate.model_validate(spec))

    return run
