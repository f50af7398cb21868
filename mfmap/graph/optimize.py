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
"""

from __future__ import annotations

import functools
import itertools
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

from mfmap.floors.levels import RawTrace, level_change, raw_trace
from mfmap.graph import heights
from mfmap.graph.barometer import pressure_at, pressure_to_height_m
from mfmap.graph.config import BaroSource, GraphConfig, RobustKernel
from mfmap.graph.heights import Calibration, Measurement, TransitionHeights
from mfmap.graph.interfloor import FloorMatch, register_floors
from mfmap.graph.ride import ride_height
from mfmap.progress import NullProgress, Progress
from mfmap.types import (
    F64,
    FloorSegmentation,
    ImuSeries,
    Keyframe,
    PoseEdge,
    PressureSeries,
    TransitionKind,
)

logger = logging.getLogger(__name__)

# A sigma that leaves a component nearly free (z across a ride, which the barometer sets) while
# keeping the problem well posed when the barometer is switched off.
FREE_SIGMA = 10.0
# Model error added (in quadrature) to a barometric level change's own sigma: what the fit cannot
# see, such as a floor kept at a slightly different pressure by its air handling (1 Pa ~ 8.5 cm).
# Over three seeds of two-floor, three-floor-revisit and stairs, 0.005 / 0.01 / 0.02 m gave floor
# elevation errors of 1.54 / 1.57 / 1.67 cm RMS (2.46 with the floors stage's change at 3 cm).
BARO_MODEL_SIGMA_M = 0.01


def X(i: int) -> int:
    return int(gtsam.symbol("x", i))


def B(k: int) -> int:
    return int(gtsam.symbol("b", k))


# The barometer's height scale (true metres per barometric metre at the assumed temperature).
SCALE = int(gtsam.symbol("s", 0))


def U(floor: int) -> int:
    """A floor's pressure offset, as a height in true metres (scale times offset)."""
    return int(gtsam.symbol("u", floor))


def Fl(floor: int) -> int:
    """A floor's level: a double holding minus its z (see LEVEL_KPA)."""
    return int(gtsam.symbol("f", floor))


# gtsam.BarometricFactor(x, f, p) has error z_x + f - height(p). At the pressure whose height is
# zero, with f holding minus a floor's level, it is z_x - level: a world-z tie between a keyframe
# and its floor, in C++. Python CustomFactors for the ties cost 10 s of graph time on `long`.
LEVEL_KPA = float(gtsam.BarometricFactor().baroOut(0.0))


def _is_level(key: int) -> bool:
    return gtsam.Symbol(key).chr() == ord("f")


def _z(values: Any, key: int) -> float:
    """World z of a keyframe X(id) or a floor level Fl(id)."""
    return -float(values.atDouble(key)) if _is_level(key) else float(values.atPose3(key).z())


@dataclass
class FactorStats:
    """Per factor kind: how many, their summed error before/after, how many are outliers."""

    count: int = 0
    error_initial: float = 0.0
    error_final: float = 0.0
    outliers: int = 0
    rejected: int = 0
    max_mahalanobis: float = 0.0

    def to_json(self) -> dict[str, float | int]:
        return {
            "count": self.count,
            "error_initial": round(self.error_initial, 6),
            "error_final": round(self.error_final, 6),
            "outliers": self.outliers,
            "rejected": self.rejected,
            "max_mahalanobis": round(self.max_mahalanobis, 4),
        }


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


@dataclass
class _Entry:
    kind: str
    factor: Any
    sqrt_info: F64  # whitening of the unwhitened error (Mahalanobis for outlier counting)


def _consistent(edge: PoseEdge, initial: dict[int, F64], config: GraphConfig) -> bool:
    """Does a loop edge agree with the initial relative pose within the gate?"""
    rel = np.linalg.inv(initial[edge.i]) @ initial[edge.j]
    delta = np.linalg.inv(np.asarray(edge.measured)) @ rel
    angle = math.degrees(math.acos(float(np.clip((np.trace(delta[:3, :3]) - 1) / 2, -1.0, 1.0))))
    return bool(np.linalg.norm(delta[:3, 3]) <= config.loop_gate_m and angle <= config.loop_gate_deg)


# Roll and pitch of the ride and inter-floor factors: loose, the gravity factors set the tilt.
_LOOSE_TILT_RAD = math.radians(5.0)


def _robust(config: GraphConfig, model: Any, kernel_name: RobustKernel | None = None) -> Any:
    kernel: Any
    if (kernel_name or config.robust_kernel) == RobustKernel.CAUCHY:
        kernel = gtsam.noiseModel.mEstimator.Cauchy.Create(config.robust_k)
    else:
        kernel = gtsam.noiseModel.mEstimator.Huber.Create(config.robust_k)
    return gtsam.noiseModel.Robust.Create(kernel, model)


