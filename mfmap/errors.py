"""Typed errors. The CLI turns every MfmapError into one line and a non-zero exit."""

from __future__ import annotations

from pathlib import Path


class MfmapError(Exception):
    """Base of every error a user can cause (bad input, bad config); never a bug."""

    exit_code = 1

    def __init__(self, message: str, path: Path | str | None = None) -> None:
        self.path = Path(path) if path is not None else None
        self.message = message
        super().__init__(f"{path}: {message}" if path is not None else message)


class ConfigError(MfmapError):
    """Invalid configuration file or value."""


class LogError(MfmapError):
    """A log that cannot be opened or read."""


class DecodeError(LogError):
    """A message that cannot be decoded (bad layout, size mismatch)."""


class MissingDataError(MfmapError):
    """A log lacks what a stage needs (no lidar, no barometer)."""


class OutputError(MfmapError):
    """An output folder that cannot be written or read (exists, interrupted build)."""


class MapError(MfmapError):
    """A map folder that `localize` cannot use (not a finished build, files missing or bad)."""


class GroundTruthError(MfmapError):
    """A ground-truth file that is malformed or does not match the build."""


def read_text(path: Path, error: type[MfmapError], encoding: str = "utf-8-sig") -> str:
    """A text file's contents; a file that is not text (or cannot be read) raises `error`
    naming it, never UnicodeDecodeError."""
    try:
        data = path.read_bytes()
    except OSError as err:
        raise error(f"cannot be read ({err.strerror or err.__class__.__name__})", path) from err
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as err:
        raise error(f"not a text file (byte {err.start} is not UTF-8)", path) from err
