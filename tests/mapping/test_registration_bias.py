"""Scan-to-map registration against a perfect map: the fine kernel takes out ICP's pull.

The local map is built from ground-truth keyframe poses and every third scan of a floor visit
is registered from its true pose, as the odometry registers it. Whatever the registration moves
it by is its own error. With only the wide kernel that the correspondence threshold sets (13 cm
and more), points near corners and at the edges of what the map has seen pull each registration
about a millimetre back along the way the robot drives; over a keyframe a metre that left the
maps 0.05-0.2 % short. The refinement at the lidar's noise (`icp_fine_kernel_m`) takes the
pull and most of the scatter out.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from mfmap.eval.odometry import read_tum
from mfmap.ingest import open_log
from mfmap.mapping.config import MappingConfig
from mfmap.mapping.geometry import (
    PoseInterpolator,
    deskew,
    inverse,
    rotation_angle_rad,
    transform,
    twist,
    yaw_pose,
)
from mfmap.mapping.loops import LoopCloser
from mfmap.mapping.odometry import AdaptiveThreshold, LocalMap, ScanMatcher
from mfmap.mapping.registration import downsample
from mfmap.types import Cloud, FloorSegmentation, Keyframe

SegFn = Callable[[Path], FloorSegmentation]


def _truth(folder: Path) -> PoseInterpolator:
    stamps, poses = read_tum(folder / "gt_trajectory.tum")
    return PoseInterpolator(stamps, poses[:, :3, 3], Rotation.from_matrix(poses[:, :3, :3]).as_quat())


def _scan(cloud: Cloud, sensor_to_base: np.ndarray, truth: PoseInterpolator,
          cfg: MappingConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A scan as the odometry registers it (base frame, deskewed with the true motion to
    mid-sweep), its true pose there and the base's true velocity."""
    assert cloud.t_offset_ns is not None
    offsets = cloud.t_offset_ns.astype(np.float64) / 1e9
    mid = 0.5 * (offsets.min() + offsets.max())
    ref_ns = cloud.stamp_ns + round(mid * 1e9)
    angular, linear = twist(inverse(truth.at(ref_ns - 50_000_000)) @ truth.at(ref_ns + 50_000_000), 0.1)
    rng = np.linalg.norm(cloud.xyz, axis=1)
    keep = (rng > cfg.min_range_m) & (rng < cfg.max_range_m)
    points = deskew(transform(cloud.xyz[keep], sensor_to_base), offsets[keep] - mid, angular, linear)
    return points, truth.at(ref_ns), linear


def _along_track_errors(folder: Path, seg: FloorSegmentation, visit: int, fine_kernel_m: float,
                        count: int) -> np.ndarray:
    """(along, lateral) error in m of `count` registrations of a moving robot, from the truth."""
    cfg = MappingConfig()
    _, start_ns, end_ns = seg.visits()[visit]
    truth = _truth(folder)
    local_map = LocalMap(cfg.local_map.voxel_size_m, cfg.local_map.keyframes, cfg.local_map.radius_m)
    matcher = ScanMatcher(cfg.voxel_size_m, local_map,
                          AdaptiveThreshold(cfg.icp.initial_threshold_m, 0.0, cfg.max_range_m,
                                            cfg.icp.min_threshold_m),
                          cfg.icp.max_iterations, tolerance=cfg.icp.tolerance,
                          fine_kernel_m=fine_kernel_m)
    errors: list[tuple[float, float]] = []
    last_keyframe: np.ndarray | None = None
    with open_log(folder / "log.mcap") as src:
        sensor_to_base = src.extrinsics().get("lidar")
        assert sensor_to_base is not None
        for index, cloud in enumerate(src.clouds(start_ns, end_ns)):
            if index % cfg.scan_stride or cloud.t_offset_ns is None:
                continue
            points, pose, linear = _scan(cloud, sensor_to_base, truth, cfg)
            speed = float(np.linalg.norm(linear))
            if local_map.target is not None and speed > 0.2:
                match = matcher.match(points, pose)
                ahead = pose[:3, :3] @ (linear / speed)
                left = np.cross([0.0, 0.0, 1.0], ahead)
                shift = match.pose[:3, 3] - pose[:3, 3]
                errors.append((float(shift @ ahead), float(shift @ left)))
                if len(errors) == count:
                    break
            if last_keyframe is None or np.linalg.norm(pose[:3, 3] - last_keyframe) >= cfg.keyframes.distance_m:
                matcher.add_keyframe(points, pose)
                last_keyframe = pose[:3, 3]
    assert len(errors) == count
    return np.array(errors)


