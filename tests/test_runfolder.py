"""The output folder: never an input or a folder holding one, never the working directory,
replaced only when mfmap wrote it; what killed builds leave is cleaned; a full disk is one line."""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from mfmap import pipeline
from mfmap.config import MfmapConfig
from mfmap.errors import OutputError
from mfmap.progress import NullProgress
from mfmap.runfolder import MARKER, OWNER, RunFolder, check_output, clean_stale
from tests.ingest import ingest_logwriter as lw


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def run(tmp_path: Path) -> Path:
    """A robot's run folder: the log and the user's notes beside it."""
    folder = tmp_path / "run"
    lw.write_log(folder, "mcap-ros2")
    (folder / "notes.txt").write_text("calibration done at 09:14\n")
    return folder


def test_output_holding_the_log_is_refused_and_nothing_is_lost(run: Path) -> None:
    before = _tree(run)
    for out in (run, run.parent, run / "log.mcap"):
        with pytest.raises(OutputError, match="the input"):
            pipeline.build(run / "log.mcap", out, MfmapConfig(), force=True)
    assert _tree(run) == before
    assert sorted(p.name for p in run.parent.iterdir()) == ["run"]  # no partial folder either


def test_working_directory_and_its_parents_are_refused(run: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    before = _tree(run)
    deeper = run / "sub"
    deeper.mkdir()
    monkeypatch.chdir(deeper)
    for out, what in ((Path("."), "is the working directory"), (Path(".."), "a parent of the working"),
                      (Path("../.."), "a parent of the working")):
        with pytest.raises(OutputError, match=what):
            pipeline.build(run / "log.mcap", out, MfmapConfig(), force=True)
    assert _tree(run) == before


def test_output_inside_a_bag_folder_or_holding_the_config_is_refused(tmp_path: Path) -> None:
    bag = lw.write_log(tmp_path, "ros2-sqlite3")
    with pytest.raises(OutputError, match="inside the input folder"):
        pipeline.build(bag, bag / "map", MfmapConfig())
    db3 = next(bag.glob("*.db3"))
    with pytest.raises(OutputError, match="inside the input folder"):
        pipeline.build(db3, bag / "map", MfmapConfig())
    config = tmp_path / "maps" / "mine.yaml"
    config.parent.mkdir()
    config.write_text("mapping: {workers: 1}\n")
    with pytest.raises(OutputError, match="holds the input"):
        pipeline.build(bag, tmp_path / "maps", MfmapConfig(), force=True, inputs=[config])
    assert config.read_text() == "mapping: {workers: 1}\n"


def test_force_replaces_only_a_folder_mfmap_wrote(tmp_path: Path) -> None:
    log = lw.write_log(tmp_path / "logs", "mcap-ros2")
    out = tmp_path / "out"
    out.mkdir()
    (out / "map.ply").write_text("an old build")
    (out / "thesis.tex").write_text("three years of work")
    with pytest.raises(OutputError, match=r"holds thesis\.tex, which mfmap did not write"):
        check_output(out, [log], force=True)
    with pytest.raises(OutputError, match="use --force"):
        check_output(out, [log], force=False)
    # A user's file deep in floors/ counts too.
    (out / "thesis.tex").unlink()
    (out / "floors" / "0").mkdir(parents=True)
    (out / "floors" / "0" / "grid.pgm").write_text("grid")
    (out / "floors" / "0" / "survey.csv").write_text("mine")
    with pytest.raises(OutputError, match=r"holds floors/0/survey\.csv"):
        check_output(out, [log], force=True)
    # Only a build's files (a folder from before the marker): replaced with --force.
    (out / "floors" / "0" / "survey.csv").unlink()
    check_output(out, [log], force=True)
    # A folder with the marker is mfmap's whatever it holds (a newer version's extra files).
    (out / "extra.bin").write_text("x")
    with pytest.raises(OutputError, match=r"holds extra\.bin"):
        check_output(out, [log], force=True)
    (out / MARKER).write_text("")
    check_output(out, [log], force=True)


def test_commit_replaces_the_old_build_and_marks_the_new(tmp_path: Path) -> None:
    out = tmp_path / "out"
    first = RunFolder.create(out)
    (first.partial / "map.ply").write_text("first")
    assert (first.partial / OWNER).is_file()
    first.commit()
    assert (out / "map.ply").read_text() == "first"
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "map.ply"]  # no owner left in it
    second = RunFolder.create(out, force=True)
    (second.partial / "map.ply").write_text("second")
    second.commit()
    assert (out / "map.ply").read_text() == "second"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_stale_folders_of_dead_builds_are_cleaned_live_ones_kept(tmp_path: Path) -> None:
    # A partial folder of a build that is running (this process).
    live = RunFolder.create(tmp_path / "other")
    # A dead build's partial folder: marker, and an owner whose process has exited.
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    pid = int(dead.stdout)
    stale = tmp_path / "out.partial-abc123"
    stale.mkdir()
    (stale / MARKER).write_text("")
    boot = Path("/proc/sys/kernel/random/boot_id")
    boot_id = boot.read_text().strip() if boot.exists() else "-"
    import socket

    (stale / OWNER).write_text(f"{pid} 1 {boot_id} {socket.gethostname()}\n")
    # A folder that merely looks like one, without the marker: someone else's.
    lookalike = tmp_path / "data.partial-2024"
    lookalike.mkdir()
    (lookalike / "keep.txt").write_text("mine")
    # A build killed between moving the old output aside and moving the new one in.
    old = tmp_path / "prev.old-xyz"
    (old / "prev").mkdir(parents=True)
    (old / MARKER).write_text("")
    (old / "prev" / "map.ply").write_text("the previous build")
    notes = clean_stale(tmp_path)
    assert not stale.exists()
    assert live.partial.is_dir() and (lookalike / "keep.txt").read_text() == "mine"
    assert (tmp_path / "prev" / "map.ply").read_text() == "the previous build"
    assert not old.exists()
    assert len(notes) == 3, notes
    live.discard()


