"""floors stage: barometer -> filtered height -> transitions -> floors (ids, elevations, visits).

`segment_pressure` is the pure core (used by `mfmap build`); `segment_path` reads a log or a
t,pressure CSV and runs it (used by `mfmap floors`). Submodules import scipy, so this package
imports them lazily.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from mfmap.floors.motion import MotionEvidence
    from mfmap.floors.pipeline import segment_path
    from mfmap.floors.segment import segment_pressure

__all__ = ["MotionEvidence", "segment_path", "segment_pressure"]

_HOME = {
    "MotionEvidence": "mfmap.floors.motion",
    "segment_path": "mfmap.floors.pipeline",
    "segment_pressure": "mfmap.floors.segment",
}


def __getattr__(name: str) -> Any:
    if name in _HOME:
        import importlib

        return getattr(importlib.import_module(_HOME[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
