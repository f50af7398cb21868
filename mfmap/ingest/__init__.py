"""ingest stage: open a log (MCAP, ROS 1 bag, ROS 2 bag), assign topics to roles, decode.

    from mfmap.ingest import open_log, describe_log
    with open_log("run.mcap") as src:
        for cloud in src.clouds():
            ...
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from mfmap.ingest.source import LogSource, LogSummary, Record, describe_log, open_log

__all__ = ["LogSource", "LogSummary", "Record", "describe_log", "open_log"]


def __getattr__(name: str) -> Any:
    # The readers pull in mcap and rosbags; load them on first use, not on `import mfmap.ingest`.
    if name in __all__:
        from mfmap.ingest import source

        return getattr(source, name)
    raise AttributeError(name)
