"""mfmap: multi-floor building maps from robot logs."""

from __future__ import annotations

__version__ = "0.1.0"
