"""Stair walks from the lidar odometry's height, for a log without a barometer.

Without a barometer the IMU finds the elevator rides (`mfmap.floors.rides`), but a flight of
stairs is not a stand-still to stand-still push of the accelerometer: the lidar sees it, as a
climb of the odometry's z within one floor visit. The keyframes' heights along a visit are cut
into levels (runs of keyframes within `LEVEL_TOLERANCE_M` of each other); a level the robot
travels at least `landing_max_path_m` on is a floor, as is where the visit starts and ends
(held for `END_KEYFRAMES` keyframes: a log that stops on a flight does not end on a floor), and
a level between is a landing or a floor passed through on the stairs. Two floors in a row whose
levels differ by at least `min_floor_height_m` are a stair walk between them, up or down, from
the last keyframe on the one to the first on the other (the IMU's flights refine the span
where it has them); levels closer than that are one floor (a ramp, a sill, a split level).

The robot's height along a floor drifts with the odometry's tilt (a few cm over tens of
metres), far below a storey; the walk's height is the levels' difference, measured again by the
mapping stage across the walk (`mfmap.mapping.transitions`) for the graph.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mfmap.types import F64, I64

# Keyframes within this of the median height of a level's keyframes so far are on it (m): the
# odometry's drift along a floor is centimetres, a flight's keyframes (about 1 m apart along it)
# half a metre apart in z.
LEVEL_TOLERANCE_M = 0.25
# A visit's first and last levels are floors when held for this many keyframes; on a flight
# each keyframe is a level of its own.
END_KEYFRAMES = 2


@dataclass(frozen=True)
class Level:
    """Keyframes first..last (inclusive, in time order) at one height."""

    first: int
    last: int
    z_m: float
    path_m: float


def levels(z_m: F64, xy_m: F64) -> list[Level]:
    """Runs of keyframes whose heights stay within `LEVEL_TOLERANCE_M` of the run's median."""
    runs: list[Level] = []
    start = 0
    for k in range(1, len(z_m) + 1):
        if k < len(z_m) and abs(z_m[k] - float(np.median(z_m[start:k]))) <= LEVEL_TOLERANCE_M:
            continue
        steps = np.linalg.norm(np.diff(xy_m[start:k], axis=0), axis=1)
        runs.append(Level(start, k - 1, float(np.median(z_m[start:k])), float(steps.sum())))
        start = k
    return runs


def stair_walks(stamp_ns: I64, xyz_m: F64, min_floor_height_m: float,
                landing_max_path_m: float) -> list[tuple[int, int, float]]:
    """The stair walks within one visit's keyframes (time order): (start_ns, end_ns, height
    change m), from the last keyframe on one floor to the first on the next."""
    if len(stamp_ns) < 2:
        return []
    runs = levels(np.asarray(xyz_m[:, 2], dtype=np.float64), np.asarray(xyz_m[:, :2], dtype=np.float64))
    ends = (0, len(runs) - 1)
    floors = [r for n, r in enumerate(runs) if r.path_m >= landing_max_path_m
              or (n in ends and r.last - r.first + 1 >= END_KEYFRAMES)]
    if not floors:
        return []
    walks = []
    here = floors[0]
    for there in floors[1:]:
        dz = there.z_m - here.z_m
        if abs(dz) < min_floor_height_m:
            # The same floor (a ramp, a sill, a half landing held long): a walk from it starts
            # after its last keyframe, at the floor's first level.
            here = Level(here.first, there.last, here.z_m, here.path_m + there.path_m)
            continue
        walks.append((int(stamp_ns[here.last]), int(stamp_ns[there.first]), dz))
        here = there
    return walks
