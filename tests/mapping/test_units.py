"""Small exact checks of the mapping stage's geometry helpers."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from mfmap.mapping.cabin import through_box
from mfmap.mapping.config import LoopsConfig, MappingConfig
from mfmap.mapping.geometry import deskew, pull_tilt, rotations_to, yaw_pose
from mfmap.mapping.loops import LoopCloser, descriptor_distance, place_descriptor
from mfmap.mapping.odometry import AdaptiveThreshold, LocalMap, ScanMatcher
from mfmap.mapping.posegraph import optimize_poses
from mfmap.mapping.registration import Registration
from mfmap.mapping.wheelscale import WheelScale, rescale
from mfmap.types import PoseEdge


def test_through_box_drops_cabin_returns_and_what_is_behind_its_walls() -> None:
    cabin = yaw_pose(0.0, np.array([3.0, 0.0, 0.0]))
    points = np.array([
        [3.0, 0.0, 0.5],   # inside the cabin
        [5.0, 0.0, 0.5],   # behind it (a mirror ghost / too-long range)
        [1.0, 0.0, 0.5],   # in front of it
        [5.0, 3.0, 0.5],   # beside it, ray passes clear
        [3.0, 2.0, 0.5],   # beside it
    ])
    mask = through_box(points, np.zeros(3), cabin, (1.0, 1.0))
    assert mask.tolist() == [True, True, False, False, False]
    # From inside the cabin every ray starts in it.
    assert through_box(points, np.array([3.0, 0.0, 0.0]), cabin, (1.0, 1.0)).all()


def test_deskew_undoes_a_constant_turn() -> None:
    # A wall point seen at t = 0.1 s by a sensor turning at 1 rad/s: expressed at t = 0 it is
    # the same point rotated by 0.1 rad.
    point = np.array([[2.0, 0.0, 0.0]])
    out = deskew(point, np.array([0.1]), np.array([0.0, 0.0, 1.0]), np.zeros(3))
    assert out[0] == pytest.approx([2.0 * np.cos(0.1), 2.0 * np.sin(0.1), 0.0])


def test_pulling_a_registered_tilt_towards_the_gyros_keeps_position_and_heading() -> None:
    from scipy.spatial.transform import Rotation

    def pose(yaw: float, pitch: float, roll: float) -> np.ndarray:
        p = np.eye(4)
        p[:3, :3] = Rotation.from_euler("zyx", [yaw, pitch, roll], degrees=True).as_matrix()
        p[:3, 3] = [1.0, 2.0, 3.0]
        return p

    def up(p: np.ndarray) -> np.ndarray:
        return p[:3, :3].T[:, 2]

    registered, predicted = pose(31.0, 1.5, -0.3), pose(30.0, 0.5, 0.2)
    gap = np.degrees(np.arccos(up(registered) @ up(predicted)))
    for share in (0.0, 0.2, 1.0):
        held = pull_tilt(registered, predicted, share)
        # The tilt keeps `share` of its gap to the prediction's ...
        left = np.degrees(np.arccos(np.clip(up(held) @ up(predicted), -1.0, 1.0)))
        assert left == pytest.approx(share * gap, abs=1e-4)
        # ... the position and the registration's heading stay.
        assert np.array_equal(held[:3, 3], registered[:3, 3])
        heading = Rotation.from_matrix(held[:3, :3]).as_euler("zyx", degrees=True)[0]
        assert heading == pytest.approx(31.0, abs=0.01)


def test_deskew_with_the_gyro_follows_a_turn_that_speeds_up_within_the_sweep() -> None:
    """A robot tipping off a stair: its pitch rate grows from 0 to 1.2 rad/s over the 0.1 s
    sweep. A floor 0.5 m below and 2-8 m ahead, deskewed with the gyro's rotation per point,
    is where it was; with one rate for the sweep, even its mean, its ends are centimetres off."""
    from scipy.spatial.transform import Rotation

    from mfmap.mapping.geometry import deskew_measured

    accel = 12.0  # rad/s^2 of pitch
    t_offset = np.linspace(-0.05, 0.05, 400)
    ahead = np.linspace(2.0, 8.0, 400)
    floor = np.column_stack([ahead, np.zeros(400), np.full(400, -0.5)])  # in the base at t = 0

    def rotations(t: np.ndarray) -> np.ndarray:
        angle = 0.5 * accel * (t + 0.05) ** 2 - 0.5 * accel * 0.05**2  # 0 at the reference
        return np.asarray(Rotation.from_rotvec(np.outer(angle, [0.0, 1.0, 0.0])).as_matrix())

    measured = np.einsum("nji,nj->ni", rotations(t_offset), floor)  # seen in the base at t
    assert np.abs(measured[:, 2] + 0.5).max() > 0.05  # the smear
    fixed = deskew_measured(measured, t_offset, rotations, np.zeros(3))
    assert np.abs(fixed - floor).max() < 1e-9
    one_rate = deskew(measured, t_offset, np.array([0.0, accel * 0.05, 0.0]), np.zeros(3))
    assert np.abs(one_rate[:, 2] + 0.5).max() > 0.05


def test_descriptor_finds_the_yaw_between_two_views() -> None:
    rng = np.random.default_rng(0)
    cloud = np.c_[rng.uniform(-10, 10, (4000, 2)), rng.uniform(0.3, 2.0, 4000)]
    cloud = cloud[np.hypot(cloud[:, 0], cloud[:, 1]) > 2 + 3 * (cloud[:, 0] > 0)]
    yaw = np.radians(60.0)
    rotated = cloud @ yaw_pose(-yaw)[:3, :3].T  # the same place seen with the robot yawed by 60
    dist, shift = descriptor_distance(place_descriptor(cloud), place_descriptor(rotated))
    assert dist < 0.05
    assert shift * 6.0 == pytest.approx(60.0, abs=6.0)


def test_pose_graph_spreads_a_loop_correction() -> None:
    # Four 1 m steps along x whose odometry says 1.02 m; a loop from 0 to 4 says 4.00 m.
    poses = {k: yaw_pose(0.0, np.array([1.02 * k, 0.0, 0.0])) for k in range(5)}
    info = np.diag([1e4] * 3 + [1e4] * 3)
    edges = [PoseEdge(k, k + 1, yaw_pose(0.0, np.array([1.02, 0.0, 0.0])), info, "odometry")
             for k in range(4)]
    edges.append(PoseEdge(0, 4, yaw_pose(0.0, np.array([4.0, 0.0, 0.0])), info * 100, "loop"))
    out = optimize_poses(poses, edges, anchor=0)
    assert out[4][0, 3] == pytest.approx(4.0, abs=0.005)
    assert out[2][0, 3] == pytest.approx(2.0, abs=0.01)


def _descriptor_distance_by_shift(a: np.ndarray, b: np.ndarray) -> tuple[float, int]:
    """The definition, one yaw shift at a time (what the vectorised version must reproduce)."""
    best, best_shift = 2.0, 0
    norm_a = np.linalg.norm(a, axis=0)
    for shift in range(a.shape[1]):
        rolled = np.roll(b, shift, axis=1)
        norm_b = np.linalg.norm(rolled, axis=0)
        valid = (norm_a > 0) & (norm_b > 0)
        if valid.sum() < a.shape[1] // 4:
            continue
        cos = (a[:, valid] * rolled[:, valid]).sum(axis=0) / (norm_a[valid] * norm_b[valid])
        if 1.0 - float(cos.mean()) < best:
            best, best_shift = 1.0 - float(cos.mean()), shift
    return best, best_shift


def test_descriptor_distance_matches_the_per_shift_definition() -> None:
    rng = np.random.default_rng(1)
    for k in range(60):
        a = np.log1p(rng.poisson(1.0, (20, 60)) * (rng.random((20, 60)) < 0.3))
        b = np.roll(a, int(rng.integers(60)), axis=1) + 0.1 * rng.random((20, 60)) * (a > 0)
        if k % 3 == 0:  # an unrelated place
            b = np.log1p(rng.poisson(1.0, (20, 60)) * (rng.random((20, 60)) < 0.1))
        if k % 7 == 0:  # too few occupied sectors for most shifts
            a[:, :50] = 0.0
        dist, shift = descriptor_distance(a, b)
        want_dist, want_shift = _descriptor_distance_by_shift(a, b)
        assert shift == want_shift
        assert dist == pytest.approx(want_dist, abs=1e-12)


def _room(rng: np.random.Generator) -> np.ndarray:
    """Points on the walls and floor of an 8 m x 5 m room with a pillar, robot at the origin."""
    wall = []
    for x0, x1, y0, y1 in ((-4, 4, -2.5, -2.5), (-4, 4, 2.5, 2.5), (-4, -4, -2.5, 2.5),
                           (4, 4, -2.5, 2.5), (1.0, 1.4, 1.0, 1.0), (1.0, 1.0, 1.0, 1.4)):
        t = rng.uniform(0, 1, 1500)
        wall.append(np.c_[x0 + t * (x1 - x0), y0 + t * (y1 - y0), rng.uniform(-0.4, 1.5, 1500)])
    wall.append(np.c_[rng.uniform(-4, 4, 3000), rng.uniform(-2.5, 2.5, 3000), np.full(3000, -0.4)])
    return np.concatenate(wall)


def _room_matcher(room: np.ndarray, **kwargs: Any) -> ScanMatcher:
    """A scan matcher whose local map is `room` (0.1 m voxels)."""
    local_map = LocalMap(0.1, 10, 30.0)
    local_map.add(room, np.zeros(3))
    return ScanMatcher(0.1, local_map, AdaptiveThreshold(0.5, 0.0, 10.0, 0.3), 30, **kwargs)


def test_gyro_overrules_a_registration_that_turns_the_heading_away() -> None:
    rng = np.random.default_rng(0)
    room = _room(rng)
    predicted = yaw_pose(np.radians(1.0))  # the truth is identity: the prior is 1 degree off

    def matcher() -> ScanMatcher:
        return _room_matcher(room, max_gyro_disagreement_deg=0.2, max_overruled=2)

    free = matcher().match(room, predicted, gyro_prior=False)
    assert free.registered
    assert abs(np.degrees(np.arctan2(free.pose[1, 0], free.pose[0, 0]))) < 0.05
    gated = matcher()
    kept = [gated.match(room, predicted, gyro_prior=True) for _ in range(3)]
    assert [m.registered for m in kept] == [False, False, True]  # the 3rd in a row is taken
    # Overruled: the gyro's heading, the registration's position (here the truth, the origin).
    assert np.degrees(np.arctan2(kept[0].pose[1, 0], kept[0].pose[0, 0])) == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(kept[0].pose, predicted, atol=2e-3)
    assert gated.overruled == 2


def test_a_registration_far_off_the_motion_prior_is_not_taken() -> None:
    """The prior puts the scan 0.25 m off the room it sees (the truth is the origin): with a
    limit of 0.1 m the registration that moves it there is left out, up to max_overruled times
    in a row; without one it is taken; within the limit it is taken."""
    rng = np.random.default_rng(0)
    room = _room(rng)
    predicted = yaw_pose(0.0, np.array([0.25, 0.0, 0.0]))
    free = _room_matcher(room).match(room, predicted, max_jump_m=0.0)
    assert free.registered and np.linalg.norm(free.pose[:3, 3]) < 0.01
    gated = _room_matcher(room, max_overruled=2)
    kept = [gated.match(room, predicted, max_jump_m=0.1) for _ in range(3)]
    assert [m.registered for m in kept] == [False, False, True]  # the 3rd in a row is taken
    np.testing.assert_array_equal(kept[0].pose, predicted)
    assert np.linalg.norm(kept[2].pose[:3, 3]) < 0.01
    assert gated.jumps == 2
    near = _room_matcher(room).match(room, yaw_pose(0.0, np.array([0.05, 0.0, 0.0])), max_jump_m=0.1)
    assert near.registered and np.linalg.norm(near.pose[:3, 3]) < 0.01


def test_gyro_bias_follows_its_drift_between_stand_stills() -> None:
    """The bias wanders 1e-3 rad/s over 300 s: a 180 deg turn right after the second
    stand-still must use the bias measured there, not one averaged over the log."""
    from mfmap.mapping.geometry import GyroIntegrator
    from mfmap.types import ImuSeries, OdomSeries

    rng = np.random.default_rng(3)
    t = np.arange(0.0, 300.0, 0.005)
    still = ((t >= 20) & (t < 30)) | ((t >= 270) & (t < 280))
    turning = (t >= 281) & (t < 287)
    rate = np.where(turning, np.pi / 6.0, 0.0)  # 180 deg in 6 s
    bias_z = 1e-3 * t / 300.0
    gyro = rng.normal(0.0, 0.003, (len(t), 3))
    gyro[:, 2] += rate + bias_z
    stamps = (1_000_000_000 + np.round(t * 1e9)).astype(np.int64)
    imu = ImuSeries(stamps, gyro, np.tile([0.0, 0.0, 9.81], (len(t), 1)), np.full((len(t), 4), np.nan))
    k = slice(None, None, 4)  # odometry at 50 Hz
    speed = np.where(still, 0.0, 0.5)[k]
    odom = OdomSeries(stamps[k], np.zeros((len(speed), 3)), np.tile([0.0, 0.0, 0.0, 1.0], (len(speed), 1)),
                      np.column_stack([speed, np.zeros((len(speed), 2))]),
                      np.column_stack([np.zeros((len(speed), 2)), rate[k]]))
    gyro_int = GyroIntegrator(imu, np.eye(4), odom)
    at = int(np.searchsorted(t, 285.0))
    assert abs(gyro_int.bias_rad_s[at, 2] - bias_z[at]) < 1e-4
    turn = gyro_int.delta(int(stamps[0] + 280.5e9), int(stamps[0] + 288e9))
    yaw_deg = np.degrees(np.arctan2(turn[1, 0], turn[0, 0]))
    # A single bias over both stand-stills (5e-4 rad/s off here) would turn it 0.21 deg short.
    assert abs(abs(yaw_deg) - 180.0) < 0.05


def test_gyro_holds_the_heading_tighter_when_the_scan_sees_new_structure() -> None:
    """A 0.15 deg correction is within the 0.2 deg allowed for a scan that matches the map
    (fitness ~1), but over the 0.1 deg allowed for one that is a third new structure."""
    rng = np.random.default_rng(1)
    room = _room(rng)
    # A second room beyond the far wall, not in the map yet: about a third of the scan.
    beyond = room[(room[:, 0] > -4) & (room[:, 0] < 4)][::2] + np.array([8.0, 0.0, 0.0])
    predicted = yaw_pose(np.radians(0.15))

    def matcher() -> ScanMatcher:
        return _room_matcher(room, max_gyro_disagreement_deg=0.2, low_fitness=0.9)

    seen = matcher().match(room, predicted, gyro_prior=True)
    assert seen.fitness > 0.9 and seen.registered
    assert abs(np.degrees(np.arctan2(seen.pose[1, 0], seen.pose[0, 0]))) < 0.05
    new = matcher().match(np.vstack([room, beyond]), predicted, gyro_prior=True)
    assert new.fitness < 0.9 and not new.registered
    assert np.degrees(np.arctan2(new.pose[1, 0], new.pose[0, 0])) == pytest.approx(0.15, abs=1e-9)


def test_rescale_equals_the_chain_with_scaled_steps() -> None:
    rng = np.random.default_rng(4)
    start = yaw_pose(0.7, np.array([3.0, -2.0, 4.5]))
    steps = [yaw_pose(float(rng.uniform(-0.3, 0.3)), rng.uniform(-0.5, 0.5, 3)) for _ in range(12)]
    plain, scaled = start.copy(), start.copy()
    for step in steps:
        plain = plain @ step
        longer = step.copy()
        longer[:3, 3] *= 0.94
        scaled = scaled @ longer
    assert np.allclose(rescale(start, plain, 0.94), scaled, atol=1e-12)


def test_wheel_scale_is_the_least_squares_ratio_and_waits_for_travel() -> None:
    est = WheelScale(min_travel_m=5.0)
    for k in range(9):
        wheels = yaw_pose(0.0, np.array([0.6, 0.05 * k, 0.0]))
        lidar = yaw_pose(0.0, np.array([0.6 * 0.95, 0.05 * k * 0.95, 0.0]))
        est.add(lidar, wheels)
        assert (est.value is None) == (est.travel_m < 5.0)
    assert est.value == pytest.approx(0.95, abs=1e-12)
    est.add(yaw_pose(0.5), yaw_pose(0.5, np.array([0.1, 0.0, 0.0])))  # a turn on the spot: skipped
    assert est.value == pytest.approx(0.95, abs=1e-12)
    wrong = WheelScale(min_travel_m=1.0)
    wrong.add(yaw_pose(0.0, np.array([2.0, 0.0, 0.0])), yaw_pose(0.0, np.array([1.0, 0.0, 0.0])))
    assert wrong.value is None  # twice the wheels' distance: not a radius error


def test_loop_sigmas_grow_with_the_distance_between_its_keyframes() -> None:
    cfg = MappingConfig(loops=LoopsConfig(sigma_m=0.01, sigma_deg=0.3, sigma_growth_per_m=1.0))
    loops = LoopCloser(cfg)
    near = loops._edge(0, 20, Registration(np.eye(4), 0.9, 0.01))
    far = loops._edge(0, 20, Registration(yaw_pose(0.1, np.array([3.0, 0.0, 0.0])), 0.6, 0.03))
    assert near.information[3, 3] == pytest.approx(0.01**-2)
    assert near.information[2, 2] == pytest.approx(np.radians(0.3) ** -2)
    # 3 m apart: every sigma four times as large.
    assert np.allclose(np.diag(far.information), np.diag(near.information) / 16.0)
    flat = LoopCloser(MappingConfig(loops=LoopsConfig(sigma_growth_per_m=0.0)))
    assert flat._edge(0, 20, Registration(yaw_pose(0.1, np.array([3.0, 0.0, 0.0])), 0.6, 0.03)
                      ).information[3, 3] == pytest.approx(cfg.loops.sigma_m**-2)


def test_a_low_overlap_heading_is_blended_with_the_gyro_by_their_variances() -> None:
    """Below the low-fitness mark the registered heading moves towards the prediction by the
    Kalman gain of the two variances; at full overlap the registration stands."""
    sigma_deg, gyro_var = 0.035, np.radians(0.01) ** 2
    matcher = ScanMatcher(0.25, LocalMap(0.15, 30, 30.0), AdaptiveThreshold(1.0, 0.0, 40.0, 0.4), 30,
                          low_fitness=0.95, heading_sigma_deg=sigma_deg)
    predicted = np.eye(4)
    registered = yaw_pose(np.radians(0.1), np.array([0.3, -0.2, 0.0]))

    def blend(fitness: float) -> float:
        pose = matcher._blend_heading(Registration(registered, fitness, 0.01), predicted, True, gyro_var)
        np.testing.assert_allclose(pose[:3, 3], registered[:3, 3])  # the position stands
        return float(np.degrees(np.arctan2(pose[1, 0], pose[0, 0])))

    assert blend(0.98) == pytest.approx(0.1, abs=1e-12)  # full overlap: the registration
    held_var = np.radians(sigma_deg / 0.98) ** 2
    # A third of the scan new: the gain of the prediction's variance (the last heading's plus
    # the gyro's) against the registration's, which grows as 1 / fitness.
    measured_var = np.radians(sigma_deg / 0.7) ** 2
    gain = (held_var + gyro_var) / (held_var + gyro_var + measured_var)
    assert blend(0.7) == pytest.approx(0.1 * gain, abs=1e-9)
    assert 0.3 < gain < 0.4
    assert matcher.blended == 1
    # The blended heading's variance is smaller than either: the next low-overlap scan trusts
    # the prediction more.
    second_gain = (gain * measured_var + gyro_var) / (gain * measured_var + gyro_var + measured_var)
    assert blend(0.7) == pytest.approx(0.1 * second_gain, abs=1e-9)
    assert second_gain < gain
    # Off: the registration as it is.
    off = ScanMatcher(0.25, LocalMap(0.15, 30, 30.0), AdaptiveThreshold(1.0, 0.0, 40.0, 0.4), 30,
                      low_fitness=0.95, heading_sigma_deg=0.0)
    off._heading_var = 1e-9
    np.testing.assert_array_equal(off._blend_heading(Registration(registered, 0.7, 0.01), predicted, True,
                                                     gyro_var), registered)


def test_the_gyros_angle_random_walk_is_measured_at_the_stand_stills() -> None:
    """White rate noise of 0.003 rad/s at 200 Hz is 0.012 deg/sqrt(s) of heading random walk."""
    from mfmap.mapping.geometry import DEFAULT_HEADING_NOISE_RAD_SQRT_S, heading_noise, still_mask
    from mfmap.types import OdomSeries

    rng = np.random.default_rng(5)
    t = np.arange(0.0, 120.0, 0.005)
    still = (t >= 20) & (t < 50)
    rate = rng.normal(0.0, 0.003, len(t)) + np.where(still, 0.0, 0.3)  # turning when not still
    stamps = (np.round(t * 1e9)).astype(np.int64)
    k = slice(None, None, 4)
    speed = np.where(still, 0.0, 0.5)[k]
    odom = OdomSeries(stamps[k], np.zeros((len(speed), 3)), np.tile([0.0, 0.0, 0.0, 1.0], (len(speed), 1)),
                      np.column_stack([speed, np.zeros((len(speed), 2))]), np.zeros((len(speed), 3)))
    arw = heading_noise(stamps, rate, still_mask(stamps, odom))
    assert np.degrees(arw) == pytest.approx(np.degrees(0.003 * np.sqrt(0.005)), rel=0.05)
    # No stand-still in the log: a consumer MEMS gyro's figure.
    assert heading_noise(stamps, rate, still_mask(stamps, None)) == DEFAULT_HEADING_NOISE_RAD_SQRT_S


def test_rotations_to_a_reference_instant_from_the_gyro() -> None:
    """A turn at a constant rate about a tilted axis, sampled unevenly: each sample's frame in
    the frame at a reference instant between two samples is exp(w (t_i - t_ref))."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(3)
    stamps = np.cumsum(rng.integers(4_000_000, 6_000_000, size=301)).astype(np.int64)
    rate = np.array([0.05, -0.02, 0.6])
    ref_ns = int(stamps[137]) + 1_700_000
    got = rotations_to(stamps, np.tile(rate, (len(stamps), 1)), ref_ns)
    want = Rotation.from_rotvec(((stamps - ref_ns) / 1e9)[:, None] * rate).as_matrix()
    assert got.shape == (301, 3, 3)
    assert np.abs(got - want).max() < 1e-12
    back_s = (ref_ns - int(stamps[0])) / 1e9
    assert np.arccos((np.trace(got[0]) - 1) / 2) == pytest.approx(np.linalg.norm(rate) * back_s, abs=1e-9)