def _sqrt_info_from_sigmas(sigmas: F64) -> F64:
    return np.diag(1.0 / np.asarray(sigmas, dtype=np.float64))


def _relative_level(pose_a: F64, pose_b: F64, dz_world_m: float | None) -> F64:
    """pose_a^-1 pose_b, with the world height change replaced by dz_world_m when given."""
    b = pose_b.copy()
    if dz_world_m is not None:
        b[2, 3] = pose_a[2, 3] + dz_world_m
    return np.asarray(np.linalg.inv(pose_a) @ b)


class _Builder:
    def __init__(self, config: GraphConfig) -> None:
        self.config = config
        self.graph = gtsam.NonlinearFactorGraph()
        self.entries: list[_Entry] = []
        self.stats: dict[str, FactorStats] = {}
        self.links: list[tuple[int, int]] = []

    def add(self, kind: str, factor: Any, sqrt_info: F64) -> None:
        self.graph.add(factor)
        self.entries.append(_Entry(kind, factor, sqrt_info))
        self.stats.setdefault(kind, FactorStats()).count += 1

    def between(
        self,
        kind: str,
        i: int,
        j: int,
        measured: F64,
        sigmas: Sequence[float],
        robust: bool = True,
        kernel: RobustKernel | None = None,
        links: bool = True,
    ) -> None:
        """A BetweenFactorPose3; `links` says whether it ties x, y and yaw (graph connectivity)."""
        sig = np.asarray(sigmas, dtype=np.float64)
        model = gtsam.noiseModel.Diagonal.Sigmas(sig)
        if robust:
            model = _robust(self.config, model, kernel)
        self.add(kind, gtsam.BetweenFactorPose3(X(i), X(j), gtsam.Pose3(measured), model), _sqrt_info_from_sigmas(sig))
        if links:
            self.links.append((i, j))

    def world_dz(self, kind: str, key_i: int, key_j: int, dz_m: float, sigma_m: float,
                 robust: bool = False) -> None:
        """z_j - z_i = dz_m in the world frame, whatever the two poses' tilt (gtsam keys of two
        keyframes X(id), or of two floor levels Fl(id): a BetweenFactorDouble on their minus z).

        A BetweenFactorPose3 with only z tight measures z in pose i's frame: a tilt of a
        fraction of a degree there turns the horizontal run between the poses (several metres
        on a stair walk) into centimetres of height.
        """
        model = gtsam.noiseModel.Isotropic.Sigma(1, sigma_m)
        if robust:
            model = _robust(self.config, model)
        if _is_level(key_i) and _is_level(key_j):
            self.add(kind, gtsam.BetweenFactorDouble(key_i, key_j, -dz_m, model), np.eye(1) / sigma_m)
            return
        # Pose3 retraction moves the translation by R v (first order), not by the rotation part.
        zero = np.zeros(3)

        def error(this: Any, values: Any, jacobians: list[np.ndarray] | None) -> np.ndarray:
            a = values.atPose3(this.keys()[0])
            b = values.atPose3(this.keys()[1])
            if jacobians is not None:
                jacobians[0] = np.concatenate([zero, -a.rotation().matrix()[2]]).reshape(1, 6)
                jacobians[1] = np.concatenate([zero, b.rotation().matrix()[2]]).reshape(1, 6)
            return np.array([b.z() - a.z() - dz_m])

        self.add(kind, gtsam.CustomFactor(model, [key_i, key_j], error), np.eye(1) / sigma_m)

    def reject(self, kind: str) -> None:
        self.stats.setdefault(kind, FactorStats()).rejected += 1


def _edge_model(config: GraphConfig, information: F64, kernel_name: RobustKernel) -> tuple[Any, F64]:
    info = 0.5 * (information + information.T)
    # Guard against a singular matrix from the mapping stage: floor the eigenvalues.
    w, v = np.linalg.eigh(info)
    w = np.maximum(w, 1e-6)
    info = (v * w) @ v.T
    sqrt_info = np.asarray(np.linalg.cholesky(info).T)
    return _robust(config, gtsam.noiseModel.Gaussian.Information(info), kernel_name), sqrt_info


def floor_points(
    keyframes: Sequence[Keyframe],
    poses: dict[int, F64],
    floor_id: int,
    band_m: tuple[float, float],
    floor_z_m: float,
) -> np.ndarray:
    """World points of a floor's keyframes within a height band, z made floor-relative."""
    chunks = []
    for kf in keyframes:
        if kf.floor_id != floor_id or len(kf.cloud) == 0:
            continue
        pose = poses[kf.id]
        pts = kf.cloud.astype(np.float64) @ pose[:3, :3].T + pose[:3, 3]
        rel = pts[:, 2] - floor_z_m
        keep = (rel >= band_m[0]) & (rel <= band_m[1])
        sel = pts[keep]
        sel[:, 2] -= floor_z_m
        chunks.append(sel)
    if not chunks:
        return np.zeros((0, 3))
    return np.concatenate(chunks)