def test_the_fine_kernel_takes_the_pull_out_of_registration(sim_run: Callable[..., Path],
                                                             gt_floors: SegFn) -> None:
    """The first visit of three-floor-revisit (the later ones start in the elevator's cabin)."""
    folder = sim_run("three-floor-revisit")
    seg = gt_floors(folder)
    wide = _along_track_errors(folder, seg, 0, 0.0, 150)
    fine = _along_track_errors(folder, seg, 0, MappingConfig().icp.fine_kernel_m, 150)
    # Measured: wide -1.20 mm along (sd 3.18 mm), fine -0.36 mm (sd 1.94 mm); RMS over along
    # and lateral 3.11 and 2.09 mm.
    assert wide[:, 0].mean() < -0.0009
    assert abs(fine[:, 0].mean()) < 0.0006
    assert fine[:, 0].std() < 0.7 * wide[:, 0].std()
    assert np.sqrt(np.mean(fine ** 2)) < 0.0025


def test_loops_far_apart_are_verified_to_the_lidars_noise(sim_run: Callable[..., Path],
                                                          gt_floors: SegFn) -> None:
    """Loop candidates 2.5-4 m apart, verified from a start 10 cm and 1 degree off the truth
    against a submap of true poses."""
    folder = sim_run("two-floor")
    seg = gt_floors(folder)
    _, start_ns, end_ns = seg.visits()[0]
    truth = _truth(folder)
    cfg = MappingConfig()
    clouds: list[tuple[np.ndarray, np.ndarray]] = []
    with open_log(folder / "log.mcap") as src:
        sensor_to_base = src.extrinsics().get("lidar")
        assert sensor_to_base is not None
        for index, cloud in enumerate(src.clouds(start_ns, end_ns)):
            if index % 10 == 0:  # one a second
                points, pose, _ = _scan(cloud, sensor_to_base, truth, cfg)
                clouds.append((downsample(points, cfg.keyframes.voxel_size_m), pose))
    def submap(a: int) -> np.ndarray:  # the keyframe and two neighbours each side, in its frame
        return np.concatenate([transform(clouds[k][0], inverse(clouds[a][1]) @ clouds[k][1])
                               for k in range(a - 2, a + 3)])

    pairs = [(a, b) for a in range(2, len(clouds) - 2) for b in range(a + 1, min(a + 8, len(clouds)))
             if 2.5 < np.linalg.norm(clouds[a][1][:2, 3] - clouds[b][1][:2, 3]) < 4.0][::4][:20]
    assert len(pairs) == 20
    errors = {}
    for kernel in (0.0, cfg.icp.fine_kernel_m):
        closer = LoopCloser(cfg.model_copy(update={"icp": cfg.icp.model_copy(update={"fine_kernel_m": kernel})}))
        off = []
        for a, b in pairs:
            true_rel = inverse(clouds[a][1]) @ clouds[b][1]
            check = closer.verify(submap(a), clouds[b][0],
                                  true_rel @ yaw_pose(np.radians(1.0), np.array([0.1, -0.05, 0.0])))
            assert check.registration is not None, check.reason
            off.append(np.linalg.norm((inverse(true_rel) @ check.registration.transform)[:2, 3]))
        errors[kernel] = float(np.sqrt(np.mean(np.square(off))))
    # Measured: 4.5 mm RMS with the 0.2 m kernel alone, 2.3 mm with the fine kernel. (In the
    # mapping stage, whose submaps are posed by the odometry, loops 2-5 m apart went from
    # 1.9-2.3 cm to 0.5 cm RMS.)
    assert errors[0.0] > 0.0035
    assert errors[cfg.icp.fine_kernel_m] < 0.6 * errors[0.0]


def _corridor_errors(folder: Path, end_s: float, facing: bool) -> np.ndarray:
    """Along-track errors (m) of the registrations in the log's first `end_s` seconds, each
    from its true pose against a local map of true keyframes; with `facing` the lidar's
    position is given, so only map surfaces that face it are matched."""
    cfg = MappingConfig()
    truth = _truth(folder)
    local_map = LocalMap(cfg.local_map.voxel_size_m, cfg.local_map.keyframes, cfg.local_map.radius_m)
    matcher = ScanMatcher.from_config(cfg, local_map, AdaptiveThreshold.from_config(cfg))
    errors: list[float] = []
    last_keyframe: np.ndarray | None = None
    with open_log(folder / "log.mcap") as src:
        sensor_to_base = src.extrinsics().get("lidar")
        assert sensor_to_base is not None
        sensor = sensor_to_base[:3, 3] if facing else None
        for index, cloud in enumerate(src.clouds(src.start_ns, src.start_ns + round(end_s * 1e9))):
            if index % cfg.scan_stride or cloud.t_offset_ns is None:
                continue
            points, pose, linear = _scan(cloud, sensor_to_base, truth, cfg)
            speed = float(np.linalg.norm(linear))
            if local_map.target is not None and speed > 0.2:
                match = matcher.match(points, pose, sensor=sensor)
                ahead = pose[:3, :3] @ (linear / speed)
                errors.append(float((match.pose[:3, 3] - pose[:3, 3]) @ ahead))
            if last_keyframe is None or np.linalg.norm(pose[:3, 3] - last_keyframe) >= cfg.keyframes.distance_m:
                matcher.add_keyframe(points, pose, sensor)
                last_keyframe = pose[:3, 3]
    return np.array(errors)


