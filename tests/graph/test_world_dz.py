"""The world-frame height factor of a transition: a tilted end pose does not bias the height."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import X

from mfmap.graph.config import GraphConfig
from mfmap.graph.factors import Builder


def _solve(pitch_deg: float, world_dz: bool) -> float:
    """z_b - z_a after optimising: a fixed and pitched, b 7 m ahead (a stair walk's run)."""
    builder = Builder(GraphConfig())
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


def _walk(pitch_deg: float) -> tuple[float, dict[str, int]]:
    """A stair walk between keyframes 1 and 2 (different visits), 7 m ahead and 3.5 m up. The
    lidar odometry had keyframe 1 pitched by pitch_deg; gravity measures every keyframe level,
    and the odometry's turns are loose (5 deg), so the graph levels it. Keyframe 0, a metre
    before it, holds the prior. Returns the optimised height change across the walk and the
    factor counts."""
    from mfmap.graph.optimize import optimize_building
    from mfmap.mapping.geometry import inverse
    from mfmap.types import Keyframe, PoseEdge

    first = np.eye(4)
    first[0, 3] = -1.0
    start = np.eye(4)
    start[:3, :3] = gtsam.Rot3.Ry(math.radians(pitch_deg)).matrix()
    end = np.eye(4)
    end[:3, 3] = [7.0, 0.0, 3.5]
    empty = np.zeros((0, 3), np.float32)
    kfs = [Keyframe(0, 0, 0, 0, first, empty, 1.0, 0.0), Keyframe(1, 1_000_000_000, 0, 0, start, empty, 1.0, 0.0),
           Keyframe(2, 20_000_000_000, 1, 1, end, empty, 1.0, 0.0)]
    loose_turn = math.radians(5.0) ** -2
    information = np.diag([loose_turn] * 3 + [2500.0, 2500.0, 400.0])  # 5 cm in z, as on a walk
    edges = [PoseEdge(0, 1, inverse(first) @ start, information, "odometry"),
             PoseEdge(1, 2, inverse(start) @ end, information, "odometry")]
    up = np.array([0.0, 0.0, 1.0])
    result = optimize_building(kfs, edges, None, None, GraphConfig(), gravity_body={k.id: up for k in kfs})
    assert math.degrees(math.acos(min(result.poses[1][2, 2], 1.0))) < 0.05  # levelled
    return float(result.poses[2][2, 3] - result.poses[1][2, 3]), {k: s.count for k, s in result.stats.items()}


@pytest.mark.parametrize("pitch_deg", [0.0, 0.4])
def test_a_stair_walk_climbs_its_world_height_whatever_the_first_keyframes_tilt(pitch_deg: float) -> None:
    """The odometry's own pitch at the walk's start must not come back as height once gravity
    levels that keyframe: z in its frame would be 7 m x sin(0.4 deg) = 4.9 cm off."""
    dz, counts = _walk(pitch_deg)
    assert dz == pytest.approx(3.5, abs=2e-3)
    assert counts["walk_z"] == 1
