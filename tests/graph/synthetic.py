"""A small synthetic building as the mapping stage would hand it on, with its ground truth.

Used by the graph and export tests to exercise the building graph without running
the lidar pipeline: walls per floor (outer walls and an elevator shaft shared by every floor, one
interior wall that differs per floor), a route with elevator rides, keyframe clouds ray-cast
against the walls (so occlusion is real), noisy drifting odometry between keyframes, loop edges
on revisits, and a barometer trace with noise and weather drift.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from mfmap.types import (
    F64,
    EdgeKind,
    Floor,
    FloorSegmentation,
    ImuSeries,
    Keyframe,
    PoseEdge,
    PressureSeries,
    ScanPose,
    Transition,
    TransitionKind,
)

# The test world's air: an isothermal atmosphere, p = p0 exp(-z g / (R T)), not the estimator's
# hypsometric relation with a lapse rate (mfmap.baro), so the two do not share a model.
GAS_CONSTANT_DRY_AIR = 287.05  # J / (kg K)
GRAVITY_M_S2 = 9.80665

START_NS = 1_700_000_000 * 10**9
SHARED_WALLS = np.array(
    [
        [0, 0, 20, 0], [20, 0, 20, 12], [20, 12, 0, 12], [0, 12, 0, 0],  # outer walls
        [16, 8, 18, 8], [18, 8, 18, 10], [18, 10, 16, 10],  # elevator shaft, door on x = 16
        [16, 10, 16, 9.6], [16, 8.4, 16, 8],
        [4, 9, 4.4, 9], [4.4, 9, 4.4, 9.4], [4.4, 9.4, 4, 9.4], [4, 9.4, 4, 9],  # a pillar
    ],
    dtype=np.float64,
)
INTERIOR_WALLS = [
    np.array([[8, 0, 8, 5.5], [8, 6.5, 8, 7.5]], dtype=np.float64),
    np.array([[0, 6, 3, 6], [9, 6, 12, 6]], dtype=np.float64),
    np.array([[12, 12, 12, 5.5], [12, 4.5, 12, 3]], dtype=np.float64),
]
CABIN_XY = (17.0, 9.0)
# One tour of a floor: waypoints (x, y), walked at WALK_M_S, keyframes every KEYFRAME_STEP_M.
TOUR = [(14.5, 9.0), (14.5, 3.0), (3.0, 3.0), (3.0, 10.5), (10.0, 10.5), (14.5, 9.0)]
WALK_M_S = 0.5
KEYFRAME_STEP_M = 1.0
RIDE_S = 15.0


@dataclass
class SyntheticBuilding:
    keyframes: list[Keyframe]  # initial (drifted) poses, as the mapping stage would give them
    edges: list[PoseEdge]
    scan_poses: list[ScanPose]
    segmentation: FloorSegmentation
    pressure: PressureSeries
    gt_poses: dict[int, F64]
    walls: dict[int, F64]  # floor id -> (S, 4) wall segments x0 y0 x1 y1
    floor_height_m: float
    wall_height_m: float


def walls_of_floor(floor: int) -> F64:
    return np.concatenate([SHARED_WALLS, INTERIOR_WALLS[floor % len(INTERIOR_WALLS)]])


def pose_xyyaw(x: float, y: float, z: float, yaw: float) -> F64:
    out = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    out[:2, :2] = [[c, -s], [s, c]]
    out[:3, 3] = (x, y, z)
    return out


def raycast(origin_xy: F64, walls: F64, n_rays: int = 720, max_range_m: float = 15.0) -> F64:
    """Hit points (M, 2) of rays from origin against wall segments (nearest hit per ray)."""
    angles = np.linspace(0.0, 2.0 * np.pi, n_rays, endpoint=False)
    d = np.stack([np.cos(angles), np.sin(angles)], axis=1)  # (R, 2)
    p0 = walls[:, :2]
    e = walls[:, 2:] - walls[:, :2]  # (S, 2)
    w = p0 - origin_xy  # (S, 2)
    denom = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]  # (R, S)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[None, :, 0] * e[None, :, 1] - w[None, :, 1] * e[None, :, 0]) / denom
        u = (w[None, :, 0] * d[:, None, 1] - w[None, :, 1] * d[:, None, 0]) / denom
    valid = (np.abs(denom) > 1e-12) & (t > 1e-6) & (u >= 0.0) & (u <= 1.0)
    t = np.where(valid, t, np.inf)
    best = t.min(axis=1)
    ok = best < max_range_m
    return np.asarray(origin_xy + d[ok] * best[ok, None])


def keyframe_cloud(
    pose: F64, walls: F64, rng: np.random.Generator, wall_height_m: float, noise_m: float = 0.005
) -> np.ndarray:
    """Ray-cast wall points at several heights, in the base frame (base on the floor)."""
    hits = raycast(pose[:2, 3], walls)
    heights = np.arange(0.05, wall_height_m, 0.15)
    xy = np.repeat(hits, len(heights), axis=0)
    z = np.tile(heights, len(hits)) + pose[2, 3]
    world = np.column_stack([xy, z])
    world += rng.normal(0.0, noise_m, world.shape)
    base = (world - pose[:3, 3]) @ pose[:3, :3]
    return base.astype(np.float32)


def _tour_poses(start_xy: tuple[float, float]) -> list[tuple[float, float, float]]:
    """(x, y, yaw) every KEYFRAME_STEP_M along the tour from the cabin, back to the cabin."""
    points = [start_xy, *TOUR, start_xy]
    out: list[tuple[float, float, float]] = []
    for (x0, y0), (x1, y1) in itertools.pairwise(points):
        length = math.hypot(x1 - x0, y1 - y0)
        yaw = math.atan2(y1 - y0, x1 - x0)
        n = max(round(length / KEYFRAME_STEP_M), 1)
        for k in range(n):
            f = k / n
            out.append((x0 + f * (x1 - x0), y0 + f * (y1 - y0), yaw))
    out.append((start_xy[0], start_xy[1], math.pi))
    return out


def _perturb(rng: np.random.Generator, sigma_t: float, sigma_r: float, yaw_bias: float) -> F64:
    rx, ry = rng.normal(0.0, sigma_r, 2)
    rz = rng.normal(yaw_bias, sigma_r)
    out = pose_xyyaw(0.0, 0.0, 0.0, rz)
    cx, sx, cy, sy = math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry)
    rot_x = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    rot_y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    out[:3, :3] = out[:3, :3] @ rot_y @ rot_x
    out[:3, 3] = rng.normal(0.0, sigma_t, 3)
    return out


def make_building(
    floor_sequence: tuple[int, ...] = (0, 1),
    seed: int = 0,
    floor_height_m: float = 4.0,
    wall_height_m: float = 2.8,
    temperature_k: float = 295.0,
    odom_sigma_m: float = 0.01,
    odom_sigma_rad: float = 0.002,
    yaw_bias_rad: float = 0.0005,
    ride_yaw_error_rad: float = math.radians(1.5),
    ride_xy_error_m: float = 0.15,
    ride_z_error_m: float = 0.3,
    baro_noise_pa: float = 1.5,
    weather_drift_pa_per_h: float = 50.0,
) -> SyntheticBuilding:
    """A route visiting floors in `floor_sequence` (elevator rides between them)."""
    rng = np.random.default_rng(seed)
    keyframes: list[Keyframe] = []
    gt: dict[int, F64] = {}
    edges: list[PoseEdge] = []
    scan_poses: list[ScanPose] = []
    transitions: list[Transition] = []
    visits: dict[int, list[tuple[int, int]]] = {}
    t_s = 0.0
    profile: list[tuple[float, float]] = []  # (t_s, z_gt)
    start_floor = floor_sequence[0]
    info = np.diag(1.0 / np.array([odom_sigma_rad] * 3 + [odom_sigma_m] * 3) ** 2)
    prev_init: F64 | None = None
    for visit, floor in enumerate(floor_sequence):
        z_gt = (floor - start_floor) * floor_height_m
        walls = walls_of_floor(floor)
        tour = _tour_poses(CABIN_XY)
        visit_start_s = t_s
        first_in_visit = True
        prev_xy = None
        for x, y, yaw in tour:
            if prev_xy is not None:
                t_s += math.hypot(x - prev_xy[0], y - prev_xy[1]) / WALK_M_S + 1.0
            prev_xy = (x, y)
            kid = len(keyframes)
            pose_gt = pose_xyyaw(x, y, z_gt, yaw)
            gt[kid] = pose_gt
            if prev_init is None:
                init = pose_gt.copy()
            elif first_in_visit:
                # Across a ride the mapping stage holds x, y, yaw; its hold is imperfect.
                last = keyframes[-1].pose
                ex, ey = rng.normal(0.0, ride_xy_error_m, 2)
                err = pose_xyyaw(float(ex), float(ey), 0.0, ride_yaw_error_rad)
                init = last @ np.linalg.inv(gt[kid - 1]) @ pose_gt @ err
                init[2, 3] = last[2, 3] + (z_gt - gt[kid - 1][2, 3]) + ride_z_error_m
            else:
                true_rel = np.linalg.inv(gt[kid - 1]) @ pose_gt
                measured = true_rel @ _perturb(rng, odom_sigma_m, odom_sigma_rad, yaw_bias_rad)
                edges.append(PoseEdge(kid - 1, kid, measured, info, EdgeKind.ODOMETRY))
                init = keyframes[-1].pose @ measured
            stamp_ns = START_NS + int(t_s * 1e9)
            cloud = keyframe_cloud(pose_gt, walls, rng, wall_height_m)
            keyframes.append(Keyframe(kid, stamp_ns, floor, visit, init, cloud, 0.9, 0.01))
            for k in range(3):
                rel = pose_xyyaw(0.3 * k, 0.0, 0.0, 0.0)
                scan_poses.append(ScanPose(stamp_ns + k * 200_000_000, kid, rel))
            profile.append((t_s, z_gt))
            prev_init = init
            first_in_visit = False
        visits.setdefault(floor, []).append(
            (START_NS + int(visit_start_s * 1e9), START_NS + int(t_s * 1e9))
        )
        if visit + 1 < len(floor_sequence):
            nxt = floor_sequence[visit + 1]
            ride_start = t_s + 1.0
            ride_end = ride_start + RIDE_S
            transitions.append(
                Transition(
                    TransitionKind.ELEVATOR,
                    floor,
                    nxt,
                    START_NS + int(ride_start * 1e9),
                    START_NS + int(ride_end * 1e9),
                    (nxt - floor) * floor_height_m,
                )
            )
            profile.append((ride_start, z_gt))
            profile.append((ride_end, (nxt - start_floor) * floor_height_m))
            t_s = ride_end + 1.0
    # Loop edges: returns near an earlier keyframe of the same floor (30 s or more before).
    loop_info = np.diag(1.0 / np.array([0.001] * 3 + [0.005] * 3) ** 2)
    for b in keyframes:
        for a in keyframes:
            if a.floor_id != b.floor_id or b.stamp_ns - a.stamp_ns < 30 * 10**9:
                continue
            if np.linalg.norm(gt[a.id][:2, 3] - gt[b.id][:2, 3]) < 0.6:
                rel = np.linalg.inv(gt[a.id]) @ gt[b.id] @ _perturb(rng, 0.005, 0.001, 0.0)
                edges.append(PoseEdge(a.id, b.id, rel, loop_info, EdgeKind.LOOP))
                break
    # Barometer at 10 Hz.
    prof_t = np.array([p[0] for p in profile])
    prof_z = np.array([p[1] for p in profile])
    t_grid = np.arange(0.0, t_s + 2.0, 0.1)
    z_t = np.interp(t_grid, prof_t, prof_z)
    scale_m = GAS_CONSTANT_DRY_AIR * temperature_k / GRAVITY_M_S2
    p0 = 101_325.0 - 400.0 * start_floor
    pressure = p0 * np.exp(-z_t / scale_m) + weather_drift_pa_per_h * t_grid / 3600.0
    pressure += rng.normal(0.0, baro_noise_pa, pressure.shape)
    stamps = START_NS + (t_grid * 1e9).astype(np.int64)
    series = PressureSeries(stamps, pressure, "baro")
    height = scale_m * np.log(pressure[0] / pressure)
    floor_ids = sorted(set(floor_sequence))
    floors = tuple(
        Floor(f, (f - start_floor) * floor_height_m, float(p0 * math.exp(-(f - start_floor) * floor_height_m / scale_m)),
              tuple(visits[f]))
        for f in floor_ids
    )
    floor_of_sample = np.full(len(stamps), -1, dtype=np.int32)
    for f, spans in visits.items():
        for s, e in spans:
            floor_of_sample[(stamps >= s) & (stamps <= e)] = f
    seg = FloorSegmentation(floors, tuple(transitions), stamps, height, height, floor_of_sample)
    return SyntheticBuilding(
        keyframes=keyframes,
        edges=edges,
        scan_poses=scan_poses,
        segmentation=seg,
        pressure=series,
        gt_poses=gt,
        walls={f: walls_of_floor(f) for f in floor_ids},
        floor_height_m=floor_height_m,
        wall_height_m=wall_height_m,
    )


def ride_imu(
    rides: list[tuple[int, int, float]],
    seed: int = 0,
    accel_bias_m_s2: tuple[float, float, float] = (0.05, -0.03, 0.05),
    noise_m_s2: float = 0.03,
    tilt_deg: float = 2.0,
    cabin_acc_m_s2: float = 0.5,
    cabin_speed_m_s: float = 1.0,
    margin_s: float = 6.0,
) -> ImuSeries:
    """A 200 Hz IMU standing still in a cabin around each ride (start_ns, end_ns, height change).

    The cabin's trapezoidal move is centred in [start_ns, end_ns]; the IMU is mounted tilted by
    `tilt_deg` (so up is not its z) with a constant accelerometer bias and white noise. Samples
    cover each ride +- margin_s only.
    """
    rng = np.random.default_rng([seed, 29])
    tilt = math.radians(tilt_deg)
    # World -> IMU: a tilt about the IMU's x axis.
    rot = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(tilt), math.sin(tilt)], [0.0, -math.sin(tilt), math.cos(tilt)]])
    dt_s = 1.0 / 200.0
    stamps: list[np.ndarray] = []
    accel: list[np.ndarray] = []
    for start_ns, end_ns, dz_m in rides:
        t = np.arange(-margin_s, (end_ns - start_ns) / 1e9 + margin_s, dt_s)
        acc_s = min(cabin_speed_m_s / cabin_acc_m_s2, math.sqrt(abs(dz_m) / cabin_acc_m_s2))
        cruise_s = max(abs(dz_m) / (cabin_acc_m_s2 * max(acc_s, 1e-9)) - acc_s, 0.0)
        move_s = 2 * acc_s + cruise_s
        t_move = (end_ns - start_ns) / 1e9 / 2 - move_s / 2
        tau = t - t_move
        a_up = np.where((tau >= 0) & (tau < acc_s), cabin_acc_m_s2, 0.0)
        a_up = a_up - np.where((tau >= acc_s + cruise_s) & (tau < move_s), cabin_acc_m_s2, 0.0)
        a_up *= math.copysign(1.0, dz_m)
        f_world = np.zeros((len(t), 3))
        f_world[:, 2] = GRAVITY_M_S2 + a_up
        f_imu = f_world @ rot.T + np.asarray(accel_bias_m_s2) + rng.normal(0.0, noise_m_s2, (len(t), 3))
        stamps.append(start_ns + (t * 1e9).astype(np.int64))
        accel.append(f_imu)
    n = sum(len(s) for s in stamps)
    return ImuSeries(
        np.concatenate(stamps),
        rng.normal(0.0, 0.003, (n, 3)),
        np.concatenate(accel),
        np.full((n, 4), np.nan),
        "imu",
    )
