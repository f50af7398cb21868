"""Atomic file writing: write beside the target under a temporary name, then rename into place.

An interrupted run therefore never leaves a half-written file under the real name.
"""

from __future__ import annotations

import errno
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

from mfmap.errors import OutputError


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """Yield a temporary path beside `path` (same suffix, so writers that pick the format from
    the name still work); on success it is renamed to `path`, on failure removed."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=f".tmp{path.suffix}",
                                    dir=path.parent)
    except OSError as err:
        if is_disk_error(err):
            raise disk_error(err, path) from err
        raise
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        # mkstemp makes the file private (0600); outputs get the mode a plain open() would give.
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        if is_disk_error(err):
            raise disk_error(err, path) from err
        raise
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextmanager
def atomic_open(path: Path, mode: str = "w") -> Iterator[IO[Any]]:
    """open() for writing whose result appears under `path` only when the block succeeds."""
    with atomic_path(path) as tmp, open(tmp, mode) as fh:
        yield fh


def write_bytes_atomic(path: Path, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text_atomic(path: Path, text: str) -> None:
    write_bytes_atomic(path, text.encode())


_DISK_FULL = {errno.ENOSPC, errno.EDQUOT} if hasattr(errno, "EDQUOT") else {errno.ENOSPC}


def is_disk_error(err: BaseException) -> bool:
    """An OSError that only writing causes and a user fixes on the disk (full, read-only)."""
    return isinstance(err, OSError) and err.errno in (_DISK_FULL | {errno.EROFS, errno.EFBIG})


def disk_error(err: OSError, where: Path) -> OutputError:
    """One line for an OSError met while writing outputs (a full disk above all)."""
    if err.errno in _DISK_FULL:
        return OutputError("no space left on the device while writing; free some space and "
                           "run again", where)
    if err.errno == errno.EROFS:
        return OutputError("the file system is read-only", where)
    if err.errno == errno.EFBIG:
        return OutputError("file too large for the file system", where)
    return OutputError(f"cannot write ({err.strerror or err.__class__.__name__})", where)