def test_a_wall_seen_from_its_far_side_does_not_pull_the_scan(sim_run: Callable[..., Path]) -> None:
    """gen-stairs seed 11: 26 m down a corridor and back, past a cross corridor whose 12 cm
    walls the lidar sees from the far side (through a door) only after passing them.

    Matched to the near face already in the map, those points pulled one registration of the
    odometry 11.6 cm back along the corridor, and the odometry kept the offset to the corridor's
    end and back. Here every registration starts from the truth, so each one's own pull shows.
    """
    folder = sim_run("gen-stairs", seed=11)
    unchecked = _corridor_errors(folder, 70.0, facing=False)
    checked = _corridor_errors(folder, 70.0, facing=True)
    # Measured over 163 registrations: unchecked worst -4.5 cm, RMS 4.1 mm; checked worst
    # -0.7 cm, RMS 2.1 mm.
    assert np.abs(unchecked).max() > 0.03
    assert np.abs(checked).max() < 0.012
    assert np.sqrt(np.mean(checked ** 2)) < 0.003


def _true_keyframes(folder: Path, start_s: float, end_s: float, cfg: MappingConfig) -> list[Keyframe]:
    """Keyframes of the log's span as the mapping makes them (a metre or 15 degrees apart),
    each posed at the truth."""
    truth = _truth(folder)
    keyframes: list[Keyframe] = []
    with open_log(folder / "log.mcap") as src:
        sensor_to_base = src.extrinsics().get("lidar")
        assert sensor_to_base is not None
        span = (src.start_ns + round(start_s * 1e9), src.start_ns + round(end_s * 1e9))
        for index, cloud in enumerate(src.clouds(*span)):
            if index % cfg.scan_stride or cloud.t_offset_ns is None:
                continue
            points, pose, _ = _scan(cloud, sensor_to_base, truth, cfg)
            if keyframes:
                rel = inverse(keyframes[-1].pose) @ pose
                if (np.linalg.norm(rel[:3, 3]) < cfg.keyframes.distance_m
                        and np.degrees(rotation_angle_rad(rel)) < cfg.keyframes.angle_deg):
                    continue
            cloud_kf = downsample(points, cfg.keyframes.voxel_size_m).astype(np.float32)
            keyframes.append(Keyframe(len(keyframes), cloud.stamp_ns, 0, 0, pose, cloud_kf, 1.0, 0.0))
    return keyframes


def _loop_errors(keyframes: list[Keyframe], cfg: MappingConfig) -> np.ndarray:
    """How far (m) each loop the closer accepts is from the truth."""
    closer = LoopCloser(cfg)
    errors = []
    for keyframe in keyframes:
        for edge in closer.add(keyframe):
            true_rel = inverse(keyframes[edge.i].pose) @ keyframes[edge.j].pose
            errors.append(np.linalg.norm((inverse(true_rel) @ edge.measured)[:3, 3]))
    return np.array(errors)


def test_a_loop_must_hold_both_ways(sim_run: Callable[..., Path]) -> None:
    """gen-stairs seed 11: a corridor walked at 25 s and again at 80 s, ending in a turn in place
    2 m away. Furniture that one place saw and the other did not (occluded from where it stood)
    pulled the loops from the turn one way: they passed every check and came out 3-6 cm off.
    Registered the other way round as well, such loops fail the checks or land apart."""
    folder = sim_run("gen-stairs", seed=11)
    cfg = MappingConfig()
    keyframes = _true_keyframes(folder, 15.0, 90.0, cfg)
    one_way = _loop_errors(keyframes, cfg.model_copy(
        update={"loops": cfg.loops.model_copy(update={"both_ways": False})}))
    both_ways = _loop_errors(keyframes, cfg)
    # Measured: one way 21 loops, worst 5.7 cm, six more than 2.5 cm off (the x, y, z offset);
    # both ways 15 loops, worst 0.9 cm.
    assert one_way.max() > 0.035
    assert (one_way > 0.025).sum() >= 3
    assert both_ways.max() < 0.015
    assert len(both_ways) >= 10
