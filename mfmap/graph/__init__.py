"""graph stage: one GTSAM factor graph for the whole building (mfmap.graph.optimize).

    from mfmap.graph import optimize_building
    result = optimize_building(keyframes, edges, segmentation, pressure, config.graph)

Imported lazily so `import mfmap.graph` does not pull in gtsam and open3d.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from mfmap.graph.optimize import FactorStats, GraphResult, optimize_building

__all__ = ["FactorStats", "GraphResult", "optimize_building"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from mfmap.graph import optimize

        return getattr(optimize, name)
    raise AttributeError(name)
