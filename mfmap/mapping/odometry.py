"""Scan-to-local-map lidar odometry: bounded local map, adaptive threshold, robust ICP."""

from __future__ import annotations

import copy
import math
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from mfmap.mapping.geometry import (
    inverse,
    rotation_angle_rad,
    transform,
    wrap_angle,
    yaw_pose,
    yaw_rad,
)
from mfmap.mapping.registration import (
    IcpTarget,
    Registration,
    downsample,
    downsample_viewed,
    icp,
    view_directions,
)
from mfmap.types import F64

if TYPE_CHECKING:
    from mfmap.mapping.config import MappingConfig


class AdaptiveThreshold:
    """KISS-ICP's correspondence threshold: 3 sigma of how far the prior was off so far."""

    def __init__(self, initial_m: float, min_motion_m: float, max_range_m: float,
                 floor_m: float) -> None:
        self.initial_m = initial_m
        self.min_motion_m = min_motion_m
        self.max_range_m = max_range_m
        self.floor_m = floor_m
        self._sum_sq = 0.0
        self._count = 0

    @classmethod
    def from_config(cls, cfg: MappingConfig) -> AdaptiveThreshold:
        return cls(cfg.icp.initial_threshold_m, cfg.icp.min_motion_m, cfg.max_range_m,
                   cfg.icp.min_threshold_m)

    def update(self, correction: F64) -> None:
        theta = rotation_angle_rad(correction)
        error = 2.0 * self.max_range_m * math.sin(theta / 2.0) + float(
            np.linalg.norm(correction[:3, 3]))
        if error > self.min_motion_m:
            self._sum_sq += error * error
            self._count += 1

    @property
    def value_m(self) -> float:
        if self._count == 0:
            return self.initial_m
        return max(3.0 * math.sqrt(self._sum_sq / self._count), self.floor_m)


class LocalMap:
    """The last keyframes' clouds in the world frame, merged at a voxel; bounded in size.

    Each point keeps the direction it was seen from, and the map's normals point to that side:
    a scan that sees the far face of a thin wall for the first time (through a door, or looking
    back past a corridor's end) otherwise matches it to the near face already in the map. On a
    generated corridor with 12 cm inner walls that pulled one registration 11.6 cm back along
    the corridor (looking back through a door at a cross corridor's wall), and every keyframe
    after it with it.
    """

    def __init__(self, voxel_m: float, max_keyframes: int, radius_m: float) -> None:
        self.voxel_m = voxel_m
        self.radius_m = radius_m
        # (position, points, their unit directions towards the sensor)
        self._frames: deque[tuple[F64, F64, F64]] = deque(maxlen=max_keyframes)
        self.target: IcpTarget | None = None
        self.size = 0

    @classmethod
    def from_config(cls, cfg: MappingConfig) -> LocalMap:
        return cls(cfg.local_map.voxel_size_m, cfg.local_map.keyframes, cfg.local_map.radius_m)

    def clear(self) -> None:
        self._frames.clear()
        self.target = None
        self.size = 0

    def fork(self) -> LocalMap:
        """A copy that later keyframes do not share (the target is replaced on every update,
        never changed, so both start from this one)."""
        twin = copy.copy(self)
        twin._frames = deque(self._frames, maxlen=self._frames.maxlen)
        return twin

    def add(self, world_points: F64, position: F64, sensor: F64 | None = None) -> None:
        """A keyframe's points (world frame) at `position`, seen from `sensor` (world frame; by
        default from `position`)."""
        seen_from = position if sensor is None else sensor
        points, views = downsample_viewed(world_points, view_directions(world_points, seen_from),
                                          self.voxel_m)
        self._frames.append((position, points, views))
        near = [i for i, (pos, _, _) in enumerate(self._frames)
                if np.linalg.norm(pos - position) <= self.radius_m]
        merged, merged_views = downsample_viewed(
            np.concatenate([self._frames[i][1] for i in near]),
            np.concatenate([self._frames[i][2] for i in near]), self.voxel_m)
        self.target = IcpTarget.estimate(merged, 3.0 * self.voxel_m, views=merged_views)
        self.size = len(self.target)


@dataclass(frozen=True)
class ScanMatch:
    pose: F64  # base in world after registration (or the prediction when not registered)
    fitness: float
    rmse_m: float
    registered: bool


