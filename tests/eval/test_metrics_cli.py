"""Metric names, thresholds, eval.json and the `mfmap eval` command end to end."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from mfmap.errors import MfmapError
from mfmap.eval import METRICS, EvalResult, evaluate, parse_thresholds
from mfmap.eval.io import write_ply
from mfmap.eval.metrics import is_metric_name


def test_parse_thresholds() -> None:
    items = ["points.rmse_m=0.03", "cloud.floor1.fscore_miss_5cm=0.2", "floors.inter0_1.dz_m=0.1",
             "trajectory.4dof.rot_max_deg=2", "cloud.recall_miss_2p5cm=0.5", "points.hilti_miss=40"]  # fmt: skip
    assert parse_thresholds(items) == {
        "points.rmse_m": 0.03,
        "cloud.floor1.fscore_miss_5cm": 0.2,
        "floors.inter0_1.dz_m": 0.1,
        "trajectory.4dof.rot_max_deg": 2.0,
        "cloud.recall_miss_2p5cm": 0.5,
        "points.hilti_miss": 40.0,
    }
    with pytest.raises(MfmapError, match=re.escape("expects METRIC=VALUE, got 'points.rmse_m'")):
        parse_thresholds(["points.rmse_m"])
    with pytest.raises(MfmapError, match="'abc' is not a number"):
        parse_thresholds(["points.rmse_m=abc"])
    with pytest.raises(MfmapError, match=re.escape("unknown metric 'points.rmse'")):
        parse_thresholds(["points.rmse=0.1"])
    with pytest.raises(MfmapError, match=re.escape("unknown metric 'trajectory.se3.pairs.x'")):
        parse_thresholds(["trajectory.se3.pairs.x=1"])


def test_nothing_to_evaluate_and_bad_alignment(full_case: dict[str, Path]) -> None:
    with pytest.raises(MfmapError, match="nothing to evaluate: give --points"):
        evaluate(full_case["out"])
    with pytest.raises(MfmapError, match="unknown alignment 'sim3'"):
        evaluate(full_case["out"], trajectory=full_case["trajectory"], align="sim3")


def test_check_thresholds() -> None:
    result = EvalResult(Path("out"), {}, {"points.rmse_m": 0.05, "points.z_rmse_m": 0.01})
    assert result.check_thresholds({"points.rmse_m": 0.03, "points.z_rmse_m": 0.02}) == [
        "points.rmse_m = 0.05 is above 0.03"
    ]
    assert result.check_thresholds({"points.rmse_m": 0.05}) == []
    with pytest.raises(MfmapError, match=re.escape("'cloud.accuracy_m' was not computed")):
        result.check_thresholds({"cloud.accuracy_m": 0.1})


@pytest.fixture
def full_case(make_build: Callable[..., Path], h: SimpleNamespace, tmp_path: Path) -> dict[str, Path]:
    """A two-floor build and ground truth of every kind, the build 2 cm off in x everywhere.

    The robot stands still for 0.5 s at the start and the end, where the two checkpoints are.
    """
    t = h.T0_S + np.arange(0, 60.0, 0.1)
    z = np.where(t < h.T0_S + 30, 0.0, 4.0)
    gt_xyz = np.stack([np.zeros_like(t), np.clip(np.linspace(-0.5, 5.5, len(t)), 0, 5), z], axis=1)
    q = h.yaw_quat(np.zeros(len(t)))
    floors = h.floors_doc(
        [0.0, 4.0],
        {0: [(h.T0_S, h.T0_S + 28)], 1: [(h.T0_S + 32, h.T0_S + 60)]},
        [{"kind": "elevator", "from": 0, "to": 1, "t_start": h.T0_S + 28, "t_end": h.T0_S + 32,
          "x": 0.0, "y": 2.5, "x_end": 0.0, "y_end": 2.5}],
    )  # fmt: skip
    g = np.arange(0, 3, 0.25)
    grid = np.stack(np.meshgrid(g, g, [0.0, 4.0], indexing="ij"), -1).reshape(-1, 3)
    out = make_build(
        trajectory=(t, gt_xyz + np.array([0.02, 0, 0]), q),
        floors=floors,
        cloud=(grid.astype(np.float32), (grid[:, 2] > 2).astype(np.int32)),
    )
    gt_tum = h.write_tum(tmp_path / "gt.tum", t, gt_xyz, q)
    gt_floors = tmp_path / "gt_floors.json"
    gt_floors.write_text(json.dumps(floors))
    ref = tmp_path / "ref.ply"
    write_ply(ref, grid.astype(np.float32))
    points = tmp_path / "points.csv"
    points.write_text(
        "label,floor,x,y,z,t_start,t_end\n"
        f"A,0,0,0,0,{h.T0_S},{h.T0_S + 0.5}\nA,1,0,5,4,{h.T0_S + 59},{h.T0_S + 60}\n"
    )
    return {"out": out, "points": points, "cloud": ref, "trajectory": gt_tum, "floors": gt_floors}


def test_every_reported_metric_is_documented(full_case: dict[str, Path]) -> None:
    case = dict(full_case)
    out = case.pop("out")
    names: set[str] = set()
    for align in ("se3", "4dof"):
        names |= set(evaluate(out, align=align, **case).metrics)
    undocumented = sorted(n for n in names if not is_metric_name(n))
    assert undocumented == []
    assert len(names) > 100
    assert all(isinstance(v, str) and v for v in METRICS.values())


def _mfmap(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "mfmap.cli", "eval", *args], capture_output=True, text=True)


def test_cli_exit_codes_and_eval_json(full_case: dict[str, Path], tmp_path: Path) -> None:
    c = full_case
    common = ["--points", str(c["points"]), "--trajectory", str(c["trajectory"]),
              "--floors", str(c["floors"]), "--cloud", str(c["cloud"])]  # fmt: skip
    ok = _mfmap(str(c["out"]), *common, "--fail-above", "points.rmse_m=0.03")
    assert ok.returncode == 0, ok.stderr
    assert "Table I layout" in ok.stdout and "Z-axis error between floors" in ok.stdout
    assert "tilt" in ok.stdout  # the trajectory table's roll and pitch column
    data = json.loads((c["out"] / "eval.json").read_text())
    assert data["metrics"]["points.rmse_m"] == pytest.approx(0.02, abs=1e-9)
    assert data["metrics"]["trajectory.ape_rmse_m"] == pytest.approx(0.02, abs=1e-9)
    assert data["metrics"]["cloud.fscore_5cm"] == 1.0
    assert data["tables"]["points"]["rows"][0]["label"] == "A"

    target = tmp_path / "e.json"
    bad = _mfmap(str(c["out"]), *common, "--json", str(target), "--fail-above", "points.rmse_m=0.01",
                 "--fail-above", "trajectory.xy_rmse_m=0.019")  # fmt: skip
    assert bad.returncode == 3
    assert "points.rmse_m = 0.02 is above 0.01" in bad.stderr
    assert "trajectory.xy_rmse_m = 0.02 is above 0.019" in bad.stderr
    assert target.is_file()

    unknown = _mfmap(str(c["out"]), "--points", str(c["points"]), "--fail-above", "points.rmse=1")
    assert unknown.returncode == 1
    assert unknown.stderr.strip().splitlines() == [
        "mfmap: error: --fail-above: unknown metric 'points.rmse' (see mfmap.eval.METRICS)"
    ]
    (c["out"] / ".incomplete").write_text("")
    broken = _mfmap(str(c["out"]), "--points", str(c["points"]))
    assert broken.returncode == 1
    assert broken.stderr.strip() == f"mfmap: error: {c['out']}: interrupted build (.incomplete marker present); rebuild it"