def _floor_z(keyframes: Sequence[Keyframe], poses: dict[int, F64]) -> dict[int, float]:
    by_floor: dict[int, list[float]] = {}
    for kf in keyframes:
        if kf.floor_id >= 0:
            by_floor.setdefault(kf.floor_id, []).append(float(poses[kf.id][2, 3]))
    return {f: float(np.median(z)) for f, z in sorted(by_floor.items())}


def _components(ids: list[int], links: list[tuple[int, int]]) -> dict[int, int]:
    parent = {i: i for i in ids}

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for a, b in links:
        if a in parent and b in parent:
            ra, rb = find(a), find(b)
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
    return {i: find(i) for i in ids}


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
    warnings: list[str] = []
    if not keyframes:
        raise ValueError("optimize_building needs at least one keyframe")
    kfs = sorted(keyframes, key=lambda k: (k.stamp_ns, k.id))
    ids = [k.id for k in kfs]
    initial_poses = {k.id: np.asarray(k.pose, dtype=np.float64).copy() for k in kfs}
    by_id = {k.id: k for k in kfs}
    builder = _Builder(config)
    values = gtsam.Values()
    for kf in kfs:
        values.insert(X(kf.id), gtsam.Pose3(initial_poses[kf.id]))

    with progress.stage("graph", total=3) as bar:
        # Prior: the first keyframe fixes the world frame.
        prior_sig = np.full(6, config.prior_sigma)
        builder.add(
            "prior",
            gtsam.PriorFactorPose3(X(kfs[0].id), gtsam.Pose3(initial_poses[kfs[0].id]),
                                   gtsam.noiseModel.Diagonal.Sigmas(prior_sig)),
            _sqrt_info_from_sigmas(prior_sig),
        )

        known = set(ids)
        walks: dict[tuple[int, int], _Walk] = {}
        for edge in edges:
            if edge.i not in known or edge.j not in known:
                warnings.append(f"graph: edge {edge.i}->{edge.j} refers to an unknown keyframe")
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
            model, sqrt_info = _edge_model(
                config, information,
                RobustKernel.CAUCHY if edge.kind != "odometry" else config.robust_kernel,
            )
            factor = gtsam.BetweenFactorPose3(X(edge.i), X(edge.j), gtsam.Pose3(edge.measured), model)
            builder.add(edge.kind, factor, sqrt_info)
            builder.links.append((edge.i, edge.j))
            if walk:
                # The lidar's climb, a scale-true height: weighed with the barometer's per
                # transition (mfmap.graph.heights) before it becomes a factor.
                walks[(edge.i, edge.j)] = _Walk.of(edge, initial_poses, sigma_z)

        _add_barometer(
            builder, values, kfs, initial_poses, pressure, segmentation, config, temperature_k, warnings
        )
        rides, calibration = _add_transitions(builder, values, kfs, initial_poses, segmentation, config,
                                              imu, walks, scale_prior_sigma, warnings)
        if config.same_floor_height_tie:
            _add_height_ties(builder, values, kfs, initial_poses)
        if config.gravity_factors:
            sig = math.radians(config.gravity_sigma_deg)
            up = gtsam.Unit3(np.array([0.0, 0.0, 1.0]))
            for kf in kfs:
                g = None if gravity_body is None else gravity_body.get(kf.id)
                measured = up if g is None else gtsam.Unit3(np.asarray(g, dtype=np.float64))
                # Huber: a keyframe taken while the robot accelerates in a way the odometry
                # does not see measures up off by degrees, many sigmas at this width.
                model = _robust(config, gtsam.noiseModel.Isotropic.Sigma(2, sig), RobustKernel.HUBER)
                builder.add("gravity", gtsam.AttitudeFactorPose3(X(kf.id), up, model, measured),
                            np.eye(2) / sig)
        bar.advance()

        # Phase 1: every factor but the inter-floor ones, so each floor's map is consistent
        # before floors are registered against each other.
        _bridge_components(builder, kfs, initial_poses, warnings)
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(config.max_iterations)
        params.setRelativeErrorTol(1e-7)
        params.setAbsoluteErrorTol(1e-9)
        optimizer = gtsam.LevenbergMarquardtOptimizer(builder.graph, values, params)
        result = optimizer.optimize()
        iterations = int(optimizer.iterations())
        bar.advance()

        # Phase 2: register adjacent floors on the phase-1 maps, add the factors, optimise again.
        matches: list[FloorMatch] = []
        floor_ids = sorted({k.floor_id for k in kfs if k.floor_id >= 0})
        if config.inter_floor_registration and len(floor_ids) > 1:
            phase1 = {i: np.asarray(result.atPose3(X(i)).matrix()) for i in ids}
            matches = _add_interfloor(builder, kfs, phase1, floor_ids, segmentation, config,
                                      executor)
            for m in matches:
                if not m.accepted:
                    warnings.append(f"graph: floors {m.lower}/{m.upper} not registered ({m.reason})")
            if any(m.accepted for m in matches):
                optimizer = gtsam.LevenbergMarquardtOptimizer(builder.graph, result, params)
                result = optimizer.optimize()
                iterations += int(optimizer.iterations())
        bar.advance()

    threshold = {d: float(chi2.ppf(config.outlier_chi2_p, d)) for d in (1, 2, 6)}
    for entry in builder.entries:
        stats = builder.stats[entry.kind]
        stats.error_initial += float(entry.factor.error(values))
        stats.error_final += float(entry.factor.error(result))
        residual = np.asarray(entry.factor.unwhitenedError(result), dtype=np.float64)
        d2 = float(np.sum((entry.sqrt_info @ residual) ** 2))
        stats.max_mahalanobis = max(stats.max_mahalanobis, math.sqrt(d2))
        if d2 > threshold.get(len(residual), float(chi2.ppf(config.outlier_chi2_p, len(residual)))):
            stats.outliers += 1

    poses = {i: np.asarray(result.atPose3(X(i)).matrix(), dtype=np.float64) for i in ids}
    by_id = {k.id: k for k in kfs}
    for ride in rides:
        if "keyframes" in ride:
            a, b = ride["keyframes"]
            lo, hi = _height_keys(by_id[a], by_id[b], config)
            ride["graph_height_change_m"] = round(_z(result, hi) - _z(result, lo), 4)
    height_model = calibration.to_json()
    if result.exists(SCALE):
        height_model["graph_scale"] = round(float(result.atDouble(SCALE)), 5)
        height_model["graph_offsets_m"] = {
            str(f): round(float(result.atDouble(U(f))), 4)
            for f in sorted({k.floor_id for k in kfs if k.floor_id >= 0}) if result.exists(U(f))
        }
    bias = {k: float(result.atDouble(B(k))) for k in range(len(kfs)) if result.exists(B(k))}
    return GraphResult(
        poses=poses,
        initial_poses=initial_poses,
        bias_m=bias,
        stats=builder.stats,
        floor_matches=matches,
        floor_z_m=_floor_z(kfs, poses),
        iterations=iterations,
        error_initial=float(builder.graph.error(values)),
        error_final=float(builder.graph.error(result)),
        seconds=time.perf_counter() - started,
        warnings=warnings,
        rides=rides,
        heights=height_model,
    )


