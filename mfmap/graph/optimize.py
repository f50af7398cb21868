"""The building's factor graph: one gtsam.NonlinearFactorGraph for all floors, optimised by LM.

Variables: Pose3 x<keyframe id> per keyframe, a barometer height bias b<k> per keyframe (in time
order) drifting as a random walk within a floor visit, a floor level f<id> per floor (ground
robots), and the barometer's height scale s0 and per-floor pressure offsets u<id> (as heights)
where barometric heights are used. Factors, by kind:
- prior: the first keyframe fixes the world frame;
- odometry / loop: the mapping stage's edges, robust (Huber or Cauchy);
- barometer: gtsam.BarometricFactor per keyframe (z = height(pressure) - bias);
- bias_walk: BetweenFactorDouble between consecutive biases (sigma grows with sqrt(dt); free
  across a transition);
- elevator: x, y, yaw held across a ride, z free;
- imu_ride: an elevator ride's height change from the IMU (mfmap.graph.ride), z only;
- walk_z: a stair walk's height change from the lidar odometry, z only;
- transition_z: the barometer's height change across a ride or a stairway (a fit on the raw trace
  either side, mfmap.floors.levels.level_change), through the scale and the two floors' offsets;
- baro_scale, baro_offset: their priors (mfmap.graph.heights decides which heights are used and
  calibrates the priors);
- interfloor: global registration of adjacent floors, x, y, yaw only;
- height_tie: every keyframe of a floor at that floor's level f<id> (world z; ground robots);
- gravity: roll/pitch from the IMU's gravity (or level when there is no IMU);
- bridge: a weak link (z free) only where nothing else connects two parts of the graph.

The keys and the factor builder are mfmap.graph.factors; the transitions' heights
mfmap.graph.transitions; the floors' levels, their registration and the bridges
mfmap.graph.floorlinks.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence
from concurrent.futures import Executor
from dataclasses import dataclass, field
from typing import Any

import gtsam
import numpy as np
from scipy.stats import chi2

from mfmap.graph.barometer import pressure_at, pressure_to_height_m
from mfmap.graph.config import BaroSource, GraphConfig, RobustKernel
from mfmap.graph.factors import (
    FREE_SIGMA,
    SCALE,
    B,
    Builder,
    FactorStats,
    U,
    X,
    edge_model,
    robust_model,
    sqrt_info_from_sigmas,
    world_z,
)
from mfmap.graph.floorlinks import (
    add_height_ties,
    add_interfloor,
    bridge_components,
    floor_points,
    median_floor_z,
)
from mfmap.graph.heights import Calibration
from mfmap.graph.interfloor import FloorMatch
from mfmap.graph.transitions import Walk, add_transitions, height_keys
from mfmap.logs import collect_warnings
from mfmap.progress import NullProgress, Progress
from mfmap.types import (
    F64,
    FloorSegmentation,
    ImuSeries,
    Keyframe,
    PoseEdge,
    PressureSeries,
)

logger = logging.getLogger(__name__)

__all__ = ["FactorStats", "GraphResult", "floor_points", "optimize_building"]


@dataclass
class GraphResult:
    """Optimised keyframe poses (id -> 4x4 base-in-world) and what the graph did."""

    poses: dict[int, F64]
    initial_poses: dict[int, F64]
    bias_m: dict[int, float]
    stats: dict[str, FactorStats]
    floor_matches: list[FloorMatch]
    floor_z_m: dict[int, float]  # median optimised keyframe z per floor
    iterations: int
    error_initial: float
    error_final: float
    seconds: float
    warnings: list[str] = field(default_factory=list)
    rides: list[dict[str, Any]] = field(default_factory=list)  # per transition: its heights
    heights: dict[str, Any] = field(default_factory=dict)  # the barometer's calibration

    def to_json(self) -> dict[str, Any]:
        return {
            "iterations": self.iterations,
            "error_initial": round(self.error_initial, 6),
            "error_final": round(self.error_final, 6),
            "seconds": round(self.seconds, 3),
            "factors": {k: v.to_json() for k, v in self.stats.items()},
            "inter_floor": [
                {
                    "lower": m.lower,
                    "upper": m.upper,
                    "accepted": m.accepted,
                    "reason": m.reason,
                    "fitness": round(m.fitness, 4),
                    "runner_up_fitness": round(m.runner_up_fitness, 4),
                    "rmse_m": round(m.rmse_m, 4),
                    "dx_m": round(m.dx_m, 4),
                    "dy_m": round(m.dy_m, 4),
                    "dyaw_deg": round(m.dyaw_deg, 4),
                }
                for m in self.floor_matches
            ],
            "floor_z_m": {str(k): round(v, 4) for k, v in self.floor_z_m.items()},
            "rides": [dict(r) for r in self.rides],
            "heights": dict(self.heights),
            "warnings": list(self.warnings),
        }


def _consistent(edge: PoseEdge, initial: dict[int, F64], config: GraphConfig) -> bool:
    """Does a loop edge agree with the initial relative pose within the gate?"""
    rel = np.linalg.inv(initial[edge.i]) @ initial[edge.j]
    delta = np.linalg.inv(np.asarray(edge.measured)) @ rel
    angle = math.degrees(math.acos(float(np.clip((np.trace(delta[:3, :3]) - 1) / 2, -1.0, 1.0))))
    return bool(np.linalg.norm(delta[:3, 3]) <= config.robust.loop_gate_m and angle <= config.robust.loop_gate_deg)


def optimize_building(
    keyframes: Sequence[Keyframe],
    edges: Sequence[PoseEdge],
    segmentation: FloorSegmentation | None,
    pressure: PressureSeries | None,
    config: GraphConfig,
    temperature_k: float = 288.15,
    gravity_body: dict[int, F64] | None = None,
    progress: Progress | None = None,
    imu: ImuSeries | None = None,
    executor: Executor | None = None,
    scale_prior_sigma: float | None = None,
) -> GraphResult:
    """Build the building's factor graph from the mapping stage's keyframes and edges; optimise.

    `gravity_body` maps a keyframe id to the measured up direction (specific force) in the base
    frame; keyframes without one are assumed level. `imu` gives each elevator ride's height change
    (config `imu_ride_height`); without it z across a ride comes from the barometer alone.
    With `executor` (processes of `mapping.workers.worker_pool`) the pairs of adjacent floors are
    registered in parallel, with the same results. `scale_prior_sigma`: the uncertainty of the
    barometer's height scale before the data (a Temperature topic's; default: config
    `baro_scale_sigma`, the assumed temperature's).
    Heights: see mfmap.graph.heights.
    Returns optimised poses; keyframes are not modified.
    """
    started = time.perf_counter()
    progress = progress or NullProgress()
    if not keyframes:
        raise ValueError("optimize_building needs at least one keyframe")
    kfs = sorted(keyframes, key=lambda k: (k.stamp_ns, k.id))
    ids = [k.id for k in kfs]
    initial_poses = {k.id: np.asarray(k.pose, dtype=np.float64).copy() for k in kfs}
    builder = Builder(config)
    values = gtsam.Values()
    for kf in kfs:
        values.insert(X(kf.id), gtsam.Pose3(initial_poses[kf.id]))

    sensors = _Sensors(pressure, temperature_k, gravity_body, imu, scale_prior_sigma)
    with collect_warnings() as collected:  # logged, and kept in the result (report.json's "graph")
        result, iterations, matches, rides, calibration = _solve(
            builder, values, kfs, edges, initial_poses, segmentation, config, sensors, executor,
            progress,
        )
    _count_outliers(builder, values, result, config)
    poses = {i: np.asarray(result.atPose3(X(i)).matrix(), dtype=np.float64) for i in ids}
    return GraphResult(
        poses=poses,
        initial_poses=initial_poses,
        bias_m=_heights_in_graph(result, kfs, rides, config),
        stats=builder.stats,
        floor_matches=matches,
        floor_z_m=median_floor_z(kfs, poses),
        iterations=iterations,
        error_initial=float(builder.graph.error(values)),
        error_final=float(builder.graph.error(result)),
        seconds=time.perf_counter() - started,
        warnings=collected.lines(),
        rides=rides,
        heights=_height_model(result, kfs, calibration),
    )


def _solve(
    builder: Builder,
    values: Any,
    kfs: list[Keyframe],
    edges: Sequence[PoseEdge],
    initial_poses: dict[int, F64],
    segmentation: FloorSegmentation | None,
    config: GraphConfig,
    sensors: _Sensors,
    executor: Executor | None,
    progress: Progress,
) -> tuple[Any, int, list[FloorMatch], list[dict[str, Any]], Calibration]:
    """The factors, the two phases of optimisation; returns the result, the iterations, the
    floors' matches, the transitions' report entries and the barometer's calibration."""
    with progress.stage("graph", total=3) as bar:
        rides, calibration = _add_factors(
            builder, values, kfs, edges, initial_poses, segmentation, config, sensors,
        )
        bar.advance()

        # Phase 1: every factor but the inter-floor ones, so each floor's map is consistent
        # before floors are registered against each other.
        bridge_components(builder, kfs, initial_poses)
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(config.max_iterations)
        params.setRelativeErrorTol(1e-7)
        params.setAbsoluteErrorTol(1e-9)
        optimizer = gtsam.LevenbergMarquardtOptimizer(builder.graph, values, params)
        result = optimizer.optimize()
        iterations = int(optimizer.iterations())
        bar.advance()

        result, more, matches = _register_and_optimize(builder, kfs, result, params, segmentation,
                                                       config, executor)
        iterations += more
        bar.advance()

    return result, iterations, matches, rides, calibration


