"""A warning made at any stage reaches the console, report.json and report.html.

The `tiny` log rewritten without per-point time, with its barometer in hPa and its temperature on
a topic of its own: the lidar's warning is made when the build opens the log, the barometer's
only when the floors stage reads it (after the old copy of the ingest warnings). Every warning
the log source makes during the build is recorded and must be in all three outputs.
"""

from __future__ import annotations

import html
import json
from collections.abc import Callable
from pathlib import Path

import pytest
from typer.testing import CliRunner

import mfmap.ingest.source as source
from mfmap.cli import app
from pipelines.relayout import Options, relayout


@pytest.mark.slow
def test_every_warning_reaches_console_json_and_html(
    sim_run: Callable[..., Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    log = relayout(sim_run("tiny") / "log.mcap", tmp_path / "log.mcap",
                   Options("notime", baro_unit="hPa", temperature_topic=True)).out
    made: list[str] = []
    real = source.LogSource._warn

    def recording(self: source.LogSource, text: str) -> None:
        made.append(text)
        real(self, text)

    monkeypatch.setattr(source.LogSource, "_warn", recording)
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["build", str(log), "-o", str(out)])
    assert result.exit_code == 0, result.output
    report = json.loads((out / "report.json").read_text())
    page = (out / "report.html").read_text()
    console = " ".join(result.stderr.split())  # rich wraps long lines
    assert any("no per-point time" in w and "azimuth" in w for w in made)
    assert any("published in hPa" in w for w in made)
    for text in dict.fromkeys(made):
        assert f"ingest: {text}" in report["warnings"]
    assert report["warnings"]
    for warning in report["warnings"]:
        assert html.escape(warning) in page
        assert " ".join(warning.split()) in console
    assert report["ingest"]["lidar"]["deskew"] == "azimuth"
    assert report["ingest"]["pressure_unit"] == "hPa"
