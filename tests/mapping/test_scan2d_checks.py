"""The 2D path's checks: the matcher's gyro cross-check of heading, and loop verification by a
fit in the plane with a degeneracy check that rejects a corridor."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from mfmap.mapping.config import LoopsConfig, MappingConfig
from mfmap.mapping.geometry import yaw_pose, yaw_rad
from mfmap.mapping.loops import LoopCloser
from mfmap.mapping.odometry import AdaptiveThreshold
from mfmap.mapping.scan2d import Scan2DMatcher


def _walls(segments: list[tuple[float, float, float, float]], step_m: float = 0.02) -> np.ndarray[Any, Any]:
    """Points every `step_m` along line segments (x0, y0, x1, y1), on the scan plane (z = 0.3)."""
    out = []
    for x0, y0, x1, y1 in segments:
        n = max(2, int(math.hypot(x1 - x0, y1 - y0) / step_m))
        s = np.linspace(0.0, 1.0, n)
        out.append(np.stack([x0 + s * (x1 - x0), y0 + s * (y1 - y0), np.full(n, 0.3)], axis=1))
    return np.concatenate(out)


ROOM = [(-4, -3, 5, -3), (5, -3, 5, 4), (5, 4, -4, 4), (-4, 4, -4, -3), (1, 1, 2, 1), (2, 1, 2, 2.5)]
CORRIDOR = [(-15, -1, 15, -1), (-15, 1, 15, 1)]


def _seen_from(points: np.ndarray[Any, Any], pose: np.ndarray[Any, Any], rng: np.random.Generator,
               noise_m: float = 0.005) -> np.ndarray[Any, Any]:
    """The world points in the base frame at `pose`, with range noise."""
    local = (points - pose[:3, 3]) @ pose[:3, :3]
    local[:, :2] += rng.normal(0.0, noise_m, (len(local), 2))
    return local


def _matcher(limit_deg: float) -> Scan2DMatcher:
    return Scan2DMatcher(0.05, 0.05, 10, AdaptiveThreshold(1.0, 0.0, 30.0, 0.4), 30,
                         max_gyro_disagreement_deg=limit_deg, low_fitness=0.0, max_overruled=2)


def test_gyro_keeps_the_heading_a_registration_turns_away_from() -> None:
    """The map is the room; the scan is taken 1 degree further turned than the gyro predicts.
    With the gyro's prediction the heading stays the gyro's (x, y fitted at it), until the
    registrations keep disagreeing for longer than `max_overruled`; without it, it turns."""
    rng = np.random.default_rng(3)
    world = _walls(ROOM)
    truth = yaw_pose(math.radians(1.0), np.array([0.4, -0.2, 0.0]))
    predicted = yaw_pose(0.0, np.array([0.35, -0.15, 0.0]))
    scan = _seen_from(world, truth, rng)
    for gyro_prior, limit in ((False, 0.2), (True, 0.0), (True, 0.2)):
        matcher = _matcher(limit)
        matcher.add_keyframe(world, np.eye(4))
        match = matcher.match(scan, predicted, gyro_prior=gyro_prior)
        heading = math.degrees(yaw_rad(match.pose))
        if gyro_prior and limit > 0:
            assert match.registered is False and matcher.overruled == 1
            assert heading == 0.0
            # x, y solved at the held heading, not left at the prediction.
            assert np.hypot(*(match.pose[:2, 3] - predicted[:2, 3])) > 0.02
        else:
            assert match.registered and matcher.overruled == 0
            assert abs(heading - 1.0) < 0.05
            np.testing.assert_allclose(match.pose[:2, 3], truth[:2, 3], atol=0.01)
    # Three disagreeing scans in a row: the third is the registration's again.
    matcher = _matcher(0.2)
    matcher.add_keyframe(world, np.eye(4))
    results = [matcher.match(scan, predicted, gyro_prior=True) for _ in range(3)]
    assert [r.registered for r in results] == [False, False, True]


def _keyframe_clouds(segments: list[tuple[float, float, float, float]], a: np.ndarray[Any, Any],
                     b: np.ndarray[Any, Any], seed: int) -> tuple[np.ndarray[Any, Any], np.ndarray[Any, Any]]:
    rng = np.random.default_rng(seed)
    world = _walls(segments)
    # What each keyframe sees: the walls within 12 m.
    near_a = world[np.hypot(*(world[:, :2] - a[:2, 3]).T) < 12]
    near_b = world[np.hypot(*(world[:, :2] - b[:2, 3]).T) < 12]
    return _seen_from(near_a, a, rng), _seen_from(near_b, b, rng)


def test_2d_loop_verified_in_the_plane() -> None:
    a = yaw_pose(0.3, np.array([0.5, 0.2, 0.0]))
    b = yaw_pose(-0.4, np.array([2.5, -1.0, 0.0]))
    target, source = _keyframe_clouds(ROOM, a, b, 0)
    true_rel = np.linalg.inv(a) @ b
    # Drift: the guess is 0.3 m and 4 degrees off.
    guess = true_rel @ yaw_pose(math.radians(4.0), np.array([0.3, -0.2, 0.0]))
    loops = LoopCloser(MappingConfig(), planar=True)
    check = loops.verify_2d(target, source, guess)
    assert check.accepted, check.reason
    assert check.registration is not None
    found = check.registration.transform
    np.testing.assert_allclose(found[:2, 3], true_rel[:2, 3], atol=0.01)
    assert abs(math.degrees(yaw_rad(found) - yaw_rad(true_rel))) < 0.1
    assert found[2, 3] == 0.0
    # A guess a room's width off lands nowhere: refused, not accepted by accident.
    far = true_rel @ yaw_pose(0.0, np.array([4.0, 3.0, 0.0]))
    assert not loops.verify_2d(target, source, far).accepted


def test_2d_loop_in_a_corridor_is_degenerate() -> None:
    """Two parallel walls: along them nothing holds the fit, whatever its overlap and RMSE."""
    a = yaw_pose(0.0, np.array([0.0, 0.0, 0.0]))
    b = yaw_pose(0.05, np.array([3.0, 0.1, 0.0]))
    target, source = _keyframe_clouds(CORRIDOR, a, b, 1)
    loops = LoopCloser(MappingConfig(), planar=True)
    check = loops.verify_2d(target, source, np.linalg.inv(a) @ b)
    assert not check.accepted and check.reason in ("degenerate", "ambiguous")
    assert check.registration is not None and check.registration.rmse_m < 0.02  # a good fit


def test_2d_loop_degeneracy_gate_alone() -> None:
    """The corridor's fit is good but its information along the walls is near zero: with the
    ambiguity check off, the degeneracy check still refuses it, and only it."""
    a = yaw_pose(0.0, np.array([0.0, 0.0, 0.0]))
    b = yaw_pose(0.0, np.array([2.0, 0.0, 0.0]))
    target, source = _keyframe_clouds(CORRIDOR, a, b, 2)
    loops = LoopCloser(MappingConfig(loops=LoopsConfig(ambiguity_m=100.0)), planar=True)
    check = loops.verify_2d(target, source, np.linalg.inv(a) @ b)
    assert not check.accepted and check.reason == "degenerate"
    assert check.registration is not None and check.registration.fitness > 0.8
