"""Several logs of one building, one map (`mfmap build A B ... -o OUT`, `--extend OUT`).

    from mfmap.multilog import build_logs
    result = build_logs([Path("day1.mcap"), Path("day2.mcap")], Path("maps/tower_a"), config)
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from mfmap.multilog.run import build_logs, logs_of_build

__all__ = ["build_logs", "logs_of_build"]


def __getattr__(name: str) -> Any:
    # open3d and GTSAM load on first use, not on `import mfmap.multilog`.
    if name in __all__:
        from mfmap.multilog import run

        return getattr(run, name)
    raise AttributeError(name)
