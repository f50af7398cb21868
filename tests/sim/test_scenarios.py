"""Scenario routes (no sensors: fast): they stay in free space, respect the speed limits, visit
every floor; stairs climb on real steps; the determinism and the CLI of `mfmap simulate`."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mfmap.errors import MfmapError
from mfmap.sim import SCENARIOS, simulate
from mfmap.sim.building import Building
from mfmap.sim.run import build_trajectory
from mfmap.sim.scenarios import building_for
from mfmap.sim.spec import office_block
from mfmap.sim.trajectory import DT_S


def _route(name: str, seed: int = 0) -> tuple[Building, object]:
    spec = SCENARIOS[name]
    building = building_for(spec, seed)
    return building, build_trajectory(spec, building, seed, 1)


_GENERATED = [(n, seed) for n in sorted(SCENARIOS) if SCENARIOS[n].building is not None for seed in (1, 2, 3)]


@pytest.mark.parametrize(("name", "seed"), [(n, 0) for n in sorted(SCENARIOS)] + _GENERATED)
def test_route_is_drivable(name: str, seed: int) -> None:
    import open3d as o3d

    building, traj = _route(name, seed)
    xyz = traj.xyz  # type: ignore[attr-defined]
    rpy = traj.rpy  # type: ignore[attr-defined]
    speed = np.linalg.norm(np.diff(xyz[:, :2], axis=0), axis=1) / DT_S
    yaw_rate = np.abs(np.diff(rpy[:, 2])) / DT_S
    assert speed.max() <= 1.0 + 1e-9 and yaw_rate.max() < 0.7
    # The elevator at most at its speed (1 m/s in the office block).
    assert np.abs(np.diff(xyz[:, 2])).max() / DT_S <= building.spec.shaft.speed_m_s + 1e-9
    # Every floor of the office block is visited (others skip floors: passed through on the
    # stairs, stopped at in the cabin); the robot starts at the world origin.
    floors = {building.floor_of_height(z) for z in xyz[::200, 2]}
    visited = {f for f, _, _ in traj.floor_visits}  # type: ignore[attr-defined]
    assert visited <= floors
    session = SCENARIOS[name].session
    if session is not None:  # one log of several of a building: its own start and floors
        start = (*session.start_xy, building.elevation(SCENARIOS[name].start_floor))
        np.testing.assert_allclose(xyz[0], start)
        assert visited == floors
    else:
        if SCENARIOS[name].building is None:
            assert floors == set(range(building.n_floors))
        else:
            assert len(visited) >= 2
        np.testing.assert_allclose(xyz[0], 0.0)
    # Clearance: 0.6 m above the base, nothing within 0.35 m (the robot's radius), except in the
    # elevator's doorway/cabin and the stairwell where the carrier squeezes past the divider.
    probe = xyz[::20].copy()
    probe[:, 2] += 0.6
    dist = building.scene(None).compute_distance(o3d.core.Tensor(probe.astype(np.float32))).numpy()
    near_cabin = np.linalg.norm(probe[:, :2] - np.array(building.shaft_center), axis=1) < 1.8
    sx0, sx1, sy0, sy1 = building.stair_rect
    in_stairs = (probe[:, 0] > sx0) & (probe[:, 0] < sx1) & (probe[:, 1] > sy0) & (probe[:, 1] < sy1)
    free = ~near_cabin & ~in_stairs
    assert dist[free].min() >= 0.35


def test_buildings_for_many_seeds() -> None:
    for seed in range(40):
        building = Building(office_block(3, 4.0), 0, seed)
        counts = [len(f.boxes) for f in building.floors]
        assert all(c > 80 for c in counts)
    # Floors differ from each other (rooms, doors, furniture) but share the structure.
    a, b = (set(f.boxes) for f in Building(office_block(2, 4.0), 0, 0).floors)
    shifted = {type(x)((x.lo[0], x.lo[1], x.lo[2] - 4.0), (x.hi[0], x.hi[1], x.hi[2] - 4.0), x.kind) for x in b}
    common = a & shifted
    assert len(common) >= 15 and len(a - shifted) > 20


def test_durations() -> None:
    durations = {name: _route(name)[1].duration_s for name in ("tiny", "two-floor", "long")}  # type: ignore[attr-defined]
    assert 60 <= durations["tiny"] <= 100
    assert 120 <= durations["two-floor"] <= 240
    assert 1700 <= durations["long"] <= 2000


def test_two_floor_mirrors_the_seed_experiment() -> None:
    _, traj = _route("two-floor")
    cps = {(c.label, c.floor): (c.x, c.y, c.z) for c in traj.checkpoints}  # type: ignore[attr-defined]
    for floor, z in ((0, 0.0), (1, 4.7)):
        for label, (x, y) in {"P1": (0, 0), "P2": (6, -2), "P3": (6, -12), "P4": (0.7, -12)}.items():
            assert cps[(label, floor)] == pytest.approx((x, y, z), abs=1e-9)
    assert traj.rpy[0, 2] == 0.0  # type: ignore[attr-defined]  # start facing +x


def test_stairs_climb_on_the_steps() -> None:
    import open3d as o3d

    building, traj = _route("stairs")
    trs = traj.transitions  # type: ignore[attr-defined]
    assert [(t.kind, t.from_floor, t.to_floor) for t in trs] == [("stairs", 0, 1), ("stairs", 1, 2)]
    xyz, rpy = traj.xyz, traj.rpy  # type: ignore[attr-defined]
    for tr in trs:
        i0, i1 = round(tr.t_start_s / DT_S), round(tr.t_end_s / DT_S)
        z = xyz[i0:i1, 2]
        assert z[-1] - z[0] == pytest.approx(3.5, abs=1e-6)
        moving = np.linalg.norm(np.diff(xyz[i0:i1, :2], axis=0), axis=1) / DT_S
        assert np.median(moving) > 0.2  # height changes while moving
        assert np.degrees(np.abs(rpy[i0:i1, 1]).max()) > 15  # pitched on the steps
        # The surface below the carrier is a step: within a riser of its base height.
        mid = xyz[i0:i1][len(z) // 4 : 3 * len(z) // 4 : 40]
        rays = np.column_stack([mid + np.array([0.0, 0.0, 0.6]), np.tile([0, 0, -1.0], (len(mid), 1))]).astype(np.float32)
        hit = building.scene(None).cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        gap = hit - 0.6
        assert np.all(np.abs(gap) < building.stairs.rise_m + 0.03)


def test_unknown_scenario_lists_the_valid_ones(tmp_path: Path) -> None:
    with pytest.raises(MfmapError, match=r"unknown scenario 'nope'.*two-floor"):
        simulate("nope", tmp_path)


def _digest(folder: Path) -> dict[str, str]:
    return {
        p.name: hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.suffix != ".png"
    }


def test_deterministic(tmp_path: Path) -> None:
    a = simulate("tiny-2d", tmp_path / "a", seed=3)
    b = simulate("tiny-2d", tmp_path / "b", seed=3)
    da, db = _digest(a.out_dir), _digest(b.out_dir)
    assert set(da) == {"log.mcap", "gt_trajectory.tum", "gt_points.csv", "gt_floors.json", "gt_cloud.ply"}
    assert da == db  # byte-identical log and ground truth
    # Another seed is another building (rooms, furniture) and another epoch.
    boxes3 = [f.boxes for f in Building(office_block(2, 3.5), 0, 3).floors]
    boxes4 = [f.boxes for f in Building(office_block(2, 3.5), 0, 4).floors]
    assert boxes3 != boxes4


def test_lidar_scan_is_deterministic() -> None:
    from mfmap.sim.sensors import Lidar, LidarSpec, Scenes

    scans = []
    for _ in range(2):
        building, traj = _route("tiny", seed=5)
        lidar = Lidar(LidarSpec(beams=8, columns=256), Scenes(building, traj), seed=5)  # type: ignore[arg-type]
        scans.append(lidar.scan(12.3).tobytes() + lidar.scan(45.0).tobytes())
    assert scans[0] == scans[1]


def test_cli_simulate_with_plots(tmp_path: Path) -> None:
    res = subprocess.run(
        [sys.executable, "-m", "mfmap.cli", "simulate", "tiny-2d", "-o", str(tmp_path), "--format", "ros1", "--plot"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr
    for name in ("log.bag", "gt_trajectory.tum", "gt_points.csv", "gt_floors.json", "gt_cloud.ply", "floorplans.png", "pressure.png"):
        assert (tmp_path / name).stat().st_size > 100
    assert (tmp_path / "floorplans.png").read_bytes()[:4] == b"\x89PNG"
    bad = subprocess.run(
        [sys.executable, "-m", "mfmap.cli", "simulate", "nope", "-o", str(tmp_path / "x")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert bad.returncode == 1 and "unknown scenario 'nope'" in bad.stderr
    assert "Traceback" not in bad.stderr


def test_kinematics_windows_equal_the_whole() -> None:
    from mfmap.sim.sensors import Kinematics

    _, traj = _route("tiny")
    whole = Kinematics.of(traj)  # type: ignore[arg-type]
    n = len(traj.xyz)  # type: ignore[attr-defined]
    for i0 in (0, 200, 9_000, n - 200):
        part = Kinematics.of(traj, i0, i0 + 200)  # type: ignore[arg-type]
        assert np.array_equal(part.gyro, whole.gyro[i0 : i0 + 200])
        assert np.array_equal(part.specific_force, whole.specific_force[i0 : i0 + 200])
        assert np.array_equal(part.yaw_rate, whole.yaw_rate[i0 : i0 + 200])


def test_source_digest_is_a_stable_cache_key() -> None:
    from mfmap.sim import source_digest

    key = source_digest()
    assert len(key) == 10 and int(key, 16) >= 0 and key == source_digest()
