"""mapping stage: per-floor lidar odometry, keyframes, same-floor loop closure, cabin filtering.

`map_floors` is imported lazily so importing the package does not pull in open3d.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from mfmap.mapping.stage import map_floors

__all__ = ["map_floors"]


def __getattr__(name: str) -> Any:
    if name == "map_floors":
        from mfmap.mapping.stage import map_floors

        return map_floors
    raise AttributeError(name)
