"""The building's one factor graph over every log: each log's own graph, its variables moved
into the building frame, and factors between the logs from the registration of shared floors.

Each log's factors are the ones its single-log build optimises (`mfmap.multilog.logs`), rekeyed
so the logs' variables stay apart (keyframe poses, barometer biases, scales, floor offsets and
levels). Only two of them hold a log to its own frame: the prior on its first keyframe and the
prior on its first barometer bias. The first log keeps them: its start is the building frame.
The others drop them; their frames are held instead by between-keyframe factors to the logs
placed before them, on each floor they share: a keyframe of the log and the nearest keyframe
already in the building, at the relative pose the floors' registration gives (x, y, yaw from
the registration, z from the floors' levels: both stand on the same slab). Every other factor
(between, barometric, height, gravity) is relative, so the log's solution moved by its rigid,
gravity-aligned transform still satisfies it; that is where the building's graph starts.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import gtsam
import numpy as np

from mfmap.graph.config import GraphConfig, RobustKernel
from mfmap.graph.factors import LOOSE_TILT_RAD, Builder, FactorStats, X, robust_model
from mfmap.multilog.logs import LogRun
from mfmap.multilog.match import PairFit
from mfmap.types import F64

# Keys of log i are its own keys with i * LOG_STRIDE added to their index: keyframe ids, bias
# indices and floor ids stay far below it.
LOG_STRIDE = 10_000_000
# Factors that fix a log to its own frame (see the module docstring).
_FRAME_KINDS = frozenset({"prior", "bias_prior"})
# Keyframe pairs per shared floor, spread over the log's keyframes on it.
PAIRS_PER_FLOOR = 8


@dataclass(frozen=True)
class InterLogSigmas:
    """The registration of two logs' floors as a factor: x, y and z in metres, yaw in degrees,
    shared by PAIRS_PER_FLOOR factors (each weighs 1/PAIRS_PER_FLOOR of it)."""

    xy_m: float = 0.01
    z_m: float = 0.01
    yaw_deg: float = 0.05


def key_of(log_index: int, key: int) -> int:
    """A log's own variable key in the building's graph."""
    if log_index == 0:
        return key
    sym = gtsam.Symbol(key)
    return int(gtsam.symbol(chr(sym.chr()), sym.index() + log_index * LOG_STRIDE))


@dataclass
class JointGraph:
    """The building's graph: factors, starting values, and the keyframe pairs between logs."""

    config: GraphConfig
    graph: Any = field(default_factory=gtsam.NonlinearFactorGraph)
    values: Any = field(default_factory=gtsam.Values)
    stats: dict[str, FactorStats] = field(default_factory=dict)
    links: list[dict[str, Any]] = field(default_factory=list)
    kinds: list[str] = field(default_factory=list)  # per factor, in the graph's order

    def add(self, kind: str, factor: Any) -> None:
        self.graph.add(factor)
        self.kinds.append(kind)
        self.stats.setdefault(kind, FactorStats()).count += 1

    def errors(self, values: Any, final: bool) -> None:
        """Each kind's summed error at `values` into its statistics (before or after)."""
        for k, kind in enumerate(self.kinds):
            error = float(self.graph.at(k).error(values))
            if final:
                self.stats[kind].error_final += error
            else:
                self.stats[kind].error_initial += error

    def add_log(self, run: LogRun, transform: F64) -> None:
        """The log's factors and its solution moved by `transform` (log -> building frame)."""
        builder: Builder = run.graph.builder
        i = run.index
        for entry in builder.entries:
            if i > 0 and entry.kind in _FRAME_KINDS:
                continue
            factor = entry.factor
            if i > 0:
                own = factor.keys()  # a gtsam KeyVector
                keys = [key_of(i, k) for k in own]
                # A Python factor cannot be cloned with new keys (its error reads its own).
                factor = (_renamed(factor, keys) if isinstance(factor, gtsam.CustomFactor)
                          else factor.rekey(keys))
            self.add(entry.kind, factor)
        dz = float(transform[2, 3])
        result = run.graph.result
        move = gtsam.Pose3(transform)
        keys = result.keys()  # a gtsam KeyVector
        for key in keys:
            new = key_of(i, key)
            chr_ = chr(gtsam.Symbol(key).chr())
            if chr_ == "x":
                self.values.insert(new, move.compose(result.atPose3(key)))
            elif chr_ == "b":
                self.values.insert(new, result.atDouble(key) - dz)  # bias = height - z
            elif chr_ == "f":
                self.values.insert(new, result.atDouble(key) - dz)  # a level holds minus its z
            else:
                self.values.insert(new, result.atDouble(key))

    def pose(self, log_index: int, keyframe: int) -> F64:
        return np.asarray(self.values.atPose3(key_of(log_index, X(keyframe))).matrix())

    def link(self, run: LogRun, pair: PairFit, placed: dict[int, list[tuple[int, int]]],
             level_m: float, log_level_m: float, sigmas: InterLogSigmas) -> None:
        """Factors between the log's keyframes on a shared floor and the nearest keyframes of
        the logs placed before (`placed`: building floor -> [(log index, keyframe id)])."""
        mine = [k for k in run.graph.keyframes if k.floor_id == pair.log_floor]
        theirs = placed.get(pair.building_floor, [])
        if not mine or not theirs:
            return
        frame = pair.transform.copy()
        frame[2, 3] = level_m - log_level_m
        their_xy = np.array([self.pose(li, kid)[:2, 3] for li, kid in theirs])
        chosen = np.unique(np.linspace(0, len(mine) - 1, min(PAIRS_PER_FLOOR, len(mine))).astype(int))
        model = _model(self.config, sigmas, len(chosen))
        for idx in chosen:
            kf = mine[int(idx)]
            pose_a = frame @ run.graph.poses[kf.id]  # the log's keyframe, as registered
            near = int(np.argmin(np.hypot(*(their_xy - pose_a[:2, 3]).T)))
            li, kid = theirs[near]
            measured = np.linalg.inv(self.pose(li, kid)) @ pose_a
            self.add("inter_log", gtsam.BetweenFactorPose3(
                key_of(li, X(kid)), key_of(run.index, X(kf.id)), gtsam.Pose3(measured), model))
            self.links.append({"log": run.index, "keyframe": kf.id, "to_log": li,
                               "to_keyframe": kid, "building_floor": pair.building_floor,
                               "distance_m": round(float(np.linalg.norm(measured[:2, 3])), 3)})

    def optimise(self, max_iterations: int) -> tuple[Any, int, float, float, float]:
        """Levenberg-Marquardt from the logs' own solutions; the result, the iterations, the
        errors before and after, and the seconds."""
        started = time.perf_counter()
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(max_iterations)
        params.setRelativeErrorTol(1e-7)
        params.setAbsoluteErrorTol(1e-9)
        optimizer = gtsam.LevenbergMarquardtOptimizer(self.graph, self.values, params)
        result = optimizer.optimize()
        return (result, int(optimizer.iterations()), float(self.graph.error(self.values)),
                float(self.graph.error(result)), time.perf_counter() - started)