@dataclass(frozen=True)
class _Sensors:
    """What the graph takes besides the mapping stage's keyframes and edges (see
    optimize_building)."""

    pressure: PressureSeries | None
    temperature_k: float
    gravity_body: dict[int, F64] | None
    imu: ImuSeries | None
    scale_prior_sigma: float | None


def _add_factors(
    builder: Builder,
    values: Any,
    kfs: list[Keyframe],
    edges: Sequence[PoseEdge],
    initial_poses: dict[int, F64],
    segmentation: FloorSegmentation | None,
    config: GraphConfig,
    sensors: _Sensors,
) -> tuple[list[dict[str, Any]], Calibration]:
    """Every factor of phase 1; returns the transitions' report entries and the barometer's
    calibration."""
    walks = _add_edges(builder, kfs, edges, initial_poses, config)
    _add_barometer(
        builder, values, kfs, initial_poses, sensors.pressure, segmentation, config, sensors.temperature_k,
    )
    rides, calibration = add_transitions(builder, values, kfs, initial_poses, segmentation, config,
                                         sensors.imu, walks, sensors.scale_prior_sigma)
    if config.ablation.same_floor_height_tie:
        add_height_ties(builder, values, kfs, initial_poses)
    if config.ablation.gravity_factors:
        _add_gravity(builder, kfs, sensors.gravity_body, config)
    return rides, calibration


