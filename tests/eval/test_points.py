"""Checkpoints: the LeGO-LOAM elevator paper's Table I as a known-answer test, Hilti points, bad input."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from rich.console import Console

from mfmap.errors import GroundTruthError, OutputError
from mfmap.eval import evaluate
from mfmap.eval.points import hilti_points
from mfmap.eval.report import render_eval

# The LeGO-LOAM elevator paper, Table I: ground truth (x, y) with z 0 / 4.7, and the estimate on each floor.
TABLE_I = {
    "P1": ((0, 0), (0, 0, 0), (0.21, -0.19, 4.95)),
    "P2": ((6, -2), (6.07, -1.8, -0.05), (6.2, -1.98, 4.94)),
    "P3": ((6, -12), (6.05, -12, -0.1), (5.97, -12.02, 4.78)),
    "P4": ((0.7, -12), (0.8, -12.05, -0.01), (0.72, -11.98, 4.81)),
}
FLOOR_Z = (0.0, 4.7)


def _table_i_build(make_build: Callable[..., Path], h: SimpleNamespace, tmp_path: Path) -> tuple[Path, Path]:
    """A trajectory that stands 10 s on each of the eight points, with moves between them.

    Each stand has one wild pose (2 m off) that the median must ignore.
    """
    stamps: list[float] = []
    xyz: list[tuple[float, float, float]] = []
    rows = ["label,floor,x,y,z,t_start,t_end"]
    t = h.T0_S
    for floor in (0, 1):
        for label, (gt_xy, est0, est1) in TABLE_I.items():
            est = est0 if floor == 0 else est1
            start = t
            for k in range(11):  # 11 poses at 10 Hz over the 1 s stand
                stamps.append(start + 0.1 * k)
                wild = 2.0 if k == 3 else 0.0
                xyz.append((est[0] + wild, est[1], est[2]))
            rows.append(f"{label},{floor},{gt_xy[0]},{gt_xy[1]},{FLOOR_Z[floor]},{start - 0.01},{start + 1.01}")
            t = start + 5.0
            stamps.append(t - 2.0)  # a pose on the way to the next point, outside every window
            xyz.append((50.0, 50.0, 50.0))
    stamps_a = np.array(stamps)
    floors = h.floors_doc([0.0, 4.7], {0: [(h.T0_S, h.T0_S + 20)], 1: [(h.T0_S + 20, t)]}, [])
    out = make_build(trajectory=(stamps_a, np.array(xyz), h.yaw_quat(np.zeros(len(stamps_a)))), floors=floors)
    points = tmp_path / "points.csv"
    points.write_text("\n".join(rows) + "\n")
    return out, points


def _expected_rmse(floor: int) -> float:
    sq = []
    for gt_xy, est0, est1 in TABLE_I.values():
        est = est0 if floor == 0 else est1
        sq.append((est[0] - gt_xy[0]) ** 2 + (est[1] - gt_xy[1]) ** 2 + (est[2] - FLOOR_Z[floor]) ** 2)
    return math.sqrt(sum(sq) / len(sq))


def test_table_i_errors_rmse_and_table(make_build: Callable[..., Path], h: SimpleNamespace, tmp_path: Path) -> None:
    out, points = _table_i_build(make_build, h, tmp_path)
    result = evaluate(out, points=points)
    m = result.metrics
    assert m["points.count"] == 8
    assert m["points.floor0.count"] == 4 and m["points.floor1.count"] == 4
    # By hand from Table I: floor 0 sqrt((0 + 0.0474 + 0.0125 + 0.0126) / 4),
    # floor 1 sqrt((0.1427 + 0.098 + 0.0077 + 0.0129) / 4).
    assert m["points.floor0.rmse_m"] == pytest.approx(_expected_rmse(0), abs=1e-9)
    assert m["points.floor0.rmse_m"] == pytest.approx(math.sqrt(0.0725 / 4), abs=1e-9)
    assert m["points.floor1.rmse_m"] == pytest.approx(_expected_rmse(1), abs=1e-9)
    assert m["points.floor1.rmse_m"] == pytest.approx(math.sqrt(0.2613 / 4), abs=1e-9)
    overall = math.sqrt((_expected_rmse(0) ** 2 + _expected_rmse(1) ** 2) / 2)
    assert m["points.rmse_m"] == pytest.approx(overall, abs=1e-9)
    # P1 on floor 1: (0.21, -0.19, 0.25) -> 0.3777 m; the largest error of the table.
    assert m["points.max_m"] == pytest.approx(math.sqrt(0.21**2 + 0.19**2 + 0.25**2), abs=1e-9)
    dz = [0, -0.05, -0.1, -0.01, 0.25, 0.24, 0.08, 0.11]
    assert m["points.z_rmse_m"] == pytest.approx(math.sqrt(np.mean(np.square(dz))), abs=1e-9)
    # P1 floor 0 is exact (20 points); P3 floor 1 is 0.088 m (3 points); the other six are
    # between 10 and 40 cm (1 point each).
    assert m["points.hilti_points"] == 20 + 1 + 1 + 1 + 1 + 1 + 3 + 1
    assert m["points.hilti_score"] == pytest.approx(100 * 29 / 160)
    assert m["points.hilti_miss"] == pytest.approx(100 - 100 * 29 / 160)

    rows = result.tables["points"]["rows"]
    assert [r["label"] for r in rows] == ["P1", "P2", "P3", "P4"]
    assert rows[1]["floor1"]["est"] == pytest.approx([6.2, -1.98, 4.94])
    assert rows[1]["floor1"]["poses"] == 11
    assert rows[1]["floor1"]["spread_m"] == 0.0  # one wild pose of 11 is above the 90th percentile
    assert result.warnings == []
    console = Console(width=160, record=True)
    console.print(render_eval(result))
    text = console.export_text()
    assert "(0.00, 0.00, 0.00 / 4.70)" in text
    assert "(6.20, -1.98, 4.94)" in text
    assert "Hilti score 18.1/100" in text


def test_hilti_points_thresholds() -> None:
    errors = [0.0, 0.0049, 0.005, 0.0099, 0.02, 0.05, 0.09, 0.3, 0.4, 2.0]
    assert [hilti_points(e) for e in errors] == [20, 20, 10, 10, 6, 5, 3, 1, 0, 0]


def test_bad_points_files(make_build: Callable[..., Path], h: SimpleNamespace, tmp_path: Path) -> None:
    out, points = _table_i_build(make_build, h, tmp_path)
    lines = points.read_text().splitlines()
    bad = tmp_path / "bad.csv"

    bad.write_text("\n".join(["label,floor,x,y,height,t_start,t_end", *lines[1:]]))
    with pytest.raises(GroundTruthError, match=r"bad\.csv: missing column\(s\) z;"):
        evaluate(out, points=bad)

    t0 = h.T0_S
    bad.write_text(f"{lines[0]}\nP9,0,0,0,0,{t0 - 100},{t0 - 90}\n")
    with pytest.raises(GroundTruthError, match=r"bad\.csv: line 2 \(P9\): window .* is outside the log"):
        evaluate(out, points=bad)

    bad.write_text(f"{lines[0]}\nP9,0,0,0,0,{t0 + 2.0},{t0 + 2.5}\n")
    with pytest.raises(GroundTruthError, match=r"line 2 \(P9\): no trajectory pose in the window"):
        evaluate(out, points=bad)

    bad.write_text(f"{lines[0]}\nP9,2,0,0,0,{t0},{t0 + 1}\n")
    with pytest.raises(GroundTruthError, match=r"floor 2 is not in the build \(its floors: 0, 1\)"):
        evaluate(out, points=bad)

    # A window over the move between two points: scored, with a warning. Its 12 poses lie 0 m
    # (10), 2 m and 86.6 m from their median: 90th percentile 0.9 x 2 = 1.8 m.
    moving = tmp_path / "moving.csv"
    moving.write_text(f"{lines[0]}\nP9,0,0,0,0,{t0},{t0 + 4.5}\n")
    result = evaluate(out, points=moving)
    assert result.metrics["points.count"] == 1
    assert result.warnings == [
        "checkpoint P9 (floor 0): the build's poses in its window spread 1.80 m; did the robot stand still there?"
    ]

    bad.write_bytes(("\ufeff" + "\n".join(lines[:2]) + "\n").encode())  # a spreadsheet's BOM is fine
    assert evaluate(out, points=bad).metrics["points.count"] == 1

    bad.write_text(f"{lines[0]}\nP9,one,0,0,0,{t0},{t0 + 1}\n")
    with pytest.raises(GroundTruthError, match=r"bad\.csv: line 2: bad value"):
        evaluate(out, points=bad)


def test_interrupted_build(make_build: Callable[..., Path], h: SimpleNamespace, tmp_path: Path) -> None:
    out, points = _table_i_build(make_build, h, tmp_path)
    (out / ".incomplete").write_text("")
    with pytest.raises(OutputError, match=r"build: interrupted build \(\.incomplete marker present\)"):
        evaluate(out, points=points)
    (out / ".incomplete").unlink()
    (out / "report.json").unlink()
    with pytest.raises(OutputError, match=r"report\.json is missing"):
        evaluate(out, points=points)
    (out / "report.json").write_text("{}")
    (out / "trajectory.tum").unlink()
    with pytest.raises(OutputError, match=r"trajectory\.tum is missing"):
        evaluate(out, points=points)


def test_binary_ground_truth_files_are_one_error_naming_them(tmp_path: Path) -> None:
    """A points CSV or TUM file that is not text: once a UnicodeDecodeError traceback."""
    from mfmap.eval.io import read_points_csv, read_tum

    for name, reader in (("points.csv", read_points_csv), ("gt.tum", read_tum)):
        path = tmp_path / name
        path.write_bytes(b"label,floor\n" + bytes(range(128, 256)))
        with pytest.raises(GroundTruthError, match=r"not a text file \(byte 12 is not UTF-8\)") as err:
            reader(path)
        assert str(err.value).startswith(str(path))