def _add_barometer(
    builder: _Builder,
    values: Any,
    kfs: list[Keyframe],
    initial: dict[int, F64],
    pressure: PressureSeries | None,
    seg: FloorSegmentation | None,
    config: GraphConfig,
    temperature_k: float,
    warnings: list[str],
) -> None:
    if not config.barometer_factors:
        return
    if pressure is None or len(pressure) == 0:
        warnings.append("graph: no barometer, barometric factors skipped")
        return
    stamps = np.array([k.stamp_ns for k in kfs], dtype=np.int64)
    if config.baro_source == BaroSource.FILTERED and seg is not None and len(seg.stamp_ns) > 1:
        # The floors stage's offline-filtered trace: spikes and door/HVAC transients removed.
        filtered = PressureSeries(seg.stamp_ns, np.asarray(seg.height_filtered_m, dtype=np.float64))
        height = pressure_at(filtered, stamps, config.baro_window_s)
    else:
        p_pa = pressure_at(pressure, stamps, config.baro_window_s)
        height = pressure_to_height_m(p_pa, float(pressure.pressure_pa[0]), temperature_k)
    converter = gtsam.BarometricFactor()
    model = _robust(config, gtsam.noiseModel.Isotropic.Sigma(1, config.baro_sigma_m))
    for k, kf in enumerate(kfs):
        baro_kpa = float(converter.baroOut(float(height[k])))
        factor = gtsam.BarometricFactor(X(kf.id), B(k), baro_kpa, model)
        builder.add("barometer", factor, np.eye(1) / config.baro_sigma_m)
        values.insert(B(k), float(height[k] - initial[kf.id][2, 3]))
    builder.add(
        "bias_prior",
        gtsam.PriorFactorDouble(B(0), float(height[0] - initial[kfs[0].id][2, 3]),
                                gtsam.noiseModel.Isotropic.Sigma(1, 10.0)),
        np.eye(1) / 10.0,
    )
    for k in range(len(kfs) - 1):
        dt_s = max((kfs[k + 1].stamp_ns - kfs[k].stamp_ns) / 1e9, 1e-3)
        sig = config.bias_random_walk_m_sqrt_s * math.sqrt(dt_s)
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