def _add_edges(
    builder: Builder,
    kfs: list[Keyframe],
    edges: Sequence[PoseEdge],
    initial_poses: dict[int, F64],
    config: GraphConfig,
) -> dict[tuple[int, int], Walk]:
    """The prior on the first keyframe and the mapping stage's odometry and loop edges; returns
    the stair walks, whose height change is weighed with the barometer's per transition."""
    by_id = {k.id: k for k in kfs}
    # Prior: the first keyframe fixes the world frame.
    prior_sig = np.full(6, config.prior_sigma)
    builder.add(
        "prior",
        gtsam.PriorFactorPose3(X(kfs[0].id), gtsam.Pose3(initial_poses[kfs[0].id]),
                               gtsam.noiseModel.Diagonal.Sigmas(prior_sig)),
        sqrt_info_from_sigmas(prior_sig),
    )

    known = set(by_id)
    walks: dict[tuple[int, int], Walk] = {}
    for edge in edges:
        if edge.i not in known or edge.j not in known:
            logger.warning("edge %d->%d refers to an unknown keyframe", edge.i, edge.j)
            continue
        if edge.kind != "odometry" and not _consistent(edge, initial_poses, config):
            # A loop that contradicts the mapping stage's own map by metres or tens of
            # degrees is a false match (a similar place), not drift: a robust kernel would
            # still pull on it, so it is left out.
            builder.reject(edge.kind)
            continue
        information = np.asarray(edge.information, dtype=np.float64)
        walk = edge.kind == "odometry" and by_id[edge.i].visit != by_id[edge.j].visit
        if walk:
            # Across a stair walk the height change is its own world-z factor: z in the
            # first pose's frame would turn that pose's tilt (0.2 deg against the
            # odometry's own) into centimetres over the walk's horizontal run.
            sigma_z = float(information[5, 5]) ** -0.5
            information = information.copy()
            information[5, :] = 0.0
            information[:, 5] = 0.0
            information[5, 5] = FREE_SIGMA**-2
        model, sqrt_info = edge_model(
            config, information,
            RobustKernel.CAUCHY if edge.kind != "odometry" else config.robust.kernel,
        )
        factor = gtsam.BetweenFactorPose3(X(edge.i), X(edge.j), gtsam.Pose3(edge.measured), model)
        builder.add(edge.kind, factor, sqrt_info)
        builder.links.append((edge.i, edge.j))
        if walk and sigma_z < FREE_SIGMA:
            # The lidar's climb, a scale-true height: weighed with the barometer's per
            # transition (mfmap.graph.heights) before it becomes a factor. Not a 2D lidar's,
            # which measures none (its edge's z is free).
            walks[(edge.i, edge.j)] = Walk.of(edge, initial_poses, sigma_z)
    return walks


