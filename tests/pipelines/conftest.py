"""Fixtures for the regression pipeline: manifests written to tmp_path, metric dicts."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
# `pipelines` is a top-level package of the checkout, not installed; `python -m pytest` finds it
# through the working directory, a bare `pytest` (import-mode importlib) needs this.
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


@pytest.fixture
def write_manifest(tmp_path: Path) -> Callable[..., Path]:
    """write_manifest(data, name="m.yaml") -> path of a YAML manifest in tmp_path."""

    def write(data: dict[str, Any], name: str = "m.yaml") -> Path:
        path = tmp_path / name
        path.write_text(yaml.safe_dump(data, sort_keys=False))
        return path

    return write


@pytest.fixture
def eval_metrics() -> dict[str, float]:
    """Metrics under mfmap.eval's documented names, as a two-floor build scores them."""
    return {
        "points.count": 6.0,
        "points.rmse_m": 0.042,
        "points.z_rmse_m": 0.011,
        "points.hilti_score": 41.7,
        "points.hilti_miss": 58.3,
        "trajectory.pairs": 1200.0,
        "trajectory.ape_rmse_m": 0.085,
        "trajectory.rot_rmse_deg": 0.9,
        "cloud.fscore_10cm": 0.81,
        "cloud.fscore_miss_10cm": 0.19,
        "cloud.accuracy_m": 0.035,
        "floors.count_correct": 1.0,
        "floors.count_error": 0.0,
        "floors.elevation_error_max_m": 0.07,
        "floors.inter.dx_m": 0.05,
        "floors.inter.dz_m": 0.04,
    }
