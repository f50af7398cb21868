"""Same log and config, same output: two builds of one log are byte-identical."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

FILES = ["trajectory.tum", "map.ply", "floors.json", "floors/0/grid.pgm", "floors/1/grid.pgm", "map.mcap",
         "building.yaml", "floors/index.yaml"]


def _digest(folder: Path) -> dict[str, str]:
    return {name: hashlib.sha256((folder / name).read_bytes()).hexdigest() for name in FILES}


def test_two_builds_are_byte_identical(sim_run: Callable[..., Path], tmp_path: Path) -> None:
    log = sim_run("tiny") / "log.mcap"
    digests = []
    for run in ("a", "b"):
        out = tmp_path / run
        res = subprocess.run(
            [sys.executable, "-m", "mfmap.cli", "build", str(log), "-o", str(out)],
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert res.returncode == 0, res.stderr
        digests.append(_digest(out))
    assert digests[0] == digests[1]
