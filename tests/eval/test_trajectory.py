"""Trajectory APE: known answers, and the same RMSE as evo on the same files."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from mfmap.errors import GroundTruthError
from mfmap.eval import evaluate
from mfmap.eval.io import read_tum
from mfmap.eval.trajectory import associate, quat_to_matrix

FLOORS = {"floors": [{"id": 0, "elevation_m": 0.0, "visits": []}], "transitions": []}


def _gt(h: SimpleNamespace, n: int = 200) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A loop with changing heading and height, 10 Hz."""
    t = h.T0_S + 0.1 * np.arange(n)
    s = np.linspace(0, 2 * np.pi, n)
    xyz = np.stack([5 * np.cos(s), 3 * np.sin(s), 0.4 * np.sin(2 * s)], axis=1)
    return t, xyz, h.yaw_quat(s + np.pi / 2)


def test_known_offset_and_local_yaw_give_exactly_that_error(
    make_build: Callable[..., Path], h: SimpleNamespace, tmp_path: Path
) -> None:
    t, xyz, q = _gt(h)
    offset = np.array([0.3, -0.4, 0.12])
    yaw_err = math.radians(2.5)
    # Each estimated pose = ground truth moved by `offset` and turned by yaw_err about its own z.
    r_est = quat_to_matrix(q) @ quat_to_matrix(h.yaw_quat(np.array([yaw_err])))[0]
    from scipy.spatial.transform import Rotation

    q_est = Rotation.from_matrix(r_est).as_quat()
    out = make_build(trajectory=(t, xyz + offset, q_est), floors=FLOORS)
    gt = h.write_tum(tmp_path / "gt.tum", t, xyz, q)
    m = evaluate(out, trajectory=gt, align="4dof").metrics
    assert m["trajectory.pairs"] == 200
    norm = float(np.linalg.norm(offset))
    for key in ("ape_rmse_m", "ape_mean_m", "ape_median_m", "ape_max_m"):
        assert m[f"trajectory.{key}"] == pytest.approx(norm, abs=1e-8)
    assert m["trajectory.z_rmse_m"] == pytest.approx(0.12, abs=1e-8)
    assert m["trajectory.xy_rmse_m"] == pytest.approx(0.5, abs=1e-8)
    for key in ("rot_rmse_deg", "rot_mean_deg", "rot_max_deg"):
        assert m[f"trajectory.{key}"] == pytest.approx(2.5, abs=1e-6)
    # A constant offset is all the 4-DoF alignment removes; the local yaw error stays.
    assert m["trajectory.4dof.ape_rmse_m"] == pytest.approx(0.0, abs=1e-8)
    assert m["trajectory.4dof.rot_rmse_deg"] == pytest.approx(2.5, abs=1e-6)
    # A yaw error tilts nothing.
    assert m["trajectory.tilt_rmse_deg"] == pytest.approx(0.0, abs=1e-6)


def test_tilt_is_roll_and_pitch_alone(
    make_build: Callable[..., Path], h: SimpleNamespace, tmp_path: Path
) -> None:
    """Each estimated pose pitched by 0.3 deg about its own y and turned 2 deg in yaw: the tilt
    error is the 0.3 deg, whatever the heading; the rotation error holds both."""
    from scipy.spatial.transform import Rotation

    t, xyz, q = _gt(h)
    local = Rotation.from_euler("zy", [2.0, 0.3], degrees=True).as_matrix()
    q_est = Rotation.from_matrix(quat_to_matrix(q) @ local).as_quat()
    out = make_build(trajectory=(t, xyz, q_est), floors=FLOORS)
    m = evaluate(out, trajectory=h.write_tum(tmp_path / "gt.tum", t, xyz, q)).metrics
    assert m["trajectory.tilt_rmse_deg"] == pytest.approx(0.3, abs=1e-6)
    assert m["trajectory.tilt_max_deg"] == pytest.approx(0.3, abs=1e-6)
    assert m["trajectory.rot_rmse_deg"] == pytest.approx(math.hypot(2.0, 0.3), abs=2e-3)