def _ride_ends(kfs: list[Keyframe], start_ns: int, end_ns: int) -> tuple[Keyframe, Keyframe] | None:
    before = [k for k in kfs if k.stamp_ns <= start_ns]
    after = [k for k in kfs if k.stamp_ns >= end_ns]
    if not before or not after:
        return None
    return before[-1], after[0]


def _add_transitions(
    builder: _Builder,
    values: Any,
    kfs: list[Keyframe],
    initial: dict[int, F64],
    seg: FloorSegmentation | None,
    config: GraphConfig,
    imu: ImuSeries | None,
    walks: dict[tuple[int, int], _Walk],
    scale_prior_sigma: float | None,
    warnings: list[str],
) -> tuple[list[dict[str, Any]], Calibration]:
    """Per transition: its height change from the scale-true sensor (an elevator ride's from the
    IMU, a stair walk's from the lidar) and from the barometer, weighed by mfmap.graph.heights and
    added as z-only factors; for elevator rides x, y and yaw held (z free). Separate factors, so
    an x, y, yaw disagreement that the robust kernel turns down does not also turn down the height.
    Returns one report entry per transition and the barometer's calibration."""
    rides: list[dict[str, Any]] = []
    prior = (1.0, config.baro_scale_sigma if scale_prior_sigma is None else scale_prior_sigma)
    if seg is None:
        seg = FloorSegmentation((), (), np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0),
                                np.zeros(0, dtype=np.int32))
    yaw = math.radians(config.elevator_sigma_yaw_deg)
    sig_xy = config.elevator_sigma_xy_m
    tilt = _LOOSE_TILT_RAD
    trace = raw_trace(seg) if config.transition_window_s > 0 and len(seg.stamp_ns) > 0 else None
    items: list[TransitionHeights] = []
    keys: dict[int, tuple[int, int]] = {}
    walk_of: dict[int, _Walk] = {}
    for index, tr in enumerate(seg.transitions):
        ends = _ride_ends(kfs, tr.start_ns, tr.end_ns)
        entry: dict[str, Any] = {
            "kind": tr.kind.value,
            "from_floor": tr.from_floor,
            "to_floor": tr.to_floor,
            "start_s": round(tr.start_ns / 1e9, 3),
            "end_s": round(tr.end_ns / 1e9, 3),
            "baro_height_change_m": round(tr.height_change_m, 4),
        }
        rides.append(entry)
        if ends is None:
            entry["heights"] = "no keyframe before or after the transition"
            continue
        a, b = ends
        entry["keyframes"] = [a.id, b.id]
        keys[index] = _height_keys(a, b, config)
        item = TransitionHeights(index, tr.kind, tr.from_floor, tr.to_floor, None, None)
        if config.transition_height:
            baro_dz, baro_sigma = _transition_height(seg, index, config, entry, trace)
            item.baro = Measurement("barometer", baro_dz, baro_sigma)
        else:
            item.baro_reason = "off"
        if tr.kind == TransitionKind.ELEVATOR:
            item.scale_true, item.scale_true_reason = _imu_height(tr.start_ns, tr.end_ns, imu, config, entry)
        elif not config.walk_height:
            item.scale_true_reason = "off"
        elif (a.id, b.id) in walks:
            w = walks[(a.id, b.id)]
            item.scale_true = Measurement("lidar", w.height_change_m, w.sigma_m)
            entry["lidar_height_change_m"] = round(w.height_change_m, 4)
            entry["lidar_sigma_m"] = round(w.sigma_m, 4)
            walk_of[index] = w
        else:
            item.scale_true_reason = "the lidar odometry does not run across it"
        items.append(item)
        if config.elevator_continuity and tr.kind == TransitionKind.ELEVATOR:
            # The mapping stage holds x, y and yaw through the ride: the initial relative pose
            # is the measurement.
            measured = _relative_level(initial[a.id], initial[b.id], tr.height_change_m)
            # Cauchy: when the ride's ends disagree with the floors' registration by many sigma
            # (a keyframe at the cabin door with a wrong pose), the factor lets go instead of
            # bending the floor with a constant (Huber) pull.
            builder.between(
                "elevator", a.id, b.id, measured, [tilt, tilt, yaw, sig_xy, sig_xy, FREE_SIGMA],
                kernel=RobustKernel.CAUCHY,
            )

    start_floor = next((k.floor_id for k in kfs if k.floor_id >= 0), 0)
    calibration = heights.calibrate(items, prior, config.baro_offset_sigma_m)
    heights.decide(items, calibration, start_floor, config.height_gate_sigma)
    if calibration.usable and calibration.pairs > 0:
        # Again on the measurements kept, and decided again on that calibration.
        calibration = heights.calibrate(items, prior, config.baro_offset_sigma_m, used_only=True)
        heights.decide(items, calibration, start_floor, config.height_gate_sigma)
    warnings.extend(calibration.warnings)
    _add_heights(builder, values, items, keys, walk_of, calibration)
    if config.walk_height:
        # A walk the floors stage has no transition for (no barometer): the lidar's climb alone.
        matched = {(w.i, w.j) for w in walk_of.values()}
        for pair, walk in walks.items():
            if pair not in matched:
                builder.world_dz("walk_z", X(walk.i), X(walk.j), walk.height_change_m, walk.sigma_m, robust=True)
    for item in items:
        entry = rides[item.index]
        entry["heights_used"] = [m.source for m, used in ((item.scale_true, item.use_scale_true),
                                                          (item.baro, item.use_baro)) if m is not None and used]
        entry["heights"] = item.why
        if not entry["heights_used"]:
            warnings.append(f"graph: {item.label}: no height measurement used ({item.why}); its floors' "
                            "heights come from the others")
        elif item.scale_true is not None and not item.use_scale_true:
            warnings.append(f"graph: {item.label}: the {item.scale_true.source}'s height left out ({item.why})")
        elif item.baro is not None and item.use_scale_true and calibration.usable and not item.use_baro:
            warnings.append(f"graph: {item.label}: the barometer's height left out ({item.why})")
    return rides, calibration


