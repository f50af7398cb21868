"""The build's output folder: checked before any work, written under a partial name beside it,
renamed into place when complete.

Every folder a build writes carries `MARKER`, so `--force` replaces only folders mfmap wrote,
and a `.partial-*` or `.old-*` folder left by a killed build is recognised as mfmap's own by the
next build, which removes it (or, for an `.old-*` folder whose replacement never arrived, puts it
back). A folder that is still being written also carries `OWNER` (the writing process), so a
build running beside it is never mistaken for a dead one.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import tempfile
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any

from mfmap.atomic import disk_error, is_disk_error
from mfmap.errors import OutputError

MARKER = ".mfmap-build"
MARKER_TEXT = "written by mfmap build; --force may replace this folder\n"
OWNER = ".mfmap-owner"

# What a build writes, for a folder written before builds carried the marker: --force replaces
# such a folder only when it holds nothing else.
_OUTPUT_FILES = frozenset({
    "map.ply", "trajectory.tum", "floors.json", "map.mcap", "building.yaml", "report.json",
    "report.html", "config.yaml", "eval.json", "foxglove_layout.json", MARKER,
})
_FLOOR_FILES = frozenset({"cloud.ply", "grid.pgm", "grid.yaml", "grid.png"})

# Free space a build needs beyond its outputs' share of the log (report, grids, config).
_MIN_FREE_BYTES = 64 * 1024 * 1024
# Outputs measured against their logs: 11 MB of tiny's 159 MB (7 %), 1.1 MB of tiny-2d's 9 MB
# (12 %); map.ply and the floors' clouds dominate. A quarter leaves room for denser clouds.
_OUTPUT_SHARE_OF_LOG = 0.25


def _resolved(path: Path) -> Path:
    return Path(os.path.realpath(path))


def _inside(path: Path, folder: Path) -> bool:
    """Is `path` (resolved) `folder` itself or somewhere below it?"""
    return path == folder or folder in path.parents


def check_output(out: Path, inputs: Iterable[Path], input_folders: Iterable[Path] = (),
                 force: bool = False) -> None:
    """Refuse, before any work, an output folder that a build must not write or replace.

    `inputs` are files and folders the build reads (the log, the config): OUT may not be one of
    them or hold one. `input_folders` are folders that are themselves inputs (a ROS 2 bag, a
    folder of .mcap files): OUT may not be inside one either. OUT may not be the working
    directory or one of its parents, and an existing OUT that is not empty is replaced only with
    `force` and only when mfmap wrote it.
    """
    target = _resolved(out)
    cwd = _resolved(Path.cwd())
    if _inside(cwd, target):
        what = "the working directory" if target == cwd else "a parent of the working directory"
        raise OutputError(f"is {what}: a build replaces its output folder, name a new one", out)
    for inp in inputs:
        real = _resolved(inp)
        if _inside(real, target):
            what = "is" if real == target else "holds"
            raise OutputError(f"{what} the input {inp}: name an output folder apart from the inputs",
                              out)
    for folder in input_folders:
        if _inside(target, _resolved(folder)):
            raise OutputError(f"is inside the input folder {folder}: name an output folder "
                              "apart from the inputs", out)
    if out.is_symlink() and not out.exists():
        raise OutputError("is a broken symbolic link", out)
    if out.exists() and not out.is_dir():
        raise OutputError("exists and is not a folder", out)
    if out.is_dir():
        if os.path.ismount(out):
            raise OutputError("is a mount point, which a build cannot replace: name a folder "
                              "inside it", out)
        try:
            entries = list(out.iterdir())
        except OSError as err:
            raise OutputError(f"cannot be read ({err.strerror})", out) from err
        if entries and not force:
            raise OutputError("exists and is not empty (use --force to replace it)", out)
        if entries and not is_build_folder(out):
            other = _foreign_entry(out)
            raise OutputError(f"holds {other}, which mfmap did not write: --force replaces only "
                              "a folder a build wrote; name a new folder", out)
        if not os.access(out, os.W_OK | os.X_OK):
            raise OutputError("exists and is not writable, so it cannot be replaced", out)
    parent = out.parent
    if not parent.exists():
        try:
            parent.mkdir(parents=True)
        except OSError as err:
            raise OutputError(f"cannot create the parent folder ({err.strerror})", parent) from err
    if not parent.is_dir():
        raise OutputError("is not a folder", parent)
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError("is not writable: a build writes beside its output folder first", parent)


def is_build_folder(folder: Path) -> bool:
    """Did mfmap write this folder (it carries the marker, or holds only a build's files)?"""
    return (folder / MARKER).is_file() or _foreign_entry(folder) is None


def _foreign_entry(folder: Path) -> str | None:
    """The first entry of `folder` that a build does not write, or None."""
    for entry in sorted(folder.iterdir()):
        if entry.name in _OUTPUT_FILES and entry.is_file() and not entry.is_symlink():
            continue
        if entry.name == "floors" and entry.is_dir() and not entry.is_symlink():
            for sub in sorted(entry.iterdir()):
                if sub.name == "index.yaml" and sub.is_file():
                    continue
                if not (sub.is_dir() and sub.name.isdigit()) or sub.is_symlink():
                    return f"floors/{sub.name}"
                for leaf in sorted(sub.iterdir()):
                    if leaf.name not in _FLOOR_FILES or not leaf.is_file() or leaf.is_symlink():
                        return f"floors/{sub.name}/{leaf.name}"
            continue
        return entry.name
    return None


def check_free_space(folder: Path, log_bytes: int) -> None:
    """Refuse to start a build that the disk under `folder` cannot hold."""
    need = _MIN_FREE_BYTES + int(_OUTPUT_SHARE_OF_LOG * log_bytes)
    try:
        free = shutil.disk_usage(folder).free
    except OSError as err:
        raise OutputError(f"cannot tell the free disk space ({err.strerror})", folder) from err
    if free < need:
        raise OutputError(f"only {free / 1e6:.0f} MB free on its disk, a build of this log needs "
                          f"about {need / 1e6:.0f} MB", folder)


def input_size(path: Path) -> int:
    """Bytes of a log file, or of the files in a log folder."""
    if path.is_dir():
        return sum(p.stat().st_size for p in path.iterdir() if p.is_file())
    return path.stat().st_size if path.exists() else 0


# ----- owners: which process writes a folder ---------------------------------------------------


def _boot_id() -> str:
    try:
        return Path("/proc/sys/kernel/random/boot_id").read_text().strip()
    except OSError:
        return "-"


def _start_time(pid: int) -> str:
    """The process's start time in clock ticks since boot (tells a reused pid apart)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return "-"
    return stat.rsplit(")", 1)[-1].split()[19]


def _owner_text() -> str:
    pid = os.getpid()
    return f"{pid} {_start_time(pid)} {_boot_id()} {socket.gethostname()}\n"


def _owner_alive(folder: Path) -> bool:
    """Is the process that wrote `folder`'s owner file still running (or can we not tell)?"""
    try:
        pid_s, start, boot, host = (folder / OWNER).read_text().split()
        pid = int(pid_s)
    except (OSError, ValueError):
        return False  # no owner (a build that finished or died while committing) or garbage
    if host != socket.gethostname():
        return True  # another machine's build on a shared disk: cannot tell, leave it
    if boot != _boot_id():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    return start == "-" or _start_time(pid) in (start, "-")


def clean_stale(parent: Path) -> list[str]:
    """Remove the `.partial-*` and `.old-*` folders that builds killed in `parent` left behind
    (only folders carrying the marker, whose process is gone); an `.old-*` folder whose build
    died before its new output arrived is moved back into place. Returns what was done."""
    done: list[str] = []
    try:
        entries = sorted(parent.iterdir())
    except OSError:
        return done
    for entry in entries:
        name, sep, _ = entry.name.rpartition(".partial-")
        kind = "partial"
        if not sep:
            name, sep, _ = entry.name.rpartition(".old-")
            kind = "old"
        if not sep or not name or entry.is_symlink() or not entry.is_dir():
            continue
        if not (entry / MARKER).is_file() or _owner_alive(entry):
            continue
        if kind == "old":
            kept = entry / name
            target = parent / name
            if kept.is_dir() and not target.exists():
                with contextlib.suppress(OSError):
                    os.replace(kept, target)
                    done.append(f"restored {target} from {entry.name}, left by a build that was killed")
        shutil.rmtree(entry, ignore_errors=True)
        if not entry.exists():
            done.append(f"removed {entry}, left by a build that was killed")
    return done


def _mark(folder: Path, owner: bool) -> None:
    # The owner before the marker: a partial folder with the marker and no owner is a killed
    # build's to every build starting beside it (`clean_stale`), which would remove this one.
    if owner:
        (folder / OWNER).write_text(_owner_text())
    (folder / MARKER).write_text(MARKER_TEXT)


# ----- the run folder ------------------------------------------------------------------------------


class RunFolder:
    """A build's output folder: `partial` is written, `commit()` renames it to `out`.

    Used as a context manager, the partial folder is removed when the block raises.
    """

    def __init__(self, out: Path, partial: Path) -> None:
        self.out = out
        self.partial = partial
        self.notes: list[str] = []

    @classmethod
    def create(cls, out: Path, inputs: Sequence[Path] = (), input_folders: Sequence[Path] = (),
               force: bool = False, log_bytes: int = 0) -> RunFolder:
        """Check `out` (see `check_output`), clean what killed builds left beside it, check the
        free space and make the partial folder."""
        out = Path(out)
        check_output(out, inputs, input_folders, force)
        notes = clean_stale(out.parent)
        check_free_space(out.parent, log_bytes)
        try:
            partial = Path(tempfile.mkdtemp(prefix=f"{out.name}.partial-", dir=out.parent))
            mask = os.umask(0)
            os.umask(mask)
            os.chmod(partial, 0o777 & ~mask)  # mkdtemp makes it private (0700)
            _mark(partial, owner=True)
        except OSError as err:
            raise OutputError(f"cannot write here ({err.strerror})", out.parent) from err
        folder = cls(out, partial)
        folder.notes = notes
        return folder

    def __enter__(self) -> RunFolder:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is not None:
            self.discard()

    def discard(self) -> None:
        shutil.rmtree(self.partial, ignore_errors=True)

    @contextlib.contextmanager
    def writing(self) -> Iterator[Path]:
        """The block that writes the partial folder: on any error the folder is removed, and an
        error about a file in it names the output folder the user knows."""
        partial = self.partial
        try:
            yield partial
        except OSError as err:
            self.discard()
            if is_disk_error(err):
                raise disk_error(err, self.out) from err
            raise
        except OutputError as err:
            self.discard()
            if err.path is not None and partial in err.path.parents:
                # The partial folder is gone: the user knows the output folder by its own name.
                name = err.path.relative_to(partial)
                raise OutputError(f"{err.message} (writing {name}; nothing was left behind)",
                                  self.out) from err
            raise
        except BaseException:
            self.discard()
            raise

    def commit(self, report: Mapping[str, Any] | None = None) -> list[str]:
        """Write `report` as report.json, the folder's last file, then rename the finished
        partial folder into place, replacing an old OUT only now. Returns the files written
        (paths relative to the folder, sorted)."""
        out, partial = self.out, self.partial
        if report is not None:
            from mfmap.export.files import write_json

            write_json(partial / "report.json", report)
        files = sorted(str(p.relative_to(partial)) for p in partial.rglob("*") if p.is_file())
        old: Path | None = None
        try:
            if out.exists():
                old = Path(tempfile.mkdtemp(prefix=f"{out.name}.old-", dir=out.parent))
                _mark(old, owner=True)
                os.replace(out, old / out.name)
            os.replace(partial, out)
            # Only now: a partial folder without its owner would look abandoned to a build
            # starting beside this one.
            (out / OWNER).unlink(missing_ok=True)
        except OSError as err:
            if old is not None and (old / out.name).exists() and not out.exists():
                with contextlib.suppress(OSError):
                    os.replace(old / out.name, out)
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)
            raise disk_error(err, out) from err
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        return files


def log_folders(log: Path) -> list[Path]:
    """The folders that are part of the log: a bag folder or a folder of .mcap files (also when
    the log is named by its metadata.yaml or one of its .db3 files)."""
    if log.is_dir():
        return [log]
    if log.suffix == ".db3" or log.name == "metadata.yaml":
        return [log.parent]
    return []


__all__ = ["MARKER", "RunFolder", "check_output", "clean_stale", "is_build_folder", "log_folders"]