def test_global_yaw_and_shift_removed_by_alignment(
    make_build: Callable[..., Path], h: SimpleNamespace, tmp_path: Path
) -> None:
    t, xyz, q = _gt(h)
    yaw = math.radians(10.0)
    rz = quat_to_matrix(h.yaw_quat(np.array([yaw])))[0]
    shift = np.array([1.0, 2.0, -0.5])
    from scipy.spatial.transform import Rotation

    q_est = Rotation.from_matrix(rz[None] @ quat_to_matrix(q)).as_quat()
    out = make_build(trajectory=(t, xyz @ rz.T + shift, q_est), floors=FLOORS)
    gt = h.write_tum(tmp_path / "gt.tum", t, xyz, q)
    for align in ("se3", "4dof"):
        m = evaluate(out, trajectory=gt, align=align).metrics
        assert m["trajectory.rot_rmse_deg"] == pytest.approx(10.0, abs=1e-6)
        assert m["trajectory.ape_rmse_m"] > 1.0
        assert m[f"trajectory.{align}.ape_rmse_m"] == pytest.approx(0.0, abs=1e-7)
        assert m[f"trajectory.{align}.rot_rmse_deg"] == pytest.approx(0.0, abs=1e-5)


def _noisy_pair(h: SimpleNamespace, tmp_path: Path, seed: int) -> tuple[Path, Path]:
    """Ground truth at 20 Hz and a noisy, jittered, drifting estimate at ~10 Hz."""
    rng = np.random.default_rng(seed)
    n = 3000
    t = h.T0_S + 0.05 * np.arange(n)
    s = np.linspace(0, 4 * np.pi, n)
    xyz = np.stack([6 * np.cos(s), 4 * np.sin(s), 0.05 * s], axis=1)
    from scipy.spatial.transform import Rotation

    rot = Rotation.from_euler("zyx", np.stack([s, 0.05 * np.sin(3 * s), 0.03 * np.cos(s)], 1))
    gt = h.write_tum(tmp_path / f"gt{seed}.tum", t, xyz, rot.as_quat())
    idx = np.arange(0, n, 2)
    t_est = t[idx] + rng.uniform(-0.02, 0.02, len(idx))  # about half fall outside 0.01 s
    xyz_est = xyz[idx] + rng.normal(0, 0.05, (len(idx), 3)) + 0.0005 * np.arange(len(idx))[:, None]
    rot_est = Rotation.from_rotvec(rng.normal(0, 0.02, (len(idx), 3))) * rot[idx]
    est = h.write_tum(tmp_path / f"est{seed}.tum", t_est, xyz_est, rot_est.as_quat())
    return est, gt


@pytest.mark.parametrize("seed", [0, 1])
def test_same_rmse_as_evo(
    make_build: Callable[..., Path], h: SimpleNamespace, tmp_path: Path, seed: int
) -> None:
    from evo.core import metrics as evo_metrics
    from evo.core import sync
    from evo.tools import file_interface

    est_path, gt_path = _noisy_pair(h, tmp_path, seed)
    out = make_build(name=f"b{seed}", floors=FLOORS)
    (out / "trajectory.tum").write_text(est_path.read_text())
    ours = evaluate(out, trajectory=gt_path, align="se3").metrics

    ref = file_interface.read_tum_trajectory_file(str(gt_path))
    est = file_interface.read_tum_trajectory_file(str(est_path))
    ref, est = sync.associate_trajectories(ref, est, max_diff=0.01)
    assert ours["trajectory.pairs"] == ref.num_poses
    assert 500 < ref.num_poses < 1000  # the jitter drops stamps: association matters

    def evo_rmse(relation: object, traj_est: object) -> float:
        ape = evo_metrics.APE(relation)
        ape.process_data((ref, traj_est))
        return float(ape.get_statistic(evo_metrics.StatisticsType.rmse))

    trans = evo_metrics.PoseRelation.translation_part
    angle = evo_metrics.PoseRelation.rotation_angle_deg
    assert ours["trajectory.ape_rmse_m"] == pytest.approx(evo_rmse(trans, est), abs=1e-6)
    assert ours["trajectory.rot_rmse_deg"] == pytest.approx(evo_rmse(angle, est), abs=1e-6)
    import copy

    aligned = copy.deepcopy(est)
    aligned.align(ref, correct_scale=False)
    assert ours["trajectory.se3.ape_rmse_m"] == pytest.approx(evo_rmse(trans, aligned), abs=1e-6)
    assert ours["trajectory.se3.rot_rmse_deg"] == pytest.approx(evo_rmse(angle, aligned), abs=1e-6)
    assert ours["trajectory.se3.ape_rmse_m"] < ours["trajectory.ape_rmse_m"]