def test_rotations_to_chains_the_steps_in_order() -> None:
    """Changing rates (steps that do not commute): the prefix product equals the steps chained
    one by one, each taken at the mean of its two samples' rates."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(5)
    stamps = np.arange(0, 200 * 5_000_000, 5_000_000, dtype=np.int64)
    rate = rng.normal(0.0, 2.0, size=(200, 3))
    got = rotations_to(stamps, rate, int(stamps[0]))
    current = np.eye(3)
    for i in range(1, 200):
        current = current @ Rotation.from_rotvec(0.5 * (rate[i] + rate[i - 1]) * 0.005).as_matrix()
        assert np.abs(got[i] - current).max() < 1e-12


def test_a_stair_walks_path_is_the_way_walked_not_the_line_between_its_ends() -> None:
    """A switch-back walk: up a 4 m flight, across a 1 m landing, back down the lane beside it;
    2 m from end to end, 9 m walked. Scans of an earlier walk or another keyframe do not count."""
    from mfmap.mapping.transitions import walk_path_m
    from mfmap.types import Keyframe, ScanPose

    def pose(x: float, y: float, z: float) -> np.ndarray:
        out = np.eye(4)
        out[:3, 3] = [x, y, z]
        return out

    before = Keyframe(7, 100, 0, 0, pose(1.0, 0.0, 0.0), np.zeros((0, 3), np.float32), 1.0, 0.0)
    after = Keyframe(8, 200, 1, 1, pose(1.0, 1.0, 3.0), np.zeros((0, 3), np.float32), 1.0, 0.0)
    way = [(5.0, 0.0, 1.5), (5.0, 1.0, 1.5)]
    scans = [ScanPose(90, 6, pose(-9.0, 0.0, 0.0)), ScanPose(100, 7, pose(0.0, 0.0, 0.0))]
    scans += [ScanPose(120 + 10 * i, 7, pose(x - 1.0, y, z)) for i, (x, y, z) in enumerate(way)]
    assert walk_path_m(before, after, scans) == pytest.approx(2 * np.hypot(4.0, 1.5) + 1.0)
    assert walk_path_m(before, after, scans[:2]) == pytest.approx(np.hypot(1.0, 3.0))


def test_a_base_stands_level_only_a_second_away_from_any_tip() -> None:
    """Level for 10 s, then tipped 22 deg onto a flight within 0.4 s (with the accelerometer's
    noise and a 0.3 m/s^2 braking): level until a second before the tip starts, not within a
    second of it, nor on the flight; never without an accelerometer or with the limit at 0."""
    from mfmap.mapping.config import MotionPrior
    from mfmap.mapping.motion import MotionModel
    from mfmap.types import ImuSeries

    rng = np.random.default_rng(4)
    t = np.arange(0.0, 20.0, 0.005)
    pitch = np.radians(22.0) * np.clip((t - 10.0) / 0.4, 0.0, 1.0)
    accel = np.column_stack([-9.81 * np.sin(pitch), np.zeros(len(t)), 9.81 * np.cos(pitch)])
    accel[(t > 3.0) & (t < 4.0), 0] -= 0.3
    accel += rng.normal(0.0, 0.03, accel.shape)
    stamps = (1_000_000_000 + np.round(t * 1e9)).astype(np.int64)
    imu = ImuSeries(stamps, np.zeros((len(t), 3)), accel, np.full((len(t), 4), np.nan))
    motion = MotionModel(MotionPrior.AUTO, None, imu, {})

    def level(at_s: float, max_deg: float = 4.0) -> bool:
        return motion.stands_level(int(stamps[0] + at_s * 1e9), 1_000_000_000, max_deg)

    assert level(3.5) and level(8.9)
    assert not level(9.2) and not level(10.2) and not level(15.0)
    assert not level(5.0, max_deg=0.0)
    assert not MotionModel(MotionPrior.AUTO, None, None, {}).stands_level(int(stamps[0] + 5e9),
                                                                       1_000_000_000, 4.0)