def _add_gravity(
    builder: Builder, kfs: list[Keyframe], gravity_body: dict[int, F64] | None, config: GraphConfig
) -> None:
    """Roll and pitch of every keyframe from the measured up direction (level without one)."""
    sig = math.radians(config.gravity.sigma_deg)
    up = gtsam.Unit3(np.array([0.0, 0.0, 1.0]))
    for kf in kfs:
        g = None if gravity_body is None else gravity_body.get(kf.id)
        measured = up if g is None else gtsam.Unit3(np.asarray(g, dtype=np.float64))
        # Huber: a keyframe taken while the robot accelerates in a way the odometry
        # does not see measures up off by degrees, many sigmas at this width.
        model = robust_model(config, gtsam.noiseModel.Isotropic.Sigma(2, sig), RobustKernel.HUBER)
        builder.add("gravity", gtsam.AttitudeFactorPose3(X(kf.id), up, model, measured),
                    np.eye(2) / sig)


def _register_and_optimize(
    builder: Builder,
    kfs: list[Keyframe],
    result: Any,
    params: Any,
    segmentation: FloorSegmentation | None,
    config: GraphConfig,
    executor: Executor | None,
) -> tuple[Any, int, list[FloorMatch]]:
    """Phase 2: register adjacent floors on the phase-1 maps, add the factors, optimise again.
    Returns the result, the further iterations and the floors' matches."""
    iterations = 0
    matches: list[FloorMatch] = []
    floor_ids = sorted({k.floor_id for k in kfs if k.floor_id >= 0})
    if config.ablation.inter_floor_registration and len(floor_ids) > 1:
        phase1 = {k.id: np.asarray(result.atPose3(X(k.id)).matrix()) for k in kfs}
        matches = add_interfloor(builder, kfs, phase1, floor_ids, config, executor)
        for m in matches:
            if not m.accepted:
                logger.warning("floors %d/%d not registered (%s)", m.lower, m.upper, m.reason)
        if any(m.accepted for m in matches):
            optimizer = gtsam.LevenbergMarquardtOptimizer(builder.graph, result, params)
            result = optimizer.optimize()
            iterations += int(optimizer.iterations())
    return result, iterations, matches


def _count_outliers(builder: Builder, values: Any, result: Any, config: GraphConfig) -> None:
    """Per factor kind: the summed error before and after, and the residuals beyond the gate."""
    threshold = {d: float(chi2.ppf(config.robust.outlier_chi2_p, d)) for d in (1, 2, 6)}
    for entry in builder.entries:
        stats = builder.stats[entry.kind]
        stats.error_initial += float(entry.factor.error(values))
        stats.error_final += float(entry.factor.error(result))
        residual = np.asarray(entry.factor.unwhitenedError(result), dtype=np.float64)
        d2 = float(np.sum((entry.sqrt_info @ residual) ** 2))
        stats.max_mahalanobis = max(stats.max_mahalanobis, math.sqrt(d2))
        if d2 > threshold.get(len(residual), float(chi2.ppf(config.robust.outlier_chi2_p, len(residual)))):
            stats.outliers += 1


