"""Ground truth tied to the data: lidar points on the GT surfaces, pressure vs GT height, still
at checkpoints, elevator rides vertical. Only the log (third-party reader) and the GT files are
used, so a mismatch between what the simulator logs and what it claims shows up here."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from simtest_helpers import (
    GtPose,
    iter_messages,
    load_floors,
    load_points,
    load_tum,
    stamp_ns,
    tf_static,
)

from mfmap.sim.atmosphere import AirColumn
from mfmap.sim.groundtruth import read_ply


@pytest.fixture(scope="module", params=[("tiny", 0), ("gen-tiny", 0), ("gen-tiny", 2)], ids=lambda p: f"{p[0]}-{p[1]}")
def lidar_check(request: pytest.FixtureRequest, sim_run: Callable[..., Path]) -> dict[str, float]:
    """Share of lidar points within 8 cm of gt_cloud, with per-point poses (deskewed), with the
    scan-stamp pose only (not deskewed), and without the extrinsic; for scans outside the cabin.
    The office block and generated buildings (storeys of their own heights, the shaft's doors
    facing any way)."""
    from scipy.spatial import cKDTree

    scenario, seed = request.param
    tiny = sim_run(scenario, seed=seed)
    floors = load_floors(tiny)
    elevator = next(c for c in floors["connectors"] if c["kind"] == "elevator")
    shaft_xy = np.array([elevator["x"], elevator["y"]])
    elevations = np.array(floors["sim"]["elevations_m"])
    start_ns = floors["sim"]["start_ns"]
    gt = GtPose(load_tum(tiny), start_ns)
    cloud, cloud_floor = read_ply(tiny / "gt_cloud.ply")
    tree = cKDTree(cloud)
    ext = tf_static(tiny, "mcap")["lidar"]
    dt = np.dtype({"names": ["x", "y", "z", "t"], "formats": ["<f4"] * 3 + ["<u4"], "offsets": [0, 4, 8, 20], "itemsize": 32})
    doors = [(a - start_ns / 1e9, b - start_ns / 1e9) for a, b, _ in floors["sim"]["door_open"]]
    same_floor: list[float] = []
    near: dict[str, list[float]] = {"deskewed": [], "stamp_pose": [], "no_extrinsic": [], "moving_deskewed": [], "moving_stamp": []}
    for i, (_, _, _, msg) in enumerate(iter_messages(tiny, "mcap", {"/lidar/points"})):
        if i % 12:
            continue
        t_scan = (stamp_ns(msg) - start_ns) / 1e9
        xyz0, _ = gt.at(np.array([t_scan]))
        if np.linalg.norm(xyz0[0, :2] - shaft_xy) < 1.2 or any(a - 0.1 < t_scan < b for a, b in doors):
            continue  # in the cabin or doors open: the cabin is not in gt_cloud
        pts = np.frombuffer(bytes(msg.data), dtype=dt)
        ok = np.isfinite(pts["x"])
        p = np.column_stack([pts["x"][ok], pts["y"][ok], pts["z"][ok]]).astype(np.float64)
        t = t_scan + pts["t"][ok] / 1e9
        pos, rot = gt.at(t)
        p_base = p @ ext[:3, :3].T + ext[:3, 3]
        variants = {
            "deskewed": (pos, rot, p_base),
            "stamp_pose": (pos[:1], rot[:1], p_base),
            "no_extrinsic": (pos, rot, p),
        }
        moving = np.linalg.norm(pos[-1] - pos[0]) > 0.05 or np.linalg.norm(rot[-1] - rot[0]) > 0.02
        for name, (pp, rr, pb) in variants.items():
            world = np.einsum("nij,nj->ni", np.broadcast_to(rr, (len(pb), 3, 3)), pb) + pp
            d, nn = tree.query(world, distance_upper_bound=0.5)
            share = float(np.mean(d < 0.08))
            if name == "deskewed":
                # What a robot sees on floor k carries label k in gt_cloud (ceiling included).
                scan_floor = int(np.argmin(np.abs(elevations - float(xyz0[0, 2]))))
                hit = d < 0.08
                same_floor.append(float(np.mean(cloud_floor[nn[hit]] == scan_floor)))
            near[name].append(share)
            if moving and name in ("deskewed", "stamp_pose"):
                near["moving_" + ("deskewed" if name == "deskewed" else "stamp")].append(share)
    out = {k: float(np.mean(v)) for k, v in near.items() if v}
    out["same_floor"] = float(np.mean(same_floor))
    return out


def test_lidar_points_lie_on_gt_surfaces(lidar_check: dict[str, float]) -> None:
    assert lidar_check["deskewed"] >= 0.99
    assert lidar_check["moving_deskewed"] >= 0.99
    assert lidar_check["same_floor"] >= 0.99


def test_the_checks_can_fail(lidar_check: dict[str, float]) -> None:
    # Ignoring the extrinsic or the per-point time puts many points off the surfaces.
    assert lidar_check["no_extrinsic"] < 0.8
    # While moving (up to 0.8 m/s, 0.6 rad/s) one pose per sweep puts points off by > 8 cm:
    # ~5 % in the office block's narrow corridors, fewer in the generated buildings' wider ones.
    assert lidar_check["moving_stamp"] < lidar_check["moving_deskewed"] - 0.015


def test_pressure_follows_gt_height(tiny: Path) -> None:
    floors = load_floors(tiny)
    sim = floors["sim"]
    start_ns = sim["start_ns"]
    gt = GtPose(load_tum(tiny), start_ns)
    baro_z = tf_static(tiny, "mcap")["baro"][2, 3]
    t, p = [], []
    for _, _, _, msg in iter_messages(tiny, "mcap", {"/baro/pressure"}):
        t.append((stamp_ns(msg) - start_ns) / 1e9)
        p.append(msg.fluid_pressure)
    t_a, p_a = np.array(t), np.array(p)
    pos, rot = gt.at(t_a)
    h = pos[:, 2] + rot[:, 2, 2] * baro_z
    air = AirColumn(sim["temperature_k"], sim["temperature_gradient_k_per_m"], sim["gravity_m_s2"])
    expected = air.pressure_pa(h, sim["reference_pressure_pa"])
    resid = p_a - expected
    # Remove the slow weather drift (a line) and the known door/HVAC steps; what is left is noise.
    calm = np.ones(len(t_a), bool)
    for t0, t1, _ in sim["pressure_transients"]:
        calm &= ~((t_a >= t0 - start_ns / 1e9 - 0.5) & (t_a <= t1 - start_ns / 1e9 + 0.5))
    coef = np.polyfit(t_a[calm], resid[calm], 1)
    noise = resid[calm] - np.polyval(coef, t_a[calm])
    assert 2.5 < float(np.std(noise)) < 3.5  # 3 Pa white noise plus quantisation
    # The fitted slope is the weather drift plus the slow wander (1.5 Pa over 15 min: <= 38 Pa/h).
    assert abs(coef[0] * 3600) < abs(sim["drift_pa_per_h"]) + 45
    # The height change across the ride, from pressure alone (means over still windows).
    tr = floors["transitions"][0]
    t0, t1 = tr["t_start"] - start_ns / 1e9, tr["t_end"] - start_ns / 1e9
    before = p_a[(t_a > t0 - 1.0) & (t_a < t0)].mean()
    after = p_a[(t_a > t1) & (t_a < t1 + 1.0)].mean()
    dz = air.height_m(after, before)
    assert abs(dz - tr["height_change_m"]) < 0.25


def test_still_at_checkpoints(tiny: Path) -> None:
    floors = load_floors(tiny)
    start_ns = floors["sim"]["start_ns"]
    tum = load_tum(tiny)
    t_rel = tum[:, 0] - start_ns / 1e9
    rows = load_points(tiny)
    assert [(r["label"], r["floor"]) for r in rows] == [("P1", "0"), ("P2", "0"), ("P2", "1")]
    odom_t, odom_v = [], []
    for _, _, _, msg in iter_messages(tiny, "mcap", {"/odom"}):
        odom_t.append((stamp_ns(msg) - start_ns) / 1e9)
        odom_v.append(abs(msg.twist.twist.linear.x) + abs(msg.twist.twist.angular.z))
    odom_ta, odom_va = np.array(odom_t), np.array(odom_v)
    for r in rows:
        t0, t1 = float(r["t_start"]) - start_ns / 1e9, float(r["t_end"]) - start_ns / 1e9
        assert t1 - t0 >= 2.9
        inside = (t_rel >= t0) & (t_rel <= t1)
        assert inside.sum() >= 29
        target = np.array([float(r["x"]), float(r["y"]), float(r["z"])])
        assert np.abs(tum[inside, 1:4] - target).max() < 1e-3
        assert np.abs(tum[inside, 1:4] - tum[inside, 1:4].mean(axis=0)).max() == 0.0
        # The wheels agree: zero twist throughout the window.
        assert odom_va[(odom_ta > t0 + 0.01) & (odom_ta < t1 - 0.01)].max() == 0.0
    np.testing.assert_allclose([float(rows[2]["x"]), float(rows[2]["y"])], [6.0, -2.0])


def test_elevator_ride_is_vertical(tiny: Path) -> None:
    floors = load_floors(tiny)
    start_ns = floors["sim"]["start_ns"]
    tum = load_tum(tiny)
    (tr,) = floors["transitions"]
    assert (tr["kind"], tr["from"], tr["to"]) == ("elevator", 0, 1)
    assert tr["height_change_m"] == pytest.approx(3.5)
    ride = (tum[:, 0] >= tr["t_start"]) & (tum[:, 0] <= tr["t_end"])
    assert ride.sum() >= 40
    assert np.abs(tum[ride, 1] - tr["x"]).max() < 1e-6
    assert np.abs(tum[ride, 2] - tr["y"]).max() < 1e-6
    z = tum[ride, 3]
    assert z[0] < 0.05 and z[-1] > 3.45 and np.all(np.diff(z) >= 0)
    speed = np.diff(z) / np.diff(tum[ride, 0])
    assert 0.9 < speed.max() <= 1.0 + 1e-6  # accelerates to ~1 m/s, then decelerates
    # Floors: ids, elevations and visits partition the log.
    f0, f1 = floors["floors"]
    assert (f0["id"], f0["elevation_m"], f1["id"], f1["elevation_m"]) == (0, 0.0, 1, 3.5)
    assert f0["visits"][0][1] == tr["t_start"] and f1["visits"][0][0] == tr["t_end"]
    assert f0["visits"][0][0] == pytest.approx(start_ns / 1e9)
    assert f0["pressure_pa"] - f1["pressure_pa"] == pytest.approx(41.0, abs=2.0)
    kinds = {c["kind"] for c in floors["connectors"]}
    assert kinds == {"elevator", "stairs"}


def _series(folder: Path, topic: str, start_ns: int, fn: object) -> tuple[np.ndarray, np.ndarray]:
    t, v = [], []
    for _, _, _, msg in iter_messages(folder, "mcap", {topic}):
        t.append((stamp_ns(msg) - start_ns) / 1e9)
        v.append(fn(msg))  # type: ignore[operator]
    return np.array(t), np.array(v)


def test_imu_and_odometry_agree_with_gt(tiny: Path) -> None:
    from scipy.spatial.transform import Rotation

    floors = load_floors(tiny)
    start_ns = floors["sim"]["start_ns"]
    tum = load_tum(tiny)
    t_imu, imu = _series(
        tiny, "/imu/data", start_ns,
        lambda m: [m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z,
                   m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z],
    )  # fmt: skip
    still = t_imu < 2.9  # standing at P1
    acc_still = imu[still, 3:].mean(axis=0)
    np.testing.assert_allclose(acc_still, [0.0, 0.0, 9.81], atol=0.12)  # gravity, plus a small bias
    bias = imu[still, :3].mean(axis=0)
    assert np.abs(bias).max() < 0.01
    # Integrated yaw rate (bias from the still start removed) follows the GT heading.
    yaw_gt = np.unwrap(Rotation.from_quat(tum[:, 4:8]).as_euler("xyz")[:, 2])
    yaw_imu = np.cumsum(imu[:, 2] - bias[2]) * 0.005
    t_gt = tum[:, 0] - start_ns / 1e9
    err = np.interp(t_gt, t_imu, yaw_imu) - (yaw_gt - yaw_gt[0])
    assert np.degrees(np.abs(err).max()) < 3.0
    assert np.degrees(np.ptp(yaw_gt)) > 150  # the route turns (so the check means something)
    # The cabin's acceleration shows on the z accelerometer during the ride.
    tr = floors["transitions"][0]
    t0 = tr["t_start"] - start_ns / 1e9
    first_second = (t_imu > t0 + 0.2) & (t_imu < t0 + 1.5)
    assert imu[first_second, 5].mean() > 9.81 + 0.25
    # Wheel odometry: flat, still in the elevator, path length within its scale error of GT.
    t_od, od = _series(tiny, "/odom", start_ns, lambda m: [m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.position.z])
    assert np.all(od[:, 2] == 0.0)
    ride = (t_od >= t0) & (t_od <= tr["t_end"] - start_ns / 1e9)
    assert np.ptp(od[ride, :2], axis=0).max() == 0.0
    len_od = np.linalg.norm(np.diff(od[:, :2], axis=0), axis=1).sum()
    len_gt = np.linalg.norm(np.diff(tum[:, 1:3], axis=0), axis=1).sum()
    assert 0.93 < len_od / len_gt < 1.07 and abs(len_od / len_gt - 1.0) > 1e-4  # noisy, not GT


def test_cabin_walls_return_spurious_ranges(tiny: Path) -> None:
    floors = load_floors(tiny)
    tr = floors["transitions"][0]
    dt = np.dtype({"names": ["x", "y", "z", "intensity"], "formats": ["<f4"] * 4, "offsets": [0, 4, 8, 16], "itemsize": 32})
    ranges = []
    for _, _, _, msg in iter_messages(tiny, "mcap", {"/lidar/points"}):
        t = stamp_ns(msg) / 1e9
        if tr["t_start"] + 0.5 < t < tr["t_end"] - 0.5:  # riding, doors closed
            pts = np.frombuffer(bytes(msg.data), dtype=dt).reshape(msg.height, msg.width)
            mid = pts[msg.height // 2 - 2 : msg.height // 2 + 2].reshape(-1)  # near-horizontal beams
            ok = np.isfinite(mid["x"])
            ranges.append(np.hypot(mid["x"][ok], mid["y"][ok]))
    assert len(ranges) >= 30
    r = np.concatenate(ranges)
    # The cabin's inner walls are 0.95..1.45 m from the lidar horizontally; a share of the
    # returns come back longer (mirror paths), as on the real robot of the LeGO-LOAM elevator paper.
    spurious = float(np.mean(r > 1.6))
    assert 0.15 < spurious < 0.45
    assert float(np.mean(r < 1.55)) > 0.5
