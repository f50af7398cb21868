"""The simulator's own ground truth, perturbed by known amounts, scored as if it were a build."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from mfmap.eval import evaluate
from mfmap.eval.io import read_ply, write_ply

LIFT_M = 0.2


def test_sim_ground_truth_with_floor1_lifted(sim_run: Callable[..., Path], tmp_path: Path) -> None:
    sim = sim_run("tiny")
    gt_floors = json.loads((sim / "gt_floors.json").read_text())
    ride_end_s = gt_floors["transitions"][0]["t_end"]
    out = tmp_path / "build"
    out.mkdir()
    (out / "report.json").write_text("{}")
    # The "build": ground truth with everything after the elevator ride LIFT_M too high.
    rows = np.loadtxt(sim / "gt_trajectory.tum", dtype=np.float64)
    rows[rows[:, 0] > ride_end_s + 1e-6, 3] += LIFT_M
    np.savetxt(out / "trajectory.tum", rows, fmt="%.9f")
    est_floors = json.loads(json.dumps(gt_floors))
    est_floors["floors"][1]["elevation_m"] += LIFT_M
    (out / "floors.json").write_text(json.dumps(est_floors))
    # Map: every 20th reference point of floor 0 only; the reference: every 20th point of both.
    ply = read_ply(sim / "gt_cloud.ply")
    xyz = np.stack([ply["x"], ply["y"], ply["z"]], axis=1)[::20]
    floor = ply["floor"][::20]
    write_ply(out / "map.ply", xyz[floor == 0], floor[floor == 0])
    ref = tmp_path / "ref.ply"
    write_ply(ref, xyz, floor)
    shutil.copy(sim / "gt_points.csv", tmp_path / "points.csv")

    m = evaluate(
        out,
        points=tmp_path / "points.csv",
        trajectory=sim / "gt_trajectory.tum",
        floors=sim / "gt_floors.json",
        cloud=ref,
    ).metrics
    assert m["points.count"] == 3
    assert m["points.floor0.rmse_m"] == pytest.approx(0.0, abs=1e-6)
    assert m["points.floor1.rmse_m"] == pytest.approx(LIFT_M, abs=1e-6)
    assert m["points.floor1.z_rmse_m"] == pytest.approx(LIFT_M, abs=1e-6)
    assert m["points.hilti_points"] == 20 + 20 + 1
    assert m["trajectory.ape_max_m"] == pytest.approx(LIFT_M, abs=1e-6)
    assert m["trajectory.z_max_m"] == pytest.approx(LIFT_M, abs=1e-6)
    assert m["trajectory.xy_rmse_m"] == pytest.approx(0.0, abs=1e-9)
    assert m["trajectory.floor0.ape_rmse_m"] == pytest.approx(0.0, abs=1e-9)
    assert m["trajectory.floor1.ape_rmse_m"] == pytest.approx(LIFT_M, abs=1e-6)
    assert m["trajectory.floor1.z_rmse_m"] == pytest.approx(LIFT_M, abs=1e-6)
    assert m["trajectory.floor0.pairs"] + m["trajectory.floor1.pairs"] < m["trajectory.pairs"]  # rides
    assert m["trajectory.rot_max_deg"] == pytest.approx(0.0, abs=1e-5)
    assert m["floors.count_correct"] == 1
    assert m["floors.time_correct_share"] == 1.0
    assert m["floors.floor1.elevation_error_m"] == pytest.approx(LIFT_M, abs=1e-9)
    assert m["floors.inter0_1.dz_m"] == pytest.approx(LIFT_M, abs=1e-9)
    assert m["floors.inter0_1.dz_pct"] == pytest.approx(100 * LIFT_M / 3.5, abs=1e-6)
    assert m["floors.inter0_1.dx_m"] == 0.0 and m["floors.inter0_1.dyaw_deg"] == pytest.approx(0.0, abs=1e-6)
    # Floor 1 is missing from the map: its recall is 0, floor 0's is 1, overall their share.
    n0, n1 = int((floor == 0).sum()), int((floor == 1).sum())
    assert m["cloud.floor0.recall_5cm"] == 1.0
    # Only where the floors touch (shaft, stairwell) is floor 1 within 5 cm of floor 0's points.
    assert m["cloud.floor1.recall_5cm"] < 0.005
    assert m["cloud.precision_5cm"] == 1.0 and m["cloud.accuracy_m"] == 0.0
    for d in ("5cm", "20cm"):
        overall = (n0 * 1.0 + n1 * m[f"cloud.floor1.recall_{d}"]) / (n0 + n1)
        assert m[f"cloud.recall_{d}"] == pytest.approx(overall, abs=1e-12)
