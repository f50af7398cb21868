"""Rich tables for the stages' report modules (rendering only; the CLI prints them)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal

from rich.table import Table

Justify = Literal["left", "center", "right"]


def table(columns: Sequence[tuple[str, Justify]], **options: Any) -> Table:
    """A Table with the given (header, justify) columns; `options` go to rich's Table."""
    out = Table(**options)
    for header, justify in columns:
        out.add_column(header, justify=justify)
    return out