def _heights_in_graph(
    result: Any, kfs: list[Keyframe], rides: list[dict[str, Any]], config: GraphConfig
) -> dict[int, float]:
    """Each transition's height change in the optimised graph (into its report entry); returns
    the barometer's bias per keyframe (in time order)."""
    by_id = {k.id: k for k in kfs}
    for ride in rides:
        if "keyframes" in ride:
            a, b = ride["keyframes"]
            lo, hi = height_keys(by_id[a], by_id[b], config)
            ride["graph_height_change_m"] = round(world_z(result, hi) - world_z(result, lo), 4)
    return {k: float(result.atDouble(B(k))) for k in range(len(kfs)) if result.exists(B(k))}


def _height_model(result: Any, kfs: list[Keyframe], calibration: Calibration) -> dict[str, Any]:
    """The barometer's calibration, with its scale and offsets as the graph optimised them."""
    height_model = calibration.to_json()
    if result.exists(SCALE):
        height_model["graph_scale"] = round(float(result.atDouble(SCALE)), 5)
        height_model["graph_offsets_m"] = {
            str(f): round(float(result.atDouble(U(f))), 4)
            for f in sorted({k.floor_id for k in kfs if k.floor_id >= 0}) if result.exists(U(f))
        }
    return height_model


def _add_barometer(
    builder: Builder,
    values: Any,
    kfs: list[Keyframe],
    initial: dict[int, F64],
    pressure: PressureSeries | None,
    seg: FloorSegmentation | None,
    config: GraphConfig,
    temperature_k: float,
) -> None:
    if not config.ablation.barometer_factors:
        return
    if pressure is None or len(pressure) == 0:
        logger.warning("no barometer, barometric factors skipped")
        return
    stamps = np.array([k.stamp_ns for k in kfs], dtype=np.int64)
    if config.barometer.source == BaroSource.FILTERED and seg is not None and len(seg.stamp_ns) > 1:
        # The floors stage's offline-filtered trace: spikes and door/HVAC transients removed.
        filtered = PressureSeries(seg.stamp_ns, np.asarray(seg.height_filtered_m, dtype=np.float64))
        height = pressure_at(filtered, stamps, config.barometer.window_s)
    else:
        p_pa = pressure_at(pressure, stamps, config.barometer.window_s)
        height = pressure_to_height_m(p_pa, float(pressure.pressure_pa[0]), temperature_k)
    converter = gtsam.BarometricFactor()
    model = robust_model(config, gtsam.noiseModel.Isotropic.Sigma(1, config.barometer.sigma_m))
    for k, kf in enumerate(kfs):
        baro_kpa = float(converter.baroOut(float(height[k])))
        factor = gtsam.BarometricFactor(X(kf.id), B(k), baro_kpa, model)
        builder.add("barometer", factor, np.eye(1) / config.barometer.sigma_m)
        values.insert(B(k), float(height[k] - initial[kf.id][2, 3]))
    builder.add(
        "bias_prior",
        gtsam.PriorFactorDouble(B(0), float(height[0] - initial[kfs[0].id][2, 3]),
                                gtsam.noiseModel.Isotropic.Sigma(1, 10.0)),
        np.eye(1) / 10.0,
    )
    for k in range(len(kfs) - 1):
        dt_s = max((kfs[k + 1].stamp_ns - kfs[k].stamp_ns) / 1e9, 1e-3)
        sig = config.barometer.bias_random_walk_m_sqrt_s * math.sqrt(dt_s)
        if kfs[k + 1].visit != kfs[k].visit:
            # Across a transition the bias is free: the keyframes' barometric heights would
            # otherwise measure the transition's height a second time, uncalibrated (its scale
            # and the floors' offsets are the transition factors' business).
            sig = FREE_SIGMA
        builder.add(
            "bias_walk",
            gtsam.BetweenFactorDouble(B(k), B(k + 1), 0.0, gtsam.noiseModel.Isotropic.Sigma(1, sig)),
            np.eye(1) / sig,
        )
