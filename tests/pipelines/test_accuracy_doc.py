"""docs/accuracy.md's generator: its figures are the regression files' own numbers."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pipelines import accuracy_doc

BASELINE = accuracy_doc.ROOT / "pipelines" / "baselines" / "sim_seeds.json"


def _row(text: str, scenario: str, seed: int, section: str) -> str:
    part = text.split(f"## {section}", 1)[1].split("\n## ", 1)[0]
    rows = [line for line in part.splitlines() if line.startswith(f"| {scenario} | {seed} |")]
    assert len(rows) == 1, rows
    return rows[0]


def test_checkpoints_and_bars_come_from_the_baseline(tmp_path: Path) -> None:
    out = tmp_path / "accuracy.md"
    assert accuracy_doc.main([str(BASELINE), "-o", str(out)]) == 0
    text = out.read_text()
    metrics = json.loads(BASELINE.read_text())["logs"]["stairs-s1"]["metrics"]
    row = _row(text, "stairs", 1, "Checkpoints")
    floors = row.split(" | ")[2].split(" / ")
    # Floor 0 is where stairs starts: bold, and the three floors in order, in mm.
    assert floors[0] == f"**{metrics['points.floor0.rmse_m'] * 1000:.1f}**"
    assert floors[1] == f"{metrics['points.floor1.rmse_m'] * 1000:.1f}"
    assert floors[2] == f"{metrics['points.floor2.rmse_m'] * 1000:.1f}"
    dz = _row(text, "stairs", 1, "Floors").split(" | ")[5].split(" / ")[1]
    assert dz == f"{metrics['floors.floor1.elevation_error_m'] * 100:.1f}"
    assert "python -m pipelines.accuracy_doc" in text


def test_a_floor_past_its_bar_is_named(tmp_path: Path) -> None:
    data = json.loads(BASELINE.read_text())
    # As a run's results.json lists them; the second floor 1 mm past the 25 mm bar.
    logs = [{"name": name, **entry} for name, entry in data["logs"].items()]
    for log in logs:
        if log["name"] == "two-floor-s1":
            log["metrics"]["points.floor1.rmse_m"] = 0.026
        if log["name"] == "two-floor-s2":
            log["metrics"]["points.floor0.rmse_m"] = 0.017  # start floor: 16 mm bar
    results = tmp_path / "results.json"
    results.write_text(json.dumps({"manifest": "sim_seeds", "logs": logs}))
    out = tmp_path / "accuracy.md"
    assert accuracy_doc.main([str(results), "-o", str(out)]) == 0
    text = out.read_text()
    assert "| no: floor 1 |" in _row(text, "two-floor", 1, "Checkpoints")
    assert "| no: floor 0 |" in _row(text, "two-floor", 2, "Checkpoints")
    assert "| yes |" in _row(text, "three-floor-revisit", 1, "Checkpoints")


def test_not_a_regression_file_is_an_error(tmp_path: Path) -> None:
    bad = tmp_path / "x.json"
    bad.write_text("[1, 2]")
    assert accuracy_doc.main([str(bad), "-o", str(tmp_path / "a.md")]) == 2


def test_headline_has_a_column_per_seed(capsys: pytest.CaptureFixture[str]) -> None:
    full = accuracy_doc.ROOT / "pipelines" / "baselines" / "sim_full.json"
    assert accuracy_doc.main([str(full), str(BASELINE), "--headline"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "| scenario | seed 0 | seed 1 | seed 2 |"
    m = json.loads(BASELINE.read_text())["logs"]["two-floor-s1"]["metrics"]
    row = next(line for line in lines if line.startswith("| two-floor |"))
    assert row.split(" | ")[2] == f"{m['points.floor0.rmse_m'] * 1000:.1f} / {m['points.floor1.rmse_m'] * 1000:.1f}"
