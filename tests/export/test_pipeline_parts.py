"""Pieces of the build pipeline: the cabin/mirror filter, gravity per keyframe, one-floor fallback."""

from __future__ import annotations

import itertools
import warnings

import numpy as np

from mfmap.export.scans import _deskew, _floor_groups
from mfmap.export.write import FloorTrajectory
from mfmap.floors.nobaro import single_floor
from mfmap.graph.gravity import gravity_at_keyframes
from mfmap.mapping.cabin import CabinBox, drop_cabins, in_cabin
from mfmap.types import Extrinsics, ImuSeries, Keyframe, OdomSeries
from tests.graph.synthetic import pose_xyyaw


def test_cabin_filter_drops_the_cabin_and_what_is_seen_through_it() -> None:
    cabin = CabinBox(0, 10, pose_xyyaw(10.0, 0.0, 0.0, 0.0), (1.0, 1.0))
    robot = pose_xyyaw(0.0, 0.0, 0.0, 0.0)
    points = np.array(
        [
            [10.0, 0.5, 1.0],  # inside the cabin
            [13.0, 0.0, 1.0],  # behind it, seen through it (a mirror ghost)
            [13.0, 5.0, 1.0],  # beside it: kept
            [5.0, 0.0, 1.0],  # in front of it: kept
            [-4.0, 0.0, 1.0],  # behind the robot: kept
        ]
    )
    kept = drop_cabins(points, robot, 5, [cabin])
    assert kept.tolist() == points[[2, 3, 4]].tolist()
    # The same in a turned robot frame: the filter works in the scan's base frame.
    turned = pose_xyyaw(0.0, 0.0, 0.0, 0.7)
    base = (points - turned[:3, 3]) @ turned[:3, :3]
    assert drop_cabins(base, turned, 5, [cabin]).shape[0] == 3
    assert in_cabin(pose_xyyaw(10.2, 0.3, 0.0, 1.0), 5, [cabin])
    assert not in_cabin(pose_xyyaw(10.2, 0.3, 0.0, 1.0), 50, [cabin])  # outside the window
    assert not in_cabin(pose_xyyaw(12.0, 0.0, 0.0, 0.0), 5, [cabin])


def test_gravity_at_keyframes_in_the_base_frame() -> None:
    n = 200
    stamps = np.arange(n, dtype=np.int64) * 10_000_000  # 100 Hz
    tilt = np.array([0.0, 0.5, 9.797])  # about 2.9 degrees of pitch, as the IMU frame sees it
    imu = ImuSeries(stamps, np.zeros((n, 3)), np.tile(tilt, (n, 1)), np.full((n, 4), np.nan), "imu")
    imu_to_base = pose_xyyaw(0.1, 0.0, 0.2, np.pi / 2)  # IMU turned 90 degrees on the robot
    ext = Extrinsics("base_link", {"imu": imu_to_base})
    kfs = [Keyframe(0, 1_000_000_000, 0, 0, np.eye(4), np.zeros((0, 3), np.float32), 1.0, 0.0)]
    up = gravity_at_keyframes(imu, kfs, ext)[0]
    assert np.allclose(up, imu_to_base[:3, :3] @ (tilt / np.linalg.norm(tilt)))
    assert abs(up[0] + 0.0510) < 1e-3 and abs(up[1]) < 1e-9
    # Accelerating: the mean is not gravity, no factor.
    moving = ImuSeries(stamps, np.zeros((n, 3)), np.tile([5.0, 0.0, 9.8], (n, 1)), np.full((n, 4), np.nan), "imu")
    assert gravity_at_keyframes(moving, kfs, ext) == {}
    # A broken IMU driver stamping every sample alike: no factor (and no division by zero).
    same = ImuSeries(np.full(n, 1_000_000_000, np.int64), np.zeros((n, 3)), np.tile(tilt, (n, 1)),
                     np.full((n, 4), np.nan), "imu")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert gravity_at_keyframes(same, kfs, ext) == {}


