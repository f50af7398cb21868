"""Stair walks from the lidar odometry's keyframes, for a log without a barometer."""

from __future__ import annotations

import numpy as np
import pytest

from mfmap.floors.climbs import stair_walks


def _keyframes(*legs: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Keyframes 1 m apart along legs of (horizontal m, climb m, pause s), one per second, with
    a centimetre of odometry noise."""
    rng = np.random.default_rng(3)
    xyz = [np.zeros(3)]
    for run, climb, _ in legs:
        n = max(1, round(run))
        for _ in range(n):
            xyz.append(xyz[-1] + np.array([run / n, 0.0, climb / n]))
    pts = np.array(xyz) + rng.normal(0.0, 0.01, (len(xyz), 3))
    stamps = np.arange(len(pts), dtype=np.int64) * 1_000_000_000
    return stamps, pts


def test_a_switch_back_walk_between_two_floors_is_one_walk_of_their_height() -> None:
    # 12 m on floor 0, a flight of 1.75 m, a 2 m half landing, another flight, 12 m on floor 1.
    stamps, xyz = _keyframes((12, 0, 0), (4, 1.75, 0), (2, 0, 0), (4, 1.75, 0), (12, 0, 0))
    walks = stair_walks(stamps, xyz, 2.0, 5.0)
    assert len(walks) == 1
    start_ns, end_ns, dz = walks[0]
    assert dz == pytest.approx(3.5, abs=0.05)
    # From the last keyframe on floor 0 (12 s) to the first on floor 1 (22 s).
    assert start_ns == 12_000_000_000 and end_ns == 22_000_000_000


def test_a_floor_passed_through_and_a_ramp_are_no_floors_of_their_own() -> None:
    # Down two floors without leaving the stairs (3 m on the floor between), then a 0.8 m ramp.
    stamps, xyz = _keyframes((10, 0, 0), (6, -3.2, 0), (3, 0, 0), (6, -3.2, 0), (10, 0, 0),
                             (8, 0.8, 0), (10, 0, 0))
    walks = stair_walks(stamps, xyz, 2.0, 5.0)
    assert [round(dz, 1) for _, _, dz in walks] == [-6.4]


def test_a_log_that_stops_on_a_flight_ends_on_no_floor() -> None:
    stamps, xyz = _keyframes((10, 0, 0), (6, 3.0, 0))
    assert stair_walks(stamps, xyz, 2.0, 5.0) == []
    # Held on the top for a few metres, it is a floor.
    stamps, xyz = _keyframes((10, 0, 0), (6, 3.0, 0), (3, 0, 0))
    assert [round(dz, 1) for _, _, dz in stair_walks(stamps, xyz, 2.0, 5.0)] == [3.0]
