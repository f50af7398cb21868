"""The building graph on a synthetic building with known truth (see tests/graph/synthetic.py)."""

from __future__ import annotations

import math
import os
from pathlib import Path

import gtsam
import numpy as np
import pytest

from mfmap.graph.barometer import pressure_to_height_m
from mfmap.graph.config import AblationConfig, GraphConfig
from mfmap.graph.interfloor import register_floors
from mfmap.graph.optimize import GraphResult, optimize_building
from tests.graph.synthetic import SyntheticBuilding, make_building, pose_xyyaw

FLOOR_HEIGHT_M = 4.0


def _fit_xyyaw(est: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Rigid 2D transform (x, y, yaw) taking estimated points onto reference points."""
    mu_e, mu_r = est.mean(axis=0), ref.mean(axis=0)
    h = (est - mu_e).T @ (ref - mu_r)
    u, _, vt = np.linalg.svd(h)
    rot = vt.T @ u.T
    if np.linalg.det(rot) < 0:
        vt[1] *= -1
        rot = vt.T @ u.T
    out = np.eye(3)
    out[:2, :2] = rot
    out[:2, 2] = mu_r - rot @ mu_e
    return out


def interfloor_error(b: SyntheticBuilding, poses: dict[int, np.ndarray], lower: int, upper: int) -> tuple[float, float, float, float]:
    """x, y, yaw (deg) and z error of floor `upper` relative to floor `lower` (as the multi-floor precision mapping paper measures it)."""
    fits = {}
    z_err = {}
    for f in (lower, upper):
        ks = [k for k in b.keyframes if k.floor_id == f]
        est = np.array([poses[k.id][:2, 3] for k in ks])
        ref = np.array([b.gt_poses[k.id][:2, 3] for k in ks])
        fits[f] = _fit_xyyaw(est, ref)
        z_err[f] = float(np.median([poses[k.id][2, 3] - b.gt_poses[k.id][2, 3] for k in ks]))
    rel = np.linalg.inv(fits[lower]) @ fits[upper]
    yaw = math.degrees(math.atan2(rel[1, 0], rel[0, 0]))
    return float(rel[0, 2]), float(rel[1, 2]), yaw, z_err[upper] - z_err[lower]


def rmse_per_floor(b: SyntheticBuilding, poses: dict[int, np.ndarray]) -> dict[int, float]:
    out = {}
    for f in sorted({k.floor_id for k in b.keyframes}):
        d = np.array([poses[k.id][:3, 3] - b.gt_poses[k.id][:3, 3] for k in b.keyframes if k.floor_id == f])
        out[f] = float(np.sqrt(np.mean(np.sum(d**2, axis=1))))
    return out


@pytest.fixture(scope="module")
def building() -> SyntheticBuilding:
    return make_building((0, 1, 0), seed=3, floor_height_m=FLOOR_HEIGHT_M)


@pytest.fixture(scope="module")
def full(building: SyntheticBuilding) -> GraphResult:
    b = building
    return optimize_building(b.keyframes, b.edges, b.segmentation, b.pressure, GraphConfig(), temperature_k=295.0)


def test_barometric_factor_takes_our_height() -> None:
    """baroOut(h) fed to gtsam.BarometricFactor makes its measurement exactly h; z = h - bias."""
    conv = gtsam.BarometricFactor()
    h = float(pressure_to_height_m(np.array([100_000.0]), 100_050.0, 295.0)[0])
    assert h == pytest.approx(4.316, abs=0.005)  # 50 Pa at 295 K is 4.32 m
    factor = gtsam.BarometricFactor(1, 2, conv.baroOut(h), gtsam.noiseModel.Isotropic.Sigma(1, 0.1))
    assert factor.measurementIn() == pytest.approx(h, abs=1e-9)
    values = gtsam.Values()
    values.insert(1, gtsam.Pose3(gtsam.Rot3(), np.array([0.0, 0.0, 4.0])))
    values.insert(2, 0.5)
    assert factor.unwhitenedError(values)[0] == pytest.approx(4.0 + 0.5 - h, abs=1e-9)


def test_factor_counts(building: SyntheticBuilding, full: GraphResult) -> None:
    n = len(building.keyframes)
    stats = full.stats
    assert stats["barometer"].count == n
    assert stats["bias_walk"].count == n - 1
    assert stats["gravity"].count == n
    assert stats["height_tie"].count == n
    assert stats["elevator"].count == 2  # two rides
    assert stats["transition_z"].count == 2
    assert stats["odometry"].count == sum(1 for e in building.edges if e.kind == "odometry")
    assert stats["loop"].count == sum(1 for e in building.edges if e.kind == "loop")
    # One registration, shared by keyframe pairs one above the other across the floors.
    assert 3 <= stats["interfloor"].count <= GraphConfig().interfloor.anchors
    assert stats["interfloor"].rejected == 0
    assert full.error_final < 0.05 * full.error_initial


def test_full_graph_meets_the_bars(building: SyntheticBuilding, full: GraphResult) -> None:
    initial = {k.id: k.pose for k in building.keyframes}
    assert rmse_per_floor(building, initial)[1] > 0.3  # the drift the graph has to remove
    dx, dy, dyaw, dz = interfloor_error(building, full.poses, 0, 1)
    assert abs(dx) < 0.05 and abs(dy) < 0.05
    assert abs(dyaw) < 0.2
    assert abs(dz) < 0.02 * FLOOR_HEIGHT_M
    rmse = rmse_per_floor(building, full.poses)
    assert rmse[0] < 0.05 and rmse[1] < 0.06
    assert full.floor_z_m[1] - full.floor_z_m[0] == pytest.approx(FLOOR_HEIGHT_M, abs=0.08)


def test_inter_floor_registration_is_what_fixes_yaw() -> None:
    """One ride up, no return: only registration can see the ride's yaw error."""
    b = make_building((0, 1), seed=4, floor_height_m=FLOOR_HEIGHT_M)
    runs = {
        on: optimize_building(
            b.keyframes, b.edges, b.segmentation, b.pressure,
            GraphConfig(ablation=AblationConfig(inter_floor_registration=on)), temperature_k=295.0,
        )
        for on in (False, True)
    }
    assert "interfloor" not in runs[False].stats
    _, _, yaw_off, _ = interfloor_error(b, runs[False].poses, 0, 1)
    _, _, yaw_on, _ = interfloor_error(b, runs[True].poses, 0, 1)
    assert abs(yaw_off) > 0.5  # the ride's 1.5 deg error mostly stays without registration
    assert abs(yaw_on) < 0.2


def test_without_barometer_z_comes_from_the_transitions(building: SyntheticBuilding) -> None:
    b = building
    res = optimize_building(
        b.keyframes, b.edges, b.segmentation, b.pressure,
        GraphConfig(ablation=AblationConfig(barometer_factors=False)), temperature_k=295.0,
    )
    assert "barometer" not in res.stats
    assert res.floor_z_m[1] - res.floor_z_m[0] == pytest.approx(FLOOR_HEIGHT_M, abs=0.1)


def test_registration_recovers_a_known_offset(building: SyntheticBuilding) -> None:
    from mfmap.graph.floorlinks import floor_points

    b = building
    gt = b.gt_poses
    lower = floor_points(b.keyframes, gt, 0, (0.5, 1.5), 0.0)
    upper = floor_points(b.keyframes, gt, 1, (0.5, 1.5), FLOOR_HEIGHT_M)
    shift = pose_xyyaw(0.25, -0.15, 0.0, math.radians(2.0))
    moved = upper @ shift[:3, :3].T + shift[:3, 3]
    match = register_floors(lower, moved, 0, 1)
    assert match.accepted, match.reason
    recovered = match.correction @ shift
    assert abs(recovered[0, 3]) < 0.01 and abs(recovered[1, 3]) < 0.01
    assert abs(math.degrees(math.atan2(recovered[1, 0], recovered[0, 0]))) < 0.05


def test_corridor_is_rejected_as_ambiguous() -> None:
    """Two long parallel walls: the floors can slide along them, so no x, y, yaw is trusted."""
    rng = np.random.default_rng(0)

    def corridor(n: int) -> np.ndarray:
        x = rng.uniform(0.0, 30.0, n)
        y = np.where(rng.random(n) < 0.5, 0.0, 2.0) + rng.normal(0, 0.005, n)
        return np.column_stack([x, y, rng.uniform(0.5, 1.5, n)])

    lower = corridor(20_000)
    upper = corridor(20_000) + np.array([0.3, 0.0, 0.0])
    match = register_floors(lower, upper, 0, 1)
    assert not match.accepted
    assert "ambiguous" in match.reason


def _walls(rng: np.random.Generator, segments: list[tuple[tuple[float, float], tuple[float, float], tuple[float, float]]]
           ) -> tuple[np.ndarray, np.ndarray]:
    """A floor's band: points on each wall segment (a, b) over 0.5-1.5 m, 5 mm noise, each seen
    from the side `view` (x, y) points to."""
    points, views = [], []
    for a, b, view in segments:
        n = int(400 * math.dist(a, b))
        t = rng.uniform(0.0, 1.0, n)
        xy = np.outer(1 - t, a) + np.outer(t, b) + rng.normal(0.0, 0.005, (n, 2))
        points.append(np.column_stack([xy, rng.uniform(0.5, 1.5, n)]))
        views.append(np.tile([2.0 * view[0], 2.0 * view[1], 0.0], (n, 1)))
    return np.concatenate(points), np.concatenate(views)


def test_floors_match_the_same_face_of_thin_walls_and_not_one_floors_clutter() -> None:
    """Two floors of one 20 x 12 m shell, in place. An 8 cm partition is seen from its east
    face below and its west face above, and the upper floor has cabinets 6 cm in front of two
    walls: least squares pulls the floors centimetres apart, face-matching and Cauchy weights
    hold them within millimetres."""
    rng = np.random.default_rng(0)
    shell = [((0.0, 0.0), (20.0, 0.0), (0.0, 1.0)), ((0.0, 12.0), (20.0, 12.0), (0.0, -1.0)),
             ((0.0, 0.0), (0.0, 12.0), (1.0, 0.0)), ((20.0, 0.0), (20.0, 12.0), (-1.0, 0.0)),
             ((0.0, 4.0), (6.0, 4.0), (0.0, 1.0))]
    lower, lower_views = _walls(rng, [*shell, ((10.04, 4.0), (10.04, 12.0), (1.0, 0.0))])
    upper, upper_views = _walls(rng, [*shell, ((9.96, 4.0), (9.96, 12.0), (-1.0, 0.0)),
                                      ((2.0, 0.06), (8.0, 0.06), (0.0, 1.0)),
                                      ((12.0, 11.94), (17.0, 11.94), (0.0, -1.0))])
    plain = register_floors(lower, upper, 0, 1)
    assert plain.accepted and math.hypot(plain.dx_m, plain.dy_m) > 0.01
    match = register_floors(lower, upper, 0, 1, lower_views=lower_views, upper_views=upper_views,
                            robust_m=GraphConfig().interfloor.robust_m)
    assert match.accepted, match.reason
    assert math.hypot(match.dx_m, match.dy_m) < 0.004
    assert abs(match.dyaw_deg) < 0.02


def test_floor_icp_holds_z_and_recovers_x_y_yaw(building: SyntheticBuilding) -> None:
    """The inter-floor ICP solves for x, y, yaw (and roll, pitch in its fine pass), never z:
    horizontal normals leave z unmeasured, and open3d's six-degree fit ran away on it."""
    import open3d as o3d

    from mfmap.graph.floorlinks import floor_points
    from mfmap.graph.interfloor import _cloud, _Target, project_xyyaw

    b = building
    lower = floor_points(b.keyframes, b.gt_poses, 0, (0.5, 1.5), 0.0)
    shift = pose_xyyaw(0.12, -0.2, 0.0, math.radians(1.5))
    tilt = np.eye(4)
    tilt[:3, :3] = gtsam.Rot3.RzRyRx(math.radians(0.3), math.radians(-0.2), 0.0).matrix()
    moved = lower @ (shift @ tilt)[:3, :3].T + shift[:3, 3]
    target = _Target(_cloud(lower, 0.1))
    source = np.asarray(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(moved))
                        .voxel_down_sample(0.1).points)
    start = np.eye(4)
    start[2, 3] = 0.05  # a z offset the walls cannot see: it must come back as it went in
    coarse = target.icp(source, start, 0.5)
    assert coarse[2, 3] == 0.05 and np.allclose(coarse[2, :3], [0.0, 0.0, 1.0])
    fine = target.icp(source, coarse, 0.1, tilt=True)
    assert fine[2, 3] == pytest.approx(0.05, abs=1e-12)
    # The fine pass takes the tilt out: what is left is the inverse of the shift.
    recovered = project_xyyaw(fine) @ shift
    assert abs(recovered[0, 3]) < 0.003 and abs(recovered[1, 3]) < 0.003
    assert abs(math.degrees(math.atan2(recovered[1, 0], recovered[0, 0]))) < 0.01


