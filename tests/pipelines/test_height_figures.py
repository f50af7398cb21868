"""pipelines/height_figures.py over a tiny regression output written to tmp_path."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from pipelines.height_figures import elevation_bar_m, figures, main

T0 = 1_700_000_000.0


def _truth() -> dict[str, Any]:
    """Three floors (0, 4.0, 12.0 m), up by elevator to 2, down the stairs to 1, the elevator to 0."""
    return {
        "floors": [
            {"id": 0, "elevation_m": 0.0, "visits": [[T0, T0 + 100], [T0 + 400, T0 + 500]]},
            {"id": 1, "elevation_m": 4.0, "visits": [[T0 + 300, T0 + 380]]},
            {"id": 2, "elevation_m": 12.0, "visits": [[T0 + 120, T0 + 200]]},
        ],
        "transitions": [
            {"kind": "elevator", "from": 0, "to": 2, "t_start": T0 + 100, "t_end": T0 + 120, "height_change_m": 12.0},
            {"kind": "stairs", "from": 2, "to": 1, "t_start": T0 + 200, "t_end": T0 + 300, "height_change_m": -8.0},
            {"kind": "elevator", "from": 1, "to": 0, "t_start": T0 + 380, "t_end": T0 + 400, "height_change_m": -4.0},
        ],
    }


def _ride(kind: str, a: int, b: int, t: tuple[float, float], graph: float, own: float, baro: float,
          used: tuple[str, ...] = ("own", "barometer")) -> dict[str, Any]:
    sensor = "imu" if kind == "elevator" else "lidar"
    return {"kind": kind, "from_floor": a, "to_floor": b, "start_s": T0 + t[0], "end_s": T0 + t[1],
            "graph_height_change_m": graph, f"{sensor}_height_change_m": own, "baro_height_change_m": baro,
            "heights_used": [sensor if u == "own" else u for u in used]}


def _run(folder: Path, errors_m: tuple[float, float], rides: list[dict[str, Any]]) -> Path:
    """A regression output folder with one log, 'three', whose floors 1 and 2 are off by errors_m."""
    log = folder / "logs" / "three"
    (log / "build").mkdir(parents=True)
    gt = folder / "gt_floors.json"
    gt.write_text(json.dumps(_truth()))
    metrics = {"floors.count_correct": 1.0, "floors.count_est": 3.0, "floors.count_gt": 3.0,
               "floors.time_correct_share": 0.9951, "points.floor0.rmse_m": 0.0084,
               "points.floor1.rmse_m": 0.0147, "points.floor2.rmse_m": 0.0302}
    rows = [{"id": 0, "gt_elevation_m": 0.0, "error_m": 0.0},
            {"id": 1, "gt_elevation_m": 4.0, "error_m": errors_m[0]},
            {"id": 2, "gt_elevation_m": 12.0, "error_m": errors_m[1]}]
    (log / "eval.json").write_text(json.dumps({"inputs": {"floors": str(gt)}, "metrics": metrics,
                                               "tables": {"floors": {"floors": rows}}}))
    (log / "build" / "report.json").write_text(json.dumps({"graph": {"rides": rides}}))
    (folder / "results.json").write_text(json.dumps({"logs": [
        {"name": "three", "log": "three.mcap", "out_dir": str(log), "error": None},
        {"name": "broken", "log": "broken.mcap", "out_dir": str(folder / "logs" / "broken"), "error": "boom"},
    ]}))
    return folder


def test_bar_is_2cm_or_half_a_percent() -> None:
    assert elevation_bar_m(3.5) == pytest.approx(0.02)
    assert elevation_bar_m(-9.0) == pytest.approx(0.045)


def test_tables_over_a_tiny_run(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    fused = _run(tmp_path / "fused", (0.006, -0.021), [
        _ride("elevator", 0, 2, (101, 121), 11.979, 11.985, 11.70),
        # The walk's build floors are 2 -> 1; its times overlap the truth's stair walk only.
        _ride("stairs", 2, 1, (205, 298), -7.973, -7.95, -8.31, used=("barometer",)),
        _ride("elevator", 1, 0, (379, 399), -4.006, -4.004, -3.91),
    ])
    baro = _run(tmp_path / "baro", (-0.12, 0.30), [])
    text = figures([fused], [baro])
    # The broken log is left out; floor 2's 2.1 cm is within its 6 cm bar, checkpoints over
    # 25 mm on floor 2 fail the log.
    assert ("| three | 3/3 | 99.51 % | 1: 4.00 m, +0.6 cm (2.0); 2: 12.00 m, -2.1 cm (6.0) "
            "| 8.4 / 14.7, **30.2** | no |") in text
    assert "broken" not in text
    assert ("| three | elevator 0 -> 2 | +12.00 m | **+11.979 m, -2.10 cm** | +11.985 m, -1.50 cm "
            "| +11.700 m, -30.00 cm |") in text
    assert ("| three | stairs 2 -> 1 | -8.00 m | **-7.973 m, +2.70 cm** | -7.950 m, +5.00 cm (left out) "
            "| -8.310 m, -31.00 cm |") in text
    assert "| three | elevator 1 -> 0 | -4.00 m | -4.006 m, -0.60 cm | -4.004 m, -0.40 cm |" in text
    assert "Within 1 cm, rides: graph 1 of 2, IMU alone 1 of 2, barometer alone 0 of 2." in text
    assert "Within 1 cm, walks: graph 0 of 1, lidar alone 0 of 1, barometer alone 0 of 1." in text
    # RMS of (0.6, -2.1) cm is 1.5; of (-12, 30) cm, 22.8.
    assert "| three | 2 | 1.5 | 2.1 | 22.8 | 30.0 |" in text
    assert "| all | 2 | 1.5 | 2.1 | 22.8 | 30.0 |" in text

    assert main([str(fused)]) == 0
    out = capsys.readouterr().out
    assert "## Per log" in out and "Barometer-only" not in out
    with pytest.raises(SystemExit) as exc:
        main([str(tmp_path)])
    assert exc.value.code == 2
