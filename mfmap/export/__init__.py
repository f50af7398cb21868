"""export stage: the output folder (clouds, nav2 grids, trajectory, floors.json, reports).

    from mfmap.export import write_outputs

Imported lazily so `import mfmap.export` does not pull in cv2 and matplotlib.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from mfmap.export.write import (
        ExportSummary,
        FloorTrajectory,
        optimised_trajectory,
        write_outputs,
    )

__all__ = ["ExportSummary", "FloorTrajectory", "optimised_trajectory", "write_outputs"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from mfmap.export import write

        return getattr(write, name)
    raise AttributeError(name)