_POOL_CHECK = """
import json, sys
import mfmap
mfmap.limit_threads()  # as `mfmap build` does: one thread, so the two runs can be compared bit for bit
import numpy as np
from mfmap.graph.config import GraphConfig
from mfmap.graph.optimize import optimize_building
from tests.graph.synthetic import make_building
from mfmap.mapping.workers import worker_pool

if __name__ == "__main__":
    b = make_building((0, 1, 2), seed=5, floor_height_m=float(sys.argv[1]))
    def run(executor):
        return optimize_building(b.keyframes, b.edges, b.segmentation, b.pressure, GraphConfig(),
                                 temperature_k=295.0, executor=executor)
    serial = run(None)
    with worker_pool(2, warm=False) as pool:
        parallel = run(pool)
    print(json.dumps({
        "accepted": [m.accepted for m in serial.floor_matches],
        "same_matches": all(
            (a.lower, a.upper, a.fitness, a.rmse_m, a.reason) == (c.lower, c.upper, c.fitness, c.rmse_m, c.reason)
            and np.array_equal(a.correction, c.correction)
            for a, c in zip(serial.floor_matches, parallel.floor_matches, strict=True)),
        "max_pose_diff": max(float(np.abs(serial.poses[i] - parallel.poses[i]).max()) for i in serial.poses),
    }))
"""


