"""eval stage: score a build folder against ground-truth points, cloud, trajectory and floors.

Only light modules are imported here; scipy and open3d load inside the functions that need them.
"""

from __future__ import annotations

from mfmap.eval.api import evaluate
from mfmap.eval.metrics import METRICS, EvalResult, parse_thresholds

__all__ = ["METRICS", "EvalResult", "evaluate", "parse_thresholds"]
