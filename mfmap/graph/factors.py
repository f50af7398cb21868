"""The graph's variables and the factor builder: keys, robust models, world-z factors.

Keys: Pose3 X(keyframe id), a barometer bias B(k) per keyframe in time order, the barometer's
height scale SCALE, a floor's pressure offset U(floor) and a floor's level Fl(floor).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import gtsam
import numpy as np

from mfmap.graph.config import GraphConfig, RobustKernel
from mfmap.types import F64

# A sigma that leaves a component nearly free (z across a ride, which the barometer sets) while
# keeping the problem well posed when the barometer is switched off.
FREE_SIGMA = 10.0


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
# and its floor, in C++. Python CustomFactors for the ties would cost 10 s of graph time on the
# simulator's `long` log.
LEVEL_KPA = float(gtsam.BarometricFactor().baroOut(0.0))


def is_level(key: int) -> bool:
    return gtsam.Symbol(key).chr() == ord("f")


def world_z(values: Any, key: int) -> float:
    """World z of a keyframe X(id) or a floor level Fl(id)."""
    return -float(values.atDouble(key)) if is_level(key) else float(values.atPose3(key).z())


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
class Entry:
    kind: str
    factor: Any
    sqrt_info: F64  # whitening of the unwhitened error (Mahalanobis for outlier counting)


# Roll and pitch of the ride and inter-floor factors: loose, the gravity factors set the tilt.
LOOSE_TILT_RAD = math.radians(5.0)


def robust_model(config: GraphConfig, model: Any, kernel_name: RobustKernel | None = None) -> Any:
    kernel: Any
    if (kernel_name or config.robust.kernel) == RobustKernel.CAUCHY:
        kernel = gtsam.noiseModel.mEstimator.Cauchy.Create(config.robust.k)
    else:
        kernel = gtsam.noiseModel.mEstimator.Huber.Create(config.robust.k)
    return gtsam.noiseModel.Robust.Create(kernel, model)


def sqrt_info_from_sigmas(sigmas: F64) -> F64:
    return np.diag(1.0 / np.asarray(sigmas, dtype=np.float64))


def relative_level(pose_a: F64, pose_b: F64, dz_world_m: float | None) -> F64:
    """pose_a^-1 pose_b, with the world height change replaced by dz_world_m when given."""
    b = pose_b.copy()
    if dz_world_m is not None:
        b[2, 3] = pose_a[2, 3] + dz_world_m
    return np.asarray(np.linalg.inv(pose_a) @ b)


class Builder:
    def __init__(self, config: GraphConfig) -> None:
        self.config = config
        self.graph = gtsam.NonlinearFactorGraph()
        self.entries: list[Entry] = []
        self.stats: dict[str, FactorStats] = {}
        self.links: list[tuple[int, int]] = []

    def add(self, kind: str, factor: Any, sqrt_info: F64) -> None:
        self.graph.add(factor)
        self.entries.append(Entry(kind, factor, sqrt_info))
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
            model = robust_model(self.config, model, kernel)
        self.add(kind, gtsam.BetweenFactorPose3(X(i), X(j), gtsam.Pose3(measured), model), sqrt_info_from_sigmas(sig))
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
            model = robust_model(self.config, model)
        if is_level(key_i) and is_level(key_j):
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


def edge_model(config: GraphConfig, information: F64, kernel_name: RobustKernel) -> tuple[Any, F64]:
    info = 0.5 * (information + information.T)
    # Guard against a singular matrix from the mapping stage: floor the eigenvalues.
    w, v = np.linalg.eigh(info)
    w = np.maximum(w, 1e-6)
    info = (v * w) @ v.T
    sqrt_info = np.asarray(np.linalg.cholesky(info).T)
    return robust_model(config, gtsam.noiseModel.Gaussian.Information(info), kernel_name), sqrt_info


def _z_with_jacobian(values: Any, key: int) -> tuple[float, np.ndarray]:
    """World z of a floor level Fl(id) or a keyframe X(id), and its Jacobian."""
    if is_level(key):
        return -float(values.atDouble(key)), np.array([[-1.0]])
    pose = values.atPose3(key)
    return float(pose.z()), np.concatenate([np.zeros(3), pose.rotation().matrix()[2]]).reshape(1, 6)


def baro_height_factor(key_a: int, key_b: int, key_ua: int, key_ub: int, d_m: float, sigma_m: float,
                        config: GraphConfig) -> Any:
    """error = (z_b - z_a) - s d + (u_b - u_a), z from two floor levels or two keyframes."""
    model = robust_model(config, gtsam.noiseModel.Isotropic.Sigma(1, sigma_m))
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