def _unprivileged() -> list[str]:
    """A command prefix that runs without the permission override root has (or skips)."""
    if os.geteuid() != 0:
        return []
    if shutil.which("setpriv") is None:
        pytest.skip("running as root without setpriv, which would drop root's override")
    return ["setpriv", "--bounding-set=-dac_override,-dac_read_search", "--"]


def test_an_existing_output_that_is_not_writable_is_refused_up_front(tmp_path: Path) -> None:
    """A build folder the user may not write (mode 555): refused before any work, where the
    build used to run to its end and then fail to move the old folder aside."""
    out = tmp_path / "out"
    out.mkdir()
    (out / MARKER).write_text("")
    out.chmod(0o555)
    code = ("import sys\nfrom pathlib import Path\nfrom mfmap.errors import OutputError\n"
            "from mfmap.runfolder import check_output\n"
            "try:\n"
            f"    check_output(Path({str(out)!r}), [], force=True)\n"
            "except OutputError as err:\n"
            "    sys.exit(str(err))\n")
    try:
        result = subprocess.run([*_unprivileged(), sys.executable, "-c", code],
                                capture_output=True, text=True)
    finally:
        out.chmod(0o755)
    assert result.stderr.strip() == f"{out}: exists and is not writable, so it cannot be replaced"


def _mount_tmpfs(where: Path, size: str) -> None:
    where.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")


@pytest.mark.skipif(os.geteuid() != 0 or shutil.which("mount") is None,
                    reason="mounts a small tmpfs, which needs root")
def test_a_disk_too_small_is_refused_before_the_build(tmp_path: Path) -> None:
    disk = tmp_path / "disk"
    _mount_tmpfs(disk, "2m")
    try:
        log = lw.write_log(tmp_path / "logs", "mcap-ros2")
        with pytest.raises(OutputError, match=r"only 2 MB free on its disk"):
            pipeline.build(log, disk / "out", MfmapConfig())
        assert list(disk.iterdir()) == []
    finally:
        subprocess.run(["umount", str(disk)], check=True)


class _FillDiskAtExport:
    """A progress that fills `disk` when the build starts writing its outputs."""

    def __init__(self, disk: Path) -> None:
        self.disk = disk

    @contextlib.contextmanager
    def stage(self, name: str, total: float | None = None) -> Iterator[Any]:
        if name == "export":
            # Unbuffered, so closing the file has nothing left to write.
            with (self.disk / "filler").open("wb", buffering=0) as f, contextlib.suppress(OSError):
                while True:
                    f.write(b"\0" * (1 << 20))
        with NullProgress().stage(name, total) as bar:
            yield bar


@pytest.mark.skipif(os.geteuid() != 0 or shutil.which("mount") is None,
                    reason="mounts a small tmpfs, which needs root")
def test_a_disk_that_fills_during_the_build_is_one_line(tmp_path: Path) -> None:
    """ENOSPC while the outputs are written: one OutputError naming the output folder, the
    partial folder removed, the user's files untouched."""
    disk = tmp_path / "disk"
    _mount_tmpfs(disk, "80m")
    try:
        log = lw.write_log(tmp_path / "logs", "mcap-ros2")
        (disk / "keep.txt").write_text("mine")
        cfg = MfmapConfig.model_validate({"mapping": {"min_points_per_scan": 0, "workers": 1},
                                          "export": {"workers": 1}})
        with pytest.raises(OutputError, match=r"out: no space left on the device while writing; "
                                              r"free some space and run again \(writing "):
            pipeline.build(log, disk / "out", cfg, progress=_FillDiskAtExport(disk))
        assert sorted(p.name for p in disk.iterdir()) == ["filler", "keep.txt"]
        assert (disk / "keep.txt").read_text() == "mine"
    finally:
        subprocess.run(["umount", str(disk)], check=True)


_CREATE_MANY = """
import sys
from pathlib import Path
from mfmap.runfolder import RunFolder
parent = Path(sys.argv[1])
for i in range(int(sys.argv[3])):
    RunFolder.create(parent / f"{sys.argv[2]}-{i}").discard()
"""


def test_builds_started_together_in_one_folder_leave_each_other_alone(tmp_path: Path) -> None:
    # Every build cleans the partial folders that killed builds left beside its output; one
    # that is being made must not look killed to a build starting next to it (a pipeline
    # starts its builds together in one folder).
    procs = [subprocess.Popen([sys.executable, "-c", _CREATE_MANY, str(tmp_path), f"b{k}", "40"],
                              stderr=subprocess.PIPE, text=True) for k in range(6)]
    errors = [p.communicate(timeout=120)[1] for p in procs]
    assert [p.returncode for p in procs] == [0] * len(procs), errors
    assert list(tmp_path.iterdir()) == []
