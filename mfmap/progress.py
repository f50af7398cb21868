"""Progress reporting that library code can call without printing.

Library functions take a `Progress` and call `progress.stage(name, total)`; the CLI passes one
backed by rich progress bars (quiet when stderr is not a terminal), tests pass nothing.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager
from typing import Protocol


class StageProgress(Protocol):
    def advance(self, n: float = 1) -> None: ...

    def set_total(self, total: float | None) -> None: ...


class Progress(Protocol):
    def stage(
        self, name: str, total: float | None = None
    ) -> AbstractContextManager[StageProgress]: ...


class _NullStage:
    def advance(self, n: float = 1) -> None:
        pass

    def set_total(self, total: float | None) -> None:
        pass


class NullProgress:
    """Does nothing; the default for library calls."""

    @contextmanager
    def stage(self, name: str, total: float | None = None) -> Iterator[StageProgress]:
        yield _NullStage()

