"""Pressure CSVs in, floors.json out, and the `mfmap floors` command on them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from mfmap.cli import app
from mfmap.errors import LogError, MissingDataError
from mfmap.floors.config import FloorsConfig
from mfmap.floors.io import (
    read_floors_json,
    read_pressure_csv,
    segmentation_to_json,
    write_floors_json,
)
from mfmap.floors.segment import segment_pressure
from mfmap.sim.traces import building_walk, synthetic_trace


def _write(path: Path, lines: list[str]) -> Path:
    path.write_text("\n".join(lines) + "\n")
    return path


def test_ipin_csv_is_read_as_hpa_with_its_header(ipin_dir: Path) -> None:
    series, warnings = read_pressure_csv(ipin_dir / "IPIN2023_T3_TrainingTrial04_repetition03_pressure.csv")
    assert len(series) == 1682
    assert series.stamp_ns[0] == 45_100_000  # app_time_s 0.0451
    assert series.pressure_pa[0] == pytest.approx(97693.82)
    assert any("hPa" in w for w in warnings)


def test_headerless_pa_and_kpa_columns(tmp_path: Path) -> None:
    pa = _write(tmp_path / "pa.csv", [f"{i * 0.1:.1f},{101300.0 + i}" for i in range(20)])
    series, warnings = read_pressure_csv(pa)
    assert len(series) == 20 and series.pressure_pa[3] == 101303.0 and warnings == []
    assert series.stamp_ns[10] == 1_000_000_000
    kpa = _write(tmp_path / "kpa.csv", ["t,pressure"] + [f"{i},{101.3 + i * 0.001:.3f}" for i in range(20)])
    series, warnings = read_pressure_csv(kpa)
    assert series.pressure_pa[0] == pytest.approx(101300.0) and "kPa" in warnings[0]


def test_semicolon_and_tab_separated(tmp_path: Path) -> None:
    semi = _write(tmp_path / "semi.csv", ["# logger export", "t;p"] + [f"{i};{1013.0 + i * 0.01:.2f}" for i in range(20)])
    series, _ = read_pressure_csv(semi)
    assert len(series) == 20 and series.pressure_pa[1] == pytest.approx(101301.0)
    tab = _write(tmp_path / "tab.tsv", [f"{i}\t{101300 + i}" for i in range(20)])
    series, _ = read_pressure_csv(tab)
    assert len(series) == 20 and series.pressure_pa[19] == 101319.0


def test_bad_csvs_raise_typed_errors(tmp_path: Path) -> None:
    with pytest.raises(LogError, match="empty"):
        read_pressure_csv(_write(tmp_path / "empty.csv", [""]))
    with pytest.raises(LogError, match="two columns"):
        read_pressure_csv(_write(tmp_path / "one.csv", ["101300", "101301"]))
    with pytest.raises(LogError, match="not Pa, hPa or kPa"):
        read_pressure_csv(_write(tmp_path / "volts.csv", ["0,3.3", "1,3.3"]))
    with pytest.raises(LogError, match="no rows of numbers"):
        read_pressure_csv(_write(tmp_path / "words.csv", ["t,p", "a,b"]))
    short, _ = read_pressure_csv(_write(tmp_path / "short.csv", ["0,101300", "1,101300"]))
    with pytest.raises(MissingDataError):
        segment_pressure(short, None, FloorsConfig())


def test_floors_json_schema_and_atomic_write(tmp_path: Path) -> None:
    trace = synthetic_trace(building_walk(4.0, "elevator"), seed=0)
    seg = segment_pressure(trace.pressure, None, FloorsConfig())
    doc = segmentation_to_json(seg)
    assert [f["id"] for f in doc["floors"]] == [0, 1, 2, 3]
    assert [f["elevation_m"] for f in doc["floors"]] == sorted(f["elevation_m"] for f in doc["floors"])
    assert sum(len(f["visits"]) for f in doc["floors"]) == 7
    first = doc["transitions"][0]
    assert set(first) == {"kind", "from", "to", "t_start", "t_end", "height_change_m"}
    assert first["t_start"] == pytest.approx(1_700_000_040.0, abs=1.0)
    path = tmp_path / "floors.json"
    write_floors_json(seg, path)
    assert read_floors_json(path) == json.loads(json.dumps(doc))
    assert [p.name for p in tmp_path.iterdir()] == ["floors.json"]  # no temp file left behind


def test_cli_floors_on_a_csv(ipin_dir: Path, tmp_path: Path) -> None:
    runner = CliRunner()
    csv_path = ipin_dir / "IPIN2023_T3_TrainingTrial51_repetition02_pressure.csv"
    png = tmp_path / "t51.png"
    result = runner.invoke(app, ["floors", str(csv_path), "--json", "--plot", str(png)])
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    assert len(doc["floors"]) == 3 and len(doc["transitions"]) == 8
    assert png.stat().st_size > 20_000
    table = runner.invoke(app, ["floors", str(csv_path)])
    assert table.exit_code == 0 and "3 floors, 8 transitions" in table.stdout


def test_cli_floors_bad_input_is_one_line(tmp_path: Path) -> None:
    import subprocess
    import sys

    bad = _write(tmp_path / "volts.csv", ["0,3.3", "1,3.3"])
    cmd = [sys.executable, "-c", "from mfmap.cli import main; main()", "floors", str(bad)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert done.returncode == 1
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "not Pa, hPa or kPa" in lines[0] and "Traceback" not in done.stderr


def test_height_trace_is_returned_per_sample(ipin_dir: Path) -> None:
    series, _ = read_pressure_csv(ipin_dir / "IPIN2023_T3_TrainingTrial04_repetition03_pressure.csv")
    seg = segment_pressure(series, None, FloorsConfig())
    assert seg.height_raw_m.shape == seg.height_filtered_m.shape == seg.floor_of_sample.shape == (1682,)
    # The smoother removes most of the phone's jitter but follows the trace.
    assert float(np.std(np.diff(seg.height_filtered_m))) < 0.5 * float(np.std(np.diff(seg.height_raw_m)))
    assert float(np.max(np.abs(seg.height_filtered_m - seg.height_raw_m))) < 0.6
