"""Fixtures of the floors stage: the IPIN 2023 real traces, a config, a scoring helper."""

from __future__ import annotations

from pathlib import Path

import pytest

from mfmap.floors.config import FloorsConfig

DATA = Path(__file__).resolve().parent.parent / "data" / "ipin2023"
TRIAL51 = "IPIN2023_T3_TrainingTrial51_repetition02"
TRIAL04 = "IPIN2023_T3_TrainingTrial04_repetition03"


@pytest.fixture
def cfg() -> FloorsConfig:
    return FloorsConfig()


@pytest.fixture(scope="session")
def ipin_dir() -> Path:
    return DATA