class ScanMatcher:
    """Registers deskewed scans (base frame) against the local map of the current visit."""

    def __init__(self, voxel_m: float, local_map: LocalMap, threshold: AdaptiveThreshold,
                 max_iterations: int, min_fitness: float = 0.2, tolerance: float = 1e-6,
                 max_gyro_disagreement_deg: float = 0.0, max_overruled: int = 3,
                 low_fitness: float = 0.0, heading_sigma_deg: float = 0.0,
                 fine_kernel_m: float = 0.0) -> None:
        self.voxel_m = voxel_m
        self.fine_kernel_m = fine_kernel_m
        self.refined = 0  # registrations refined with the fine kernel
        self.heading_sigma_rad = math.radians(heading_sigma_deg)
        self._heading_var: float | None = None  # of the last pose's heading (rad^2), if known
        self.blended = 0  # registrations whose heading was blended with the gyro's
        self.max_gyro_disagreement_rad = math.radians(max_gyro_disagreement_deg)
        self.max_overruled = max_overruled
        self.low_fitness = low_fitness
        self.overruled = 0  # registrations whose rotation the gyro overruled
        self._overruled_in_a_row = 0
        self.map = local_map
        self.threshold = threshold
        self.max_iterations = max_iterations
        self.min_fitness = min_fitness
        self.tolerance = tolerance
        self.failures = 0
        self.jumps = 0  # registrations left out for moving too far from the motion prior
        self._jumps_in_a_row = 0

    @classmethod
    def from_config(cls, cfg: MappingConfig, local_map: LocalMap,
                    threshold: AdaptiveThreshold) -> ScanMatcher:
        return cls(cfg.voxel_size_m, local_map, threshold, cfg.icp.max_iterations,
                   tolerance=cfg.icp.tolerance,
                   max_gyro_disagreement_deg=cfg.icp.max_gyro_disagreement_deg,
                   low_fitness=cfg.icp.gyro_low_fitness,
                   heading_sigma_deg=cfg.icp.heading_sigma_deg,
                   fine_kernel_m=cfg.icp.fine_kernel_m)

    def match(self, points_base: F64, predicted: F64, gyro_prior: bool = False,
              gyro_var_rad2: float = 0.0, sensor: F64 | None = None,
              max_jump_m: float = 0.0) -> ScanMatch:
        """Register against the local map from `predicted`; `sensor` is the lidar's position in
        the base frame (only map surfaces facing it are matched, see `LocalMap`).

        With `gyro_prior` (the predicted rotation comes from the IMU gyro over a fraction of a
        second), a registration that turns the scan's heading away from it by more than
        `max_gyro_disagreement_deg` (half that below `low_fitness`) keeps the gyro's heading
        and takes only the registration's position, height, roll and pitch: where a scan sees
        much new structure (fitness well below 1), ICP can settle a few tenths of a degree off,
        an error that no loop on the floor can later take out of the visit's heading. After
        `max_overruled` such scans in a row the registration is taken again, so a biased gyro
        cannot hold the odometry off the map.

        Below `low_fitness`, a registration's heading is also blended with the gyro's
        prediction (`_blend_heading`); `gyro_var_rad2` is the variance the gyro adds to the
        predicted heading since the last registered scan.

        With `fine_kernel_m`, every registration gets a second ICP pass from its result with a
        Tukey kernel at the lidar's noise. The first pass's kernel, a third of the
        correspondence threshold, is wide enough to bring in a start some centimetres off, but
        it lets points near corners and at the edges of what the map has seen pull the scan
        back along the way the robot drives, the more the further it is from the last map
        update: through the keyframes a metre apart that made the maps 0.05-0.2 % short, and
        the scans between keyframes, which the trajectory reports, came out up to 2.4 cm back
        (two-floor seed 2, standing at a checkpoint 0.6 m past its keyframe). Both passes query
        the local map's k-d tree, built once with the map (`IcpTarget`).

        The fine pass stops by open3d's rule (fitness and inlier RMSE change by less than
        `tolerance`), usually after one or two iterations, while the pose is still creeping out
        of the pull-back: run for 10, it took that stand-still from 1.3 cm to 1.5 mm, but it
        also shortened the stairs' climbs (by 4.3 cm on average over six walks, 2.6 cm as it
        is) and made the checkpoints worse overall, so it is not run longer.
        """
        if self.map.target is None or len(points_base) < 10:
            self._heading_var = None  # a new map: the heading starts from the registration
            return ScanMatch(predicted, 0.0, 0.0, False)
        result = self._icp(downsample(points_base, self.voxel_m), self.map.target, predicted,
                           sensor)
        if result.fitness < self.min_fitness or self._jumped(result, predicted, max_jump_m):
            self.failures += 1
            self._propagate(gyro_prior, gyro_var_rad2)
            return ScanMatch(predicted, result.fitness, result.rmse_m, False)
        self._jumps_in_a_row = 0
        return self._accept(result, predicted, gyro_prior, gyro_var_rad2)

    def fork(self, voxel_m: float) -> ScanMatcher:
        """A copy registering scans downsampled at `voxel_m`, with its own local map and
        adaptive threshold from here on."""
        twin = copy.copy(self)
        twin.map, twin.threshold, twin.voxel_m = self.map.fork(), copy.copy(self.threshold), voxel_m
        return twin

    def _jumped(self, result: Registration, predicted: F64, max_jump_m: float) -> bool:
        """Whether the registration moved the scan further from the motion prior than the
        robot can have moved off it since the last scan (`max_jump_m`; 0: no limit), fewer
        than `max_overruled` times in a row (so a poor prior cannot hold the odometry off
        the map)."""
        if max_jump_m <= 0:
            return False
        moved = float(np.linalg.norm(result.transform[:3, 3] - predicted[:3, 3]))
        if moved <= max_jump_m or self._jumps_in_a_row >= self.max_overruled:
            return False
        self._jumps_in_a_row += 1
        self.jumps += 1
        return True

    def _icp(self, source: F64, target: IcpTarget, predicted: F64,
             sensor: F64 | None) -> Registration:
        """The registration, refined with the fine kernel when it is good enough."""
        max_distance = self.threshold.value_m
        result: Registration = icp(source, target, predicted, max_distance,
                                   max(max_distance / 3.0, 0.5 * self.voxel_m),
                                   self.max_iterations, self.tolerance, sensor)
        if self.fine_kernel_m > 0 and result.fitness >= self.min_fitness:
            # The same correspondences, a kernel at the lidar's noise (see `fine_kernel_m`).
            fine = icp(source, target, result.transform, max_distance,
                       self.fine_kernel_m, self.max_iterations, self.tolerance, sensor)
            result = Registration(fine.transform, result.fitness, result.rmse_m)
            self.refined += 1
        return result

    def _accept(self, result: Registration, predicted: F64, gyro_prior: bool,
                gyro_var_rad2: float) -> ScanMatch:
        """A registration good enough to take: its heading overruled by the gyro's when they
        disagree too much (see `match`), else blended with it (`_blend_heading`)."""
        correction = inverse(predicted) @ result.transform
        limit = self.max_gyro_disagreement_rad
        if result.fitness < self.low_fitness:
            limit *= 0.5
        if (gyro_prior and limit > 0
                and abs(yaw_rad(correction)) > limit
                and self._overruled_in_a_row < self.max_overruled):
            self.overruled += 1
            self._overruled_in_a_row += 1
            # The gyro's heading, the registration's position, height, roll and pitch (on
            # stairs the climb comes from the registration: keeping the whole prediction
            # there lost 7 cm of a 3.5 m flight).
            held = yaw_pose(yaw_rad(predicted) - yaw_rad(result.transform)) @ result.transform
            held[:3, 3] = result.transform[:3, 3]
            self._propagate(gyro_prior, gyro_var_rad2)
            return ScanMatch(held, result.fitness, result.rmse_m, False)
        self._overruled_in_a_row = 0
        self.threshold.update(correction)
        pose = self._blend_heading(result, predicted, gyro_prior, gyro_var_rad2)
        return ScanMatch(pose, result.fitness, result.rmse_m, True)

    def _propagate(self, gyro_prior: bool, gyro_var_rad2: float) -> None:
        """The pose kept the prediction's heading: its variance grows by the gyro's."""
        if self._heading_var is not None:
            self._heading_var = self._heading_var + gyro_var_rad2 if gyro_prior else None

    def _blend_heading(self, result: Registration, predicted: F64, gyro_prior: bool,
                       gyro_var_rad2: float) -> F64:
        """The registration's pose, its heading pulled towards the gyro's prediction by a
        Kalman gain where the scan sees much new structure.

        A registration's heading is off by about `heading_sigma_deg` / fitness, unbiased where
        the scan overlaps the map; the prediction's is the last pose's plus the gyro's noise
        since then. Below `low_fitness` the two are weighed by their variances: on `long`'s
        stair-top visit, where the odometry turned 0.3 deg on its way into new corridors, this
        took the visit's error after its loops from 5.8 to 4.6 cm (pinned to one CPU). At full
        overlap the registration stands, so the gyro's slow drift never enters the map.
        """
        measured_var = (self.heading_sigma_rad / max(result.fitness, 1e-3)) ** 2
        if (self.heading_sigma_rad <= 0 or not gyro_prior or self._heading_var is None
                or result.fitness >= self.low_fitness):
            self._heading_var = measured_var
            return result.transform
        prior_var = self._heading_var + gyro_var_rad2
        gain = prior_var / (prior_var + measured_var)
        self._heading_var = gain * measured_var
        self.blended += 1
        turn = wrap_angle(yaw_rad(result.transform) - yaw_rad(predicted))
        blended = yaw_pose(-(1.0 - gain) * turn) @ result.transform
        blended[:3, 3] = result.transform[:3, 3]
        return blended

    def add_keyframe(self, points_base: F64, pose: F64, sensor: F64 | None = None) -> None:
        """A keyframe's points (base frame) at `pose`, seen from `sensor` (base frame; by
        default the base origin)."""
        seen_from = None if sensor is None else transform(sensor[None, :], pose)[0]
        self.map.add(transform(points_base, pose), pose[:3, 3], seen_from)