def test_association_matches_evo_indices(h: SimpleNamespace) -> None:
    from evo.core.sync import matching_time_indices

    rng = np.random.default_rng(3)
    a = np.sort(rng.uniform(0, 10, 500))
    b = np.sort(rng.uniform(0, 10, 800))
    i_a, i_b = associate(a, b, 0.01)
    e_a, e_b = matching_time_indices(a, b, 0.01)
    assert i_a.tolist() == e_a and i_b.tolist() == e_b
    # The longer trajectory first: evo starts from the shorter one, so must we.
    j_b, j_a = associate(b, a, 0.01)
    assert j_a.tolist() == e_a and j_b.tolist() == e_b


def test_no_common_time_and_bad_file(
    make_build: Callable[..., Path], h: SimpleNamespace, tmp_path: Path
) -> None:
    t, xyz, q = _gt(h)
    out = make_build(trajectory=(t, xyz, q), floors=FLOORS)
    late = h.write_tum(tmp_path / "late.tum", t + 1000.0, xyz, q)
    with pytest.raises(GroundTruthError, match=r"late\.tum: no poses pair up in time"):
        evaluate(out, trajectory=late)
    bad = tmp_path / "bad.tum"
    bad.write_text("1.0 2.0 3.0\n")
    with pytest.raises(GroundTruthError, match=r"bad\.tum: line 1: expected 8 values"):
        evaluate(out, trajectory=bad)
    assert len(read_tum(late).stamps_s) == 200


@pytest.mark.parametrize("kind", ["se3", "4dof"])
def test_alignment_is_the_least_squares_optimum(kind: str) -> None:
    """No rigid (resp. yaw-only) motion gives a smaller sum of squared errors than ours."""
    from scipy.optimize import minimize
    from scipy.spatial.transform import Rotation

    from mfmap.eval.trajectory import align_4dof, umeyama_se3

    rng = np.random.default_rng(7)
    src = rng.uniform(-10, 10, (200, 3))
    true_rot = Rotation.from_euler("zyx", [0.7, 0.05, -0.03]).as_matrix()
    dst = src @ true_rot.T + [3.0, -2.0, 0.5] + rng.normal(0, 0.1, src.shape)
    rot, trans = (umeyama_se3 if kind == "se3" else align_4dof)(src, dst)

    def cost(params: np.ndarray) -> float:
        if kind == "se3":
            r = Rotation.from_rotvec(params[:3]).as_matrix()
        else:
            r = Rotation.from_euler("z", params[0]).as_matrix()
        t = params[3:6] if kind == "se3" else params[1:4]
        return float(np.sum((src @ r.T + t - dst) ** 2))

    ours = float(np.sum((src @ rot.T + trans - dst) ** 2))
    if kind == "se3":
        start = np.concatenate([Rotation.from_matrix(rot).as_rotvec(), trans])
    else:
        start = np.concatenate([[math.atan2(rot[1, 0], rot[0, 0])], trans])
    best = minimize(cost, start + 0.01, method="BFGS", options={"gtol": 1e-10})
    assert ours <= best.fun + 1e-7
    assert ours == pytest.approx(best.fun, rel=1e-9)
    if kind == "4dof":
        assert rot[2, 2] == 1.0 and rot[0, 2] == 0.0  # yaw only
