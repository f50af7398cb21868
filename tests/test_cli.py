from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from mfmap import __version__


def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "mfmap.cli", *args], capture_output=True, text=True, timeout=120
    )


def test_version() -> None:
    res = run("--version")
    assert res.returncode == 0
    assert res.stdout.strip() == f"mfmap {__version__}"


def test_help_does_not_import_heavy_libraries() -> None:
    code = (
        "import sys; from typer.testing import CliRunner; from mfmap.cli import app;"
        "r = CliRunner().invoke(app, ['--help']); assert r.exit_code == 0, r.output;"
        "heavy = [m for m in ('open3d', 'gtsam', 'cv2', 'matplotlib', 'scipy') if m in sys.modules];"
        "print(','.join(heavy))"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert res.stdout.strip() == ""


def test_bad_config_is_one_line_and_exit_1(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("graph:\n  nope: 1\n")
    res = run("config", "--config", str(path))
    assert res.returncode == 1
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1
    assert "unknown key 'graph.nope'" in lines[0] and str(path) in lines[0]
    assert "Traceback" not in res.stderr


def test_bad_topic_override() -> None:
    res = run("info", "whatever.mcap", "--topic", "lidr=/x")
    assert res.returncode == 1
    assert "unknown role 'lidr'" in res.stderr
