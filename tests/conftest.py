"""Shared fixtures: simulated logs cached once per test session, the shared/ folder."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared"
# Simulated logs are deterministic, so they are cached across runs in .cache/sim (gitignored).
SIM_CACHE = Path(os.environ.get("MFMAP_SIM_CACHE", ROOT / ".cache" / "sim"))


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    if not (SHARED / "realdata").is_dir():
        pytest.skip(f"{SHARED} is absent: the real-data tests need ../shared beside the project")
    return SHARED


@pytest.fixture(scope="session")
def sim_run() -> Callable[..., Path]:
    """sim_run(scenario, fmt="mcap", seed=0) -> folder holding the log and its ground truth."""

    def run(scenario: str, fmt: str = "mcap", seed: int = 0, **kwargs: object) -> Path:
        from mfmap.sim import simulate, source_digest

        extra = "-".join(f"{k}={v}" for k, v in sorted(kwargs.items()))
        folder = SIM_CACHE / f"{scenario}-{fmt}-{seed}{('-' + extra) if extra else ''}"
        done = folder / ".complete"
        # The marker holds the simulator's source digest, so a changed simulator regenerates.
        digest = source_digest()
        if not done.exists() or done.read_text().strip() != digest:
            simulate(scenario, folder, fmt=fmt, seed=seed, **kwargs)  # type: ignore[arg-type]
            done.write_text(digest + "\n")
        return folder

    return run