def _add_heights(
    builder: _Builder,
    values: Any,
    items: list[TransitionHeights],
    keys: dict[int, tuple[int, int]],
    walk_of: dict[int, _Walk],
    cal: Calibration,
) -> None:
    """The accepted heights as factors: a scale-true one as a world-z change (robust), a
    barometric one through the scale and the two floors' offsets (variables with the
    calibration's priors):  z_b - z_a = s d - (u_b - u_a)."""
    used_baro = [it for it in items if it.use_baro and it.baro is not None]
    if used_baro:
        values.insert(SCALE, cal.scale)
        builder.add("baro_scale", gtsam.PriorFactorDouble(SCALE, cal.scale_prior[0],
                                                           gtsam.noiseModel.Isotropic.Sigma(1, cal.scale_prior[1])),
                    np.eye(1) / cal.scale_prior[1])
        sigma_o = max(cal.offset_sigma_m, 1e-3)
        for f in sorted({f for it in used_baro for f in (it.from_floor, it.to_floor)}):
            values.insert(U(f), 0.0)
            builder.add("baro_offset", gtsam.PriorFactorDouble(U(f), 0.0, gtsam.noiseModel.Isotropic.Sigma(1, sigma_o)),
                        np.eye(1) / sigma_o)
    for it in items:
        key_a, key_b = keys[it.index]
        if it.use_scale_true and it.scale_true is not None:
            kind = "walk_z" if it.index in walk_of else "imu_ride"
            builder.world_dz(kind, key_a, key_b, it.scale_true.height_change_m, it.scale_true.sigma_m,
                             robust=True)
        elif it.scale_true is not None:
            builder.reject("imu_ride" if it.scale_true.source == "imu" else "walk_z")
        if it.use_baro and it.baro is not None:
            sigma = max(cal.scale * it.baro.sigma_m, 1e-4)
            builder.add("transition_z", _baro_height_factor(key_a, key_b, U(it.from_floor), U(it.to_floor),
                                                            it.baro.height_change_m, sigma, builder.config),
                        np.eye(1) / sigma)
        elif it.baro is not None:
            builder.reject("transition_z")


@dataclass(frozen=True)
class _Walk:
    """A stair walk's height change as the lidar odometry measured it: its relative translation
    turned into the world by the mapping stage's pose of the keyframe before it (the frame the
    odometry measured it in; gravity levelling that keyframe must not move the climb)."""

    i: int
    j: int
    sigma_m: float
    height_change_m: float

    @classmethod
    def of(cls, edge: PoseEdge, initial: dict[int, F64], sigma_m: float) -> _Walk:
        dz = float((initial[edge.i][:3, :3] @ np.asarray(edge.measured)[:3, 3])[2])
        return cls(edge.i, edge.j, sigma_m, dz)


def _z_with_jacobian(values: Any, key: int) -> tuple[float, np.ndarray]:
    """World z of a floor level Fl(id) or a keyframe X(id), and its Jacobian."""
    if _is_level(key):
        return -float(values.atDouble(key)), np.array([[-1.0]])
    pose = values.atPose3(key)
    return float(pose.z()), np.concatenate([np.zeros(3), pose.rotation().matrix()[2]]).reshape(1, 6)