def test_floor_pairs_registered_in_worker_processes_give_the_same_graph(tmp_path: Path) -> None:
    """Three floors, two pairs: registered in the build's worker pool (one pair per process)
    the matches and the optimised poses are the same bits as registered one after the other,
    in a process limited to one thread as `mfmap build` is."""
    import json
    import subprocess
    import sys

    script = tmp_path / "pool_check.py"
    script.write_text(_POOL_CHECK)
    # The script imports the synthetic building from tests/: the project's root on its path.
    root = str(Path(__file__).resolve().parents[2])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p)}
    out = subprocess.run([sys.executable, str(script), str(FLOOR_HEIGHT_M)], capture_output=True,
                         text=True, check=True, timeout=300, env=env)
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["accepted"] == [True, True]
    assert result["same_matches"]
    assert result["max_pose_diff"] == 0.0


def test_a_floor_registration_is_shared_by_pairs_across_the_floors() -> None:
    """Keyframes on a 20 x 10 m loop per floor (two visits below, one above): the pairs spread
    over the lower floor, each with the upper keyframe above it once registered, none at the
    ends of a visit (where the cabin is). Floors whose routes do not meet keep the one pair."""
    from mfmap.graph.floorlinks import _anchor_pairs
    from mfmap.types import Keyframe

    def lap(n: int) -> list[tuple[float, float]]:
        s = np.linspace(0.0, 60.0, n, endpoint=False)
        return [(min(v, 20.0) - max(v - 30.0, 0.0) if v < 50 else 0.0,
                 min(max(v - 20.0, 0.0), 10.0) - max(v - 50.0, 0.0)) for v in s]

    kfs: list[Keyframe] = []
    for visit, (floor, n) in enumerate([(0, 40), (1, 30), (0, 10)]):
        for x, y in lap(n):
            pose = np.eye(4)
            pose[:3, 3] = (x, y, 4.0 * floor)
            kfs.append(Keyframe(len(kfs), len(kfs), floor, visit, pose, np.zeros((0, 3), np.float32), 1.0, 0.0))
    correction = np.eye(4)
    correction[:2, 3] = (0.3, -0.2)  # the registration moves the upper floor by this
    # the upper floor's map as the graph's first pass placed it: off by the correction's inverse
    initial = {k.id: (np.linalg.inv(correction) @ k.pose if k.floor_id == 1 else k.pose) for k in kfs}
    pairs = _anchor_pairs(kfs, initial, 0, 1, correction, 8)
    assert 6 <= len(pairs) <= 8
    ends = {k.id for v in range(3) for k in [k for k in kfs if k.visit == v][:2] + [k for k in kfs if k.visit == v][-2:]}
    assert not ends & {k.id for pair in pairs for k in pair}
    lower_xy = np.array([initial[a.id][:2, 3] for a, _ in pairs])
    assert np.ptp(lower_xy[:, 0]) > 10.0 and np.ptp(lower_xy[:, 1]) > 5.0  # spread over the floor
    for a, b in pairs:
        above = (correction @ initial[b.id])[:2, 3]
        assert np.linalg.norm(above - initial[a.id][:2, 3]) < 1.5  # one above the other
    # One pair: the middle keyframes of each floor's longest visit.
    assert [(a.id, b.id) for a, b in _anchor_pairs(kfs, initial, 0, 1, correction, 1)] == [(20, 55)]
    away = np.eye(4)
    away[:2, 3] = (40.0, 0.0)  # the upper floor's route 20 m beyond the lower one's
    apart = {i: (away @ p if next(k for k in kfs if k.id == i).floor_id == 1 else p) for i, p in initial.items()}
    assert [(a.id, b.id) for a, b in _anchor_pairs(kfs, apart, 0, 1, correction, 8)] == [(20, 55)]
    # Only a short visit above (six keyframes or fewer): the one pair.
    short = [k for k in kfs if k.floor_id == 0 or k.id < 40 + 6]
    assert [(a.id, b.id) for a, b in _anchor_pairs(short, initial, 0, 1, correction, 8)] == [(20, 43)]
