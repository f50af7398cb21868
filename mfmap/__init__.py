"""mfmap: multi-floor building maps from robot logs."""

from __future__ import annotations

__version__ = "0.3.0"

from mfmap.threads import limit_threads  # light: imports no numeric library

__all__ = ["__version__", "limit_threads"]
