"""localize stage: a new log of a mapped building, placed in the map's frame (`mfmap localize`).

    from mfmap.localize import localize
    result = localize(Path("day2.mcap"), Path("maps/tower_a"), Path("loc/day2"), config)
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from mfmap.localize.run import Hint, LocalizeResult, localize, render_summary

__all__ = ["Hint", "LocalizeResult", "localize", "render_summary"]


def __getattr__(name: str) -> Any:
    # open3d and the readers load on first use, not on `import mfmap.localize` (the config does).
    if name in __all__:
        from mfmap.localize import run

        return getattr(run, name)
    raise AttributeError(name)