def _baro_height_factor(key_a: int, key_b: int, key_ua: int, key_ub: int, d_m: float, sigma_m: float,
                        config: GraphConfig) -> Any:
    """error = (z_b - z_a) - s d + (u_b - u_a), z from two floor levels or two keyframes."""
    model = _robust(config, gtsam.noiseModel.Isotropic.Sigma(1, sigma_m))
    z_and_jacobian = _z_with_jacobian

    def error(this: Any, values: Any, jacobians: list[np.ndarray] | None) -> np.ndarray:
        za, ja = z_and_jacobian(values, key_a)
        zb, jb = z_and_jacobian(values, key_b)
        s = float(values.atDouble(SCALE))
        ua, ub = float(values.atDouble(key_ua)), float(values.atDouble(key_ub))
        if jacobians is not None:
            jacobians[0] = -ja
            jacobians[1] = jb
            jacobians[2] = np.array([[-d_m]])
            jacobians[3] = np.array([[-1.0]])
            jacobians[4] = np.array([[1.0]])
        return np.array([zb - za - s * d_m + (ub - ua)])

    if key_ua == key_ub:  # a transition back to the same floor: its offsets cancel
        def same(this: Any, values: Any, jacobians: list[np.ndarray] | None) -> np.ndarray:
            za, ja = z_and_jacobian(values, key_a)
            zb, jb = z_and_jacobian(values, key_b)
            s = float(values.atDouble(SCALE))
            if jacobians is not None:
                jacobians[0], jacobians[1], jacobians[2] = -ja, jb, np.array([[-d_m]])
            return np.array([zb - za - s * d_m])

        return gtsam.CustomFactor(model, [key_a, key_b, SCALE], same)
    return gtsam.CustomFactor(model, [key_a, key_b, SCALE, key_ua, key_ub], error)


def _height_keys(a: Keyframe, b: Keyframe, config: GraphConfig) -> tuple[int, int]:
    """Where a transition's height factors act, from its keyframes a (before) and b (after).

    A ground robot stands on the floors at both ends: the height change is between the floors'
    levels, not between two keyframes, which the floors' ties (2 cm each) would let it bend
    locally instead of moving the floor (elevation error over seeds 0-2 of two-floor,
    three-floor-revisit and stairs: 1.6 -> 1.1 cm RMS). The keyframes without the ties.
    """
    if config.same_floor_height_tie and a.floor_id >= 0 and b.floor_id >= 0 and a.floor_id != b.floor_id:
        return Fl(a.floor_id), Fl(b.floor_id)
    return X(a.id), X(b.id)


def _transition_height(
    seg: FloorSegmentation, index: int, config: GraphConfig, entry: dict[str, Any], trace: RawTrace | None
) -> tuple[float, float]:
    """The barometer's height change across transition `index` and its sigma: the fit on the raw
    trace either side (mfmap.floors.levels.level_change) where it runs, else the floors stage's."""
    tr = seg.transitions[index]
    if config.transition_window_s > 0:
        fit = level_change(seg, index, config.transition_window_s, trace=trace)
        entry["baro_fit"] = fit.reason
        if fit.height_change_m is not None:
            sigma = math.hypot(fit.sigma_m, BARO_MODEL_SIGMA_M)
            entry["baro_height_change_m"] = round(fit.height_change_m, 4)
            entry["baro_sigma_m"] = round(sigma, 4)
            entry["baro_window_s"] = round(fit.window_s, 1)
            entry["floors_height_change_m"] = round(tr.height_change_m, 4)
            return fit.height_change_m, sigma
    entry["baro_sigma_m"] = config.transition_sigma_z_m
    return tr.height_change_m, config.transition_sigma_z_m


def _imu_height(
    start_ns: int,
    end_ns: int,
    imu: ImuSeries | None,
    config: GraphConfig,
    entry: dict[str, Any],
) -> tuple[Measurement | None, str]:
    """The IMU's height change across one ride (mfmap.graph.ride), or why there is none."""
    if not config.imu_ride_height:
        entry["imu"] = "off"
        return None, "off"
    ride = ride_height(imu, start_ns, end_ns)
    entry["imu"] = ride.reason
    if ride.height_change_m is None:
        return None, ride.reason
    entry["imu_height_change_m"] = round(ride.height_change_m, 4)
    entry["imu_sigma_m"] = round(ride.sigma_m, 4)
    entry["imu_window_s"] = round((ride.end_ns - ride.start_ns) / 1e9, 3)
    entry["imu_bias_m_s2"] = round(ride.bias_m_s2, 4)
    entry["imu_legs"] = ride.legs
    return Measurement("imu", ride.height_change_m, ride.sigma_m), "ok"


