"""The world-frame height factor of a transition: a tilted end pose does not bias the height."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import X

from mfmap.graph.config import GraphConfig
from mfmap.graph.optimize import _Builder


def _solve(pitch_deg: float, world_dz: bool) -> float:
    """z_b - z_a after optimising: a fixed and pitched, b 7 m ahead (a stair walk's run)."""
    builder = _Builder(GraphConfig())
    pitch = gtsam.Rot3.Ry(math.radians(pitch_deg))
    a = gtsam.Pose3(pitch, np.zeros(3))
    builder.add("prior", gtsam.PriorFactorPose3(X(0), a, gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)),
                np.eye(6))
    # b's x, y and rotation held by a prior; only its height is left to the transition factor.
    b_guess = gtsam.Pose3(gtsam.Rot3(), np.array([7.0, 0.0, 3.0]))
    sigmas = np.array([1e-6, 1e-6, 1e-6, 1e-6, 1e-6, 1e3])
    builder.add("prior", gtsam.PriorFactorPose3(X(1), b_guess, gtsam.noiseModel.Diagonal.Sigmas(sigmas)),
                np.eye(6))
    if world_dz:
        builder.world_dz("transition_z", X(0), X(1), 3.5, 0.03)
    else:  # the old way: a between factor, z tight in a's frame, the rest free
        measured = np.eye(4)  # b relative to a, as a level a would see it
        measured[:3, 3] = [7.0, 0.0, 3.5]
        builder.between("transition_z", 0, 1, measured, [1e3, 1e3, 1e3, 1e5, 1e5, 0.03], robust=False)
    values = gtsam.Values()
    values.insert(X(0), a)
    values.insert(X(1), b_guess)
    result = gtsam.LevenbergMarquardtOptimizer(builder.graph, values).optimize()
    return float(result.atPose3(X(1)).z() - result.atPose3(X(0)).z())


@pytest.mark.parametrize("pitch_deg", [0.0, 0.3, -1.0])
def test_height_change_is_world_z_whatever_the_tilt(pitch_deg: float) -> None:
    assert _solve(pitch_deg, world_dz=True) == pytest.approx(3.5, abs=1e-6)


def test_a_between_factor_turns_tilt_into_height() -> None:
    # What the factor replaces: z in a's frame picks up 7 m x sin(0.3 deg) = 3.7 cm.
    assert abs(_solve(0.3, world_dz=False) - 3.5) == pytest.approx(7.0 * math.sin(math.radians(0.3)), abs=2e-3)
