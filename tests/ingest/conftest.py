"""Fixtures for the ingest tests: the standard test log written once per format per session."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

import pytest

# The log writer is a plain module beside the tests (uniquely named: import-mode is importlib).
sys.path.insert(0, str(Path(__file__).parent))

import ingest_logwriter as lw


@pytest.fixture(scope="session")
def written_log(tmp_path_factory: pytest.TempPathFactory) -> Callable[[str], Path]:
    """written_log(fmt) -> path of the standard test log in that format (written once)."""
    cache: dict[str, Path] = {}

    def get(fmt: str) -> Path:
        if fmt not in cache:
            cache[fmt] = lw.write_log(tmp_path_factory.mktemp(fmt), fmt)
        return cache[fmt]

    return get
