"""Fixtures for the simulator tests; helpers live in simtest_helpers.py (importlib mode)."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))


@pytest.fixture(scope="session")
def tiny(sim_run: Callable[..., Path]) -> Path:
    return sim_run("tiny")