def test_gravity_at_keyframes_takes_out_the_robots_own_acceleration() -> None:
    """Speeding up and turning: the IMU's mean specific force is not gravity; minus the
    acceleration the wheel odometry's twist gives (lever arm included) it is up, exactly."""
    n = 200
    stamps = np.arange(n, dtype=np.int64) * 10_000_000  # 100 Hz, 2 s
    t = stamps / 1e9
    lever = np.array([0.0, 0.05, 0.2])  # the IMU's place on the base
    ext = Extrinsics("base_link", {"imu": pose_xyyaw(*lever, 0.0)})
    kfs = [Keyframe(0, 1_000_000_000, 0, 0, np.eye(4), np.zeros((0, 3), np.float32), 1.0, 0.0)]
    # Speeding up at 0.3 m/s^2 while turning at 0.6 rad/s: v x w is centripetal, the lever arm
    # adds w x (w x r).
    v = np.column_stack([0.2 + 0.3 * t, np.zeros(n), np.zeros(n)])
    w = np.tile([0.0, 0.0, 0.6], (n, 1))
    accel = (np.array([0.3, 0.0, 0.0]) + np.cross(w, v) + np.cross(w, np.cross(w, np.tile(lever, (n, 1))))
             + [0.0, 0.0, 9.81])
    imu = ImuSeries(stamps, w, accel, np.full((n, 4), np.nan), "imu")
    odom = OdomSeries(stamps, np.zeros((n, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)), v, w, "odom", "base_link")
    raw = gravity_at_keyframes(imu, kfs, ext)[0]
    assert np.degrees(np.arccos(raw[2])) > 2.0  # the turn and the speeding up read as tilt
    up = gravity_at_keyframes(imu, kfs, ext, odom=odom)[0]
    assert np.degrees(np.arccos(min(up[2], 1.0))) < 1e-3
    # Where the odometry does not reach, no factor: the mean may hold the robot's acceleration.
    short = OdomSeries(stamps[:10], np.zeros((10, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (10, 1)), v[:10], w[:10])
    assert gravity_at_keyframes(imu, kfs, ext, odom=short) == {}


def test_gravity_at_keyframes_is_the_keyframes_own_tilt_while_the_robot_rocks() -> None:
    """Pitching 0.5 degrees back and forth once a second: the plain mean over +- 1 s is level, the
    samples turned into the keyframe's frame with the gyro give its tilt at that instant."""
    n = 301
    stamps = np.arange(n, dtype=np.int64) * 10_000_000  # 100 Hz, 3 s
    t = stamps / 1e9 - 1.5  # the keyframe at 1.5 s, at the largest pitch
    amplitude = np.radians(0.5)
    pitch = amplitude * np.cos(2.0 * np.pi * t)
    rate = np.column_stack([np.zeros(n), -amplitude * 2.0 * np.pi * np.sin(2.0 * np.pi * t), np.zeros(n)])
    force = 9.81 * np.column_stack([-np.sin(pitch), np.zeros(n), np.cos(pitch)])  # R_y(pitch)^T up
    imu = ImuSeries(stamps, rate, force, np.full((n, 4), np.nan), "imu")
    kfs = [Keyframe(0, 1_500_000_000, 0, 0, np.eye(4), np.zeros((0, 3), np.float32), 1.0, 0.0)]
    up = gravity_at_keyframes(imu, kfs, Extrinsics("base_link", {}), window_s=1.0)[0]
    truth = np.array([-np.sin(amplitude), 0.0, np.cos(amplitude)])
    assert np.degrees(np.arccos(min(float(up @ truth), 1.0))) < 0.01
    plain = force[50:251].mean(axis=0)  # what the window's samples average to, unturned
    assert np.degrees(np.arccos(plain[2] / np.linalg.norm(plain))) < 0.05  # level: 0.5 deg off


def test_single_floor_spans_the_log() -> None:
    seg = single_floor(5, 1_000)
    assert len(seg.floors) == 1 and seg.transitions == ()
    assert seg.floor_at(500) == 0 and seg.visits() == [(0, 5, 1_000)]


def _interpolated(p0: np.ndarray, p1: np.ndarray, frac: float) -> np.ndarray:
    """p0 moved by `frac` of the way to p1 (slerp of the relative rotation, linear translation)."""
    from scipy.spatial.transform import Rotation

    rel = np.linalg.inv(p0) @ p1
    step = np.eye(4)
    step[:3, :3] = Rotation.from_rotvec(frac * Rotation.from_matrix(rel[:3, :3]).as_rotvec()).as_matrix()
    step[:3, 3] = frac * rel[:3, 3]
    return p0 @ step


def test_deskew_puts_a_moving_sweep_back_on_the_wall() -> None:
    # 1 m/s forward and 0.5 rad/s of yaw, scans every 0.1 s; a wall 5 m ahead, x = 5.
    poses = np.stack([pose_xyyaw(0.1 * k, 0.0, 0.0, 0.05 * k) for k in range(3)])
    traj = FloorTrajectory(np.arange(3, dtype=np.int64) * 100_000_000, poses, np.zeros(3, np.int32))
    offsets = np.linspace(0, 99_000_000, 200).astype(np.int64)
    wall = np.column_stack([np.full(200, 5.0), np.linspace(-2.0, 2.0, 200), np.full(200, 1.0)])
    # What the lidar measures: each point in the base frame at its own firing time.
    measured = np.stack([
        (np.linalg.inv(_interpolated(poses[0], poses[1], t / 1e8)) @ np.append(w, 1.0))[:3]
        for w, t in zip(wall, offsets, strict=True)
    ])
    smeared = measured @ poses[0][:3, :3].T + poses[0][:3, 3]
    assert np.linalg.norm(smeared - wall, axis=1).max() > 0.2  # the smear the deskew removes
    fixed = _deskew(measured, offsets, traj, 0) @ poses[0][:3, :3].T + poses[0][:3, 3]
    assert np.abs(fixed - wall).max() < 1e-9
    # The last scan has no next one: the motion from the scan before carries on.
    measured_last = (wall - poses[2][:3, 3]) @ poses[2][:3, :3]
    assert np.allclose(_deskew(measured_last, np.zeros(200, np.int64), traj, 2), measured_last)
    # Across a gap (another floor, or a pause in the log) nothing is interpolated.
    split = FloorTrajectory(traj.stamps_ns, poses, np.array([0, 1, 2], np.int32))
    assert _deskew(measured, offsets, split, 0) is measured


def test_floor_groups_balance_scans() -> None:
    floors = np.array([0] * 50 + [1] * 30 + [2] * 25, dtype=np.int32)
    traj = FloorTrajectory(np.arange(105, dtype=np.int64), np.tile(np.eye(4), (105, 1, 1)), floors)
    used = {i: i for i in range(105)}
    assert _floor_groups(used, traj, 2) == [{1, 2}, {0}]
    assert _floor_groups(used, traj, 1) == [{0, 1, 2}]
    assert _floor_groups(used, traj, 8) == [{0}, {1}, {2}]


def test_ride_scans_sit_between_the_optimised_ride_ends() -> None:
    """Ride scans hang off the keyframe before the ride, 4 m below the cabin's end: with that
    keyframe pitched 1 deg they would swing 7 cm sideways; they go between the two ends."""
    from scipy.spatial.transform import Rotation

    from mfmap.export.write import optimised_trajectory
    from mfmap.types import MappingResult, ScanPose

    s = 1_000_000_000
    empty = np.zeros((0, 3), np.float32)
    kfs = [Keyframe(0, 0, 0, 0, np.eye(4), empty, 1.0, 0.0), Keyframe(1, 20 * s, 1, 1, np.eye(4), empty, 1.0, 0.0)]
    scan_poses = [ScanPose(k * s, 0, np.eye(4)) for k in range(5)]  # standing in the cabin
    ride_z = [0.0, 0.5, 2.0, 3.5, 4.0]
    scan_poses += [ScanPose((5 + k) * s, 0, pose_xyyaw(0.0, 0.0, z, 0.0)) for k, z in enumerate(ride_z)]
    scan_poses += [ScanPose((10 + k) * s, 1, np.eye(4)) for k in range(5)]
    mapping = MappingResult(kfs, [], scan_poses)
    pitched = np.eye(4)
    pitched[:3, :3] = Rotation.from_euler("y", 1.0, degrees=True).as_matrix()
    after = pose_xyyaw(0.02, -0.01, 4.01, np.radians(0.1))
    poses = {0: pitched, 1: after}

    plain = optimised_trajectory(mapping, poses)
    assert plain.poses[9, 0, 3] > 0.06  # 4 m * sin(1 deg)

    traj = optimised_trajectory(mapping, poses, [(5 * s, 9 * s)])
    ride = traj.poses[5:10]
    frac = (np.arange(5, 10) - 4) / 6.0  # time from the last scan before to the first after
    np.testing.assert_allclose(ride[:, 0, 3], 0.02 * frac, atol=1e-9)
    np.testing.assert_allclose(ride[:, 1, 3], -0.01 * frac, atol=1e-9)
    # z keeps the ride's own profile, scaled to land on the optimised end (4.01 m).
    np.testing.assert_allclose(ride[:, 2, 3], np.array(ride_z) * (4.01 / 4.0), atol=1e-3)
    np.testing.assert_array_equal(traj.poses[10:], plain.poses[10:])


def test_a_walks_end_jump_is_spread_over_the_walk() -> None:
    """Stair-walk scans hang off the keyframe before the walk; the graph moved the next floor's
    keyframe 0.3 deg and 3 cm against that chain: no jump is left at the walk's end."""
    from mfmap.export.write import optimised_trajectory
    from mfmap.types import MappingResult, ScanPose

    s = 1_000_000_000
    empty = np.zeros((0, 3), np.float32)
    kfs = [Keyframe(0, 0, 0, 0, np.eye(4), empty, 1.0, 0.0), Keyframe(1, 20 * s, 1, 1, np.eye(4), empty, 1.0, 0.0)]
    # Walking along x at 1 m/s, one scan a second; the walk is 5-14 s, the next floor from 15 s.
    scan_poses = [ScanPose(k * s, 0, pose_xyyaw(float(k), 0.0, 0.0, 0.0)) for k in range(15)]
    scan_poses += [ScanPose(k * s, 1, pose_xyyaw(float(k - 15), 0.0, 0.0, 0.0)) for k in range(15, 20)]
    mapping = MappingResult(kfs, [], scan_poses)
    moved = pose_xyyaw(15.0, 0.03, 0.0, np.radians(0.3))  # where the graph put floor 1's start
    poses = {0: np.eye(4), 1: moved}

    plain = optimised_trajectory(mapping, poses)
    traj = optimised_trajectory(mapping, poses, walks=[(5 * s, 14 * s)])

    def yaw_deg(p: np.ndarray) -> float:
        return float(np.degrees(np.arctan2(p[1, 0], p[0, 0])))

    np.testing.assert_array_equal(traj.poses[:5], plain.poses[:5])
    np.testing.assert_array_equal(traj.poses[15:], plain.poses[15:])
    assert abs(yaw_deg(plain.poses[15]) - yaw_deg(plain.poses[14])) > 0.29  # the jump
    # Now the last walk scan, one step on, lands on the next floor's first scan.
    step = pose_xyyaw(1.0, 0.0, 0.0, 0.0)
    np.testing.assert_allclose(traj.poses[14] @ step, traj.poses[15], atol=1e-9)
    yaws = [yaw_deg(p) for p in traj.poses[4:16]]
    assert all(b >= a - 1e-9 for a, b in itertools.pairwise(yaws))  # the turn grows over the walk
