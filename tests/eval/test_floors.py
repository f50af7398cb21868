"""Floors against ground truth: counts, time on the right floor, elevations, the multi-floor precision mapping paper's tables."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from rich.console import Console

from mfmap.errors import GroundTruthError
from mfmap.eval import evaluate
from mfmap.eval.report import render_eval


def _ride(kind: str, a: int, b: int, t0: float, t1: float, xy0: tuple[float, float], xy1: tuple[float, float]) -> dict[str, Any]:
    return {"kind": kind, "from": a, "to": b, "t_start": t0, "t_end": t1, "height_change_m": 0.0,
            "x": xy0[0], "y": xy0[1], "x_end": xy1[0], "y_end": xy1[1]}  # fmt: skip


def _gt_and_est(h: SimpleNamespace) -> tuple[dict[str, Any], dict[str, Any]]:
    t = h.T0_S
    gt = h.floors_doc(
        [0.0, 4.7, 9.0],
        {0: [(t, t + 100)], 1: [(t + 120, t + 300), (t + 515, t + 600)], 2: [(t + 320, t + 500)]},
        [
            _ride("elevator", 0, 1, t + 100, t + 120, (1, 2), (1, 2)),
            _ride("elevator", 1, 2, t + 300, t + 320, (5, 5), (5, 5)),
            _ride("stairs", 2, 1, t + 500, t + 515, (5, 5), (5, 5)),
        ],
    )
    # The build: floor 2 0.5 m too high, every transition 2 s late, two rides misplaced in x/y.
    est = h.floors_doc(
        [0.0, 4.7, 9.5],
        {0: [(t, t + 102)], 1: [(t + 122, t + 302), (t + 517, t + 600)], 2: [(t + 322, t + 502)]},
        [
            _ride("elevator", 0, 1, t + 102, t + 122, (1, 2), (1.3, 1.8)),
            _ride("elevator", 1, 2, t + 302, t + 322, (5, 5), (5, 5)),
            _ride("stairs", 2, 1, t + 502, t + 517, (5, 5), (5.1, 5)),
        ],
    )
    return gt, est


def _trajectories(h: SimpleNamespace, tmp_path: Path) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], Path]:
    """Standing trajectories; during the first ride the build turns 3 degrees and slides
    (-0.4, 0.25) m, the truth does not move."""
    t = h.T0_S + np.arange(0, 600.0, 0.5)
    gt = h.write_tum(tmp_path / "gt.tum", t, np.zeros((len(t), 3)), h.yaw_quat(np.zeros(len(t))))
    after = t > h.T0_S + 110
    xyz = np.zeros((len(t), 3))
    xyz[after, :2] = (-0.4, 0.25)
    yaw = np.where(after, math.radians(3.0), 0.0)
    return (t, xyz, h.yaw_quat(yaw)), gt


def test_elevation_off_by_half_a_metre(make_build: Callable[..., Path], h: SimpleNamespace, tmp_path: Path) -> None:
    gt, est = _gt_and_est(h)
    out = make_build(floors=est)
    gt_path = tmp_path / "gt_floors.json"
    gt_path.write_text(json.dumps(gt))
    result = evaluate(out, floors=gt_path)
    m = result.metrics
    assert m["floors.count_correct"] == 1 and m["floors.count_error"] == 0
    assert m["floors.floor0.elevation_error_m"] == 0.0
    assert m["floors.floor1.elevation_error_m"] == 0.0
    assert m["floors.floor2.elevation_error_m"] == pytest.approx(0.5, abs=1e-12)
    assert m["floors.elevation_error_max_m"] == pytest.approx(0.5, abs=1e-12)
    assert m["floors.elevation_error_rmse_m"] == pytest.approx(math.sqrt(0.25 / 3), abs=1e-12)
    # 545 s of ground-truth visits; each 2 s lag costs 2 s at the three arrivals: 539 right.
    assert m["floors.time_correct_share"] == pytest.approx(539 / 545, abs=1e-12)
    assert m["floors.time_wrong_share"] == pytest.approx(6 / 545, abs=1e-12)
    assert m["floors.transitions_gt"] == 3
    assert m["floors.transitions_missed"] == 0 and m["floors.transitions_extra"] == 0
    assert m["floors.transition_time_error_max_s"] == pytest.approx(2.0, abs=1e-6)
    # Table 1 from the floors files: ride 0->1 ends 0.3 m off in x and 0.2 m in y; of the two
    # rides between 1 and 2 one is 0.1 m off in x. No yaw without trajectories.
    assert m["floors.inter0_1.dx_m"] == pytest.approx(0.3, abs=1e-9)
    assert m["floors.inter0_1.dy_m"] == pytest.approx(0.2, abs=1e-9)
    assert m["floors.inter1_2.dx_m"] == pytest.approx(0.05, abs=1e-9)
    assert m["floors.inter1_2.dy_m"] == pytest.approx(0.0, abs=1e-9)
    assert m["floors.inter.dx_m"] == pytest.approx(0.175, abs=1e-9)
    assert m["floors.inter.dy_m"] == pytest.approx(0.1, abs=1e-9)
    assert "floors.inter0_1.dyaw_deg" not in m
    # Table 2: floors 1-2 are 4.3 m apart in truth, 4.8 m in the build.
    assert m["floors.inter0_1.dz_m"] == pytest.approx(0.0, abs=1e-12)
    assert m["floors.inter1_2.dz_m"] == pytest.approx(0.5, abs=1e-12)
    assert m["floors.inter1_2.dz_pct"] == pytest.approx(100 * 0.5 / 4.3, abs=1e-9)
    assert m["floors.inter.dz_m"] == pytest.approx(0.25, abs=1e-12)

    console = Console(width=140, record=True)
    console.print(render_eval(result))
    text = console.export_text()
    assert "Z-axis error between floors" in text and "11.6" in text
    assert "X-axis, y-axis and yaw error between floors" in text and "0.175" in text

    # With trajectories, x, y and yaw come from both trajectories at the true ride times.
    est_traj, gt_traj = _trajectories(h, tmp_path)
    (out / "trajectory.tum").unlink(missing_ok=True)
    h.write_tum(out / "trajectory.tum", *est_traj)
    m = evaluate(out, floors=gt_path, trajectory=gt_traj).metrics
    assert m["floors.inter0_1.dx_m"] == pytest.approx(0.4, abs=1e-9)
    assert m["floors.inter0_1.dy_m"] == pytest.approx(0.25, abs=1e-9)
    assert m["floors.inter0_1.dyaw_deg"] == pytest.approx(3.0, abs=1e-6)  # 9-decimal quaternions
    assert m["floors.inter1_2.dx_m"] == pytest.approx(0.0, abs=1e-9)
    assert m["floors.inter1_2.dyaw_deg"] == pytest.approx(0.0, abs=1e-9)
    assert m["floors.inter.dyaw_deg"] == pytest.approx(1.5, abs=1e-6)
    assert m["floors.inter1_2.dz_m"] == pytest.approx(0.5, abs=1e-12)


def test_missing_floor_and_bad_file(make_build: Callable[..., Path], h: SimpleNamespace, tmp_path: Path) -> None:
    gt, est = _gt_and_est(h)
    est["floors"] = est["floors"][:2]
    est["transitions"] = est["transitions"][:1]
    out = make_build(floors=est)
    gt_path = tmp_path / "gt_floors.json"
    gt_path.write_text(json.dumps(gt))
    m = evaluate(out, floors=gt_path).metrics
    assert m["floors.count_gt"] == 3 and m["floors.count_est"] == 2
    assert m["floors.count_correct"] == 0 and m["floors.count_error"] == 1
    assert m["floors.unmatched_floors"] == 1
    assert "floors.floor2.elevation_error_m" not in m
    assert m["floors.transitions_missed"] == 2
    # Floor 2 is missing (180 s wrong) and both arrivals on floor 1 lag 2 s.
    assert m["floors.time_correct_share"] == pytest.approx((100 + 178 + 83) / 545, abs=1e-12)

    del gt["floors"][1]["elevation_m"]
    gt_path.write_text(json.dumps(gt))
    with pytest.raises(GroundTruthError, match=r"gt_floors\.json: floors\[1\] lacks 'elevation_m'"):
        evaluate(out, floors=gt_path)
    gt_path.write_text("{not json")
    with pytest.raises(GroundTruthError, match=r"gt_floors\.json: not valid JSON"):
        evaluate(out, floors=gt_path)
