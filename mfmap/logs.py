"""Warnings through `logging`: a handler that collects the "mfmap" logger tree's warnings.

Each module logs its warnings on its own `logger = logging.getLogger(__name__)`; a build or a
localisation collects them with `collect_warnings()` and puts them in its report, each as
"<stage>: <message>", the stage being the package after "mfmap." (mfmap.graph.optimize:
"graph"; mfmap.pipeline and mfmap.runfolder: "build"). A record's `stage` (passed as
`extra={"stage": ...}`) names another; an empty one leaves the message bare.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator, Sequence
from contextlib import contextmanager

ROOT = "mfmap"
_BUILD_MODULES = ("pipeline", "runfolder")


def stage_of(record: logging.LogRecord) -> str:
    """The stage a record's line is prefixed with ("" for none)."""
    stage = getattr(record, "stage", None)
    if stage is not None:
        return str(stage)
    parts = record.name.split(".")
    if parts[0] != ROOT or len(parts) < 2 or parts[1] in _BUILD_MODULES:
        return "build"
    return parts[1]


class WarningCollector(logging.Handler):
    """The WARNING records of the "mfmap" logger tree, as report lines.

    The stages in `first` go ahead of the others, each group in the order its records came:
    a build's notes and the log's own warnings lead its report, though the log's are known
    only once every stage has read from it.
    """

    def __init__(self, first: Sequence[str] = ()) -> None:
        super().__init__(level=logging.WARNING)
        self.first = tuple(first)
        self._first: list[str] = []
        self._rest: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        stage = stage_of(record)
        message = record.getMessage()
        line = f"{stage}: {message}" if stage else message
        (self._first if stage in self.first else self._rest).append(line)

    def lines(self) -> list[str]:
        """The report's warnings so far."""
        return [*self._first, *self._rest]


@contextmanager
def collect_warnings(first: Sequence[str] = ()) -> Iterator[WarningCollector]:
    """Collect the "mfmap" loggers' warnings while the block runs.

    The records do not travel on to the root logger's handlers (nor to Python's last-resort
    one, which prints to stderr): the caller reports them, so none is printed twice. Nested
    collectors each receive every record.
    """
    root = logging.getLogger(ROOT)
    collector = WarningCollector(first)
    propagate, level = root.propagate, root.level
    root.addHandler(collector)
    root.propagate = False
    if root.getEffectiveLevel() > logging.WARNING:
        root.setLevel(logging.WARNING)
    try:
        yield collector
    finally:
        root.removeHandler(collector)
        root.propagate = propagate
        root.setLevel(level)