# Step of the numerical Jacobians of a renamed Python factor (radians, metres): its errors are
# smooth (heights, scale and offsets), central differences are exact to ~1e-12.
_STEP = 1e-6


def _renamed(factor: Any, keys: list[int]) -> Any:
    """A CustomFactor on `keys` whose error is `factor`'s on its own keys, Jacobians by central
    differences (the few height factors of rides and stairs)."""
    own = list(factor.keys())

    def local(values: Any, moved: tuple[int, Any] | None = None) -> Any:
        out = gtsam.Values()
        for old, new in zip(own, keys, strict=True):
            pose = chr(gtsam.Symbol(old).chr()) == "x"
            value = values.atPose3(new) if pose else values.atDouble(new)
            if moved is not None and moved[0] == old:
                value = moved[1]
            if pose:
                out.insert(old, value)
            else:
                out.insert(old, float(value))
        return out

    def error(this: Any, values: Any, jacobians: list[np.ndarray] | None) -> np.ndarray:
        here = local(values)
        err = np.asarray(factor.unwhitenedError(here), dtype=np.float64)
        if jacobians is not None:
            for n, old in enumerate(own):
                jacobians[n] = _jacobian(factor, values, local, old, keys[n], len(err))
        return err

    return gtsam.CustomFactor(factor.noiseModel(), keys, error)


def _jacobian(factor: Any, values: Any, local: Any, old: int, new: int, rows: int) -> np.ndarray:
    pose = chr(gtsam.Symbol(old).chr()) == "x"
    dim = 6 if pose else 1
    jac = np.zeros((rows, dim))
    for d in range(dim):
        step = np.zeros(dim)
        step[d] = _STEP
        sides = []
        for sign in (1.0, -1.0):
            moved = (values.atPose3(new).retract(sign * step) if pose
                     else values.atDouble(new) + sign * _STEP)
            sides.append(np.asarray(factor.unwhitenedError(local(values, (old, moved)))))
        jac[:, d] = (sides[0] - sides[1]) / (2.0 * _STEP)
    return jac


def _model(config: GraphConfig, sigmas: InterLogSigmas, shares: int) -> Any:
    """gtsam order (rx, ry, rz, tx, ty, tz); the registration's weight shared by `shares`."""
    scale = math.sqrt(shares)
    sig = np.array([LOOSE_TILT_RAD, LOOSE_TILT_RAD, math.radians(sigmas.yaw_deg) * scale,
                    sigmas.xy_m * scale, sigmas.xy_m * scale, sigmas.z_m * scale])
    return robust_model(config, gtsam.noiseModel.Diagonal.Sigmas(sig), RobustKernel.HUBER)


__all__ = ["LOG_STRIDE", "InterLogSigmas", "JointGraph", "key_of"]