def _add_height_ties(
    builder: _Builder, values: Any, kfs: list[Keyframe], initial: dict[int, F64]
) -> None:
    """Every keyframe of a floor shares that floor's z: a floor level f<id> tied to each.

    A star, not a chain, so the tie does not let z wander from keyframe to keyframe. Each tie is
    a world-z factor (robust; LEVEL_KPA). A BetweenFactorPose3 with only z tight, as before,
    measured z in the floor variable's frame, through SE(3)'s log that mixes rotation into
    translation: a keyframe's tilt times its distance from the floor variable (tens of metres)
    became centimetres of height, and put tiny-2d's keyframes 6 cm off their floor's level.
    """
    sig = builder.config.height_tie_sigma_m
    model = _robust(builder.config, gtsam.noiseModel.Isotropic.Sigma(1, sig))
    for kf in kfs:
        if kf.floor_id < 0:
            continue
        if not values.exists(Fl(kf.floor_id)):
            values.insert(Fl(kf.floor_id), -float(initial[kf.id][2, 3]))
        builder.add("height_tie", gtsam.BarometricFactor(X(kf.id), Fl(kf.floor_id), LEVEL_KPA, model), np.eye(1) / sig)


def _anchors(
    kfs: list[Keyframe], lower: int, upper: int, seg: FloorSegmentation | None
) -> tuple[Keyframe, Keyframe]:
    """The middle keyframes of the two visits joined by a ride between the floors.

    Not the keyframes at the ride itself: those are taken in and at the cabin, where the mapping
    stage's poses are least reliable, and an anchor there would carry its error to the floor.
    """
    low = [k for k in kfs if k.floor_id == lower]
    up = [k for k in kfs if k.floor_id == upper]

    def middle_of_visit(cands: list[Keyframe], near_ns: int) -> Keyframe:
        closest = min(cands, key=lambda k: abs(k.stamp_ns - near_ns))
        same = [k for k in cands if k.visit == closest.visit]
        return same[len(same) // 2]

    if seg is not None:
        for tr in seg.transitions:
            if {tr.from_floor, tr.to_floor} == {lower, upper}:
                mid = (tr.start_ns + tr.end_ns) // 2
                return middle_of_visit(low, mid), middle_of_visit(up, mid)
    return low[len(low) // 2], up[len(up) // 2]


def _add_interfloor(
    builder: _Builder,
    kfs: list[Keyframe],
    initial: dict[int, F64],
    floor_ids: list[int],
    seg: FloorSegmentation | None,
    config: GraphConfig,
    executor: Executor | None = None,
) -> list[FloorMatch]:
    floor_z = _floor_z(kfs, initial)
    clouds = {
        f: floor_points(kfs, initial, f, config.interfloor_band_m, floor_z[f]) for f in floor_ids
    }
    if any(len(c) < 200 for c in clouds.values()):
        # A 2D scanner's returns all lie at its own height, usually below the band: use them all.
        clouds = {f: floor_points(kfs, initial, f, (-1.0, 3.0), floor_z[f]) for f in floor_ids}
    yaw = math.radians(config.interfloor_sigma_yaw_deg)
    sig_xy = config.interfloor_sigma_xy_m
    tilt = _LOOSE_TILT_RAD
    register = functools.partial(
        register_floors,
        voxel_m=config.interfloor_voxel_m,
        min_fitness=config.interfloor_min_fitness,
        ambiguity_ratio=config.interfloor_ambiguity_ratio,
        max_correction_m=config.interfloor_max_correction_m,
        max_correction_deg=config.interfloor_max_correction_deg,
        seed=config.seed,
    )
    pairs = list(itertools.pairwise(floor_ids))
    if executor is not None and len(pairs) > 1:
        # Each pair on its own (one thread per process, the same seed): the same matches.
        futures = [executor.submit(register, clouds[lower], clouds[upper], lower, upper)
                   for lower, upper in pairs]
        matches = [future.result() for future in futures]
    else:
        matches = [register(clouds[lower], clouds[upper], lower, upper) for lower, upper in pairs]
    for (lower, upper), match in zip(pairs, matches, strict=True):
        if not match.accepted:
            builder.reject("interfloor")
            continue
        a, b = _anchors(kfs, lower, upper, seg)
        target_b = match.correction @ initial[b.id]
        measured = _relative_level(initial[a.id], target_b, None)
        builder.between(
            "interfloor", a.id, b.id, measured, [tilt, tilt, yaw, sig_xy, sig_xy, FREE_SIGMA],
            robust=False,
        )
    return matches


def _bridge_components(
    builder: _Builder, kfs: list[Keyframe], initial: dict[int, F64], warnings: list[str]
) -> None:
    """Link parts of the graph nothing else connects, weakly, at their initial relative pose."""
    ids = [k.id for k in kfs]
    comp = _components(ids, builder.links)
    seen = {comp[ids[0]]}
    for prev, kf in itertools.pairwise(kfs):
        root = comp[kf.id]
        if root in seen:
            continue
        seen.add(root)
        measured = _relative_level(initial[prev.id], initial[kf.id], None)
        builder.between("bridge", prev.id, kf.id, measured, [0.1, 0.1, 0.1, 1.0, 1.0, FREE_SIGMA], robust=False)
        warnings.append(
            f"graph: keyframes {prev.id} and {kf.id} had no measurement linking them; "
            "bridged weakly at the mapping stage's relative pose"
        )


