"""The cabin measurement on scans made here: a box with polished walls and a door, at a known
pose, seen from a robot standing in it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mfmap.export.cabin import Cabin, _Phase, _Ride, door_of, fit_cabin_box, measure_cabins


def _box_scan(centre: tuple[float, float], yaw: float, half: tuple[float, float], robot: tuple[float, float],
              rng: np.random.Generator, door_open: bool = False, n_rays: int = 3000,
              spurious: float = 0.3) -> np.ndarray:
    """World x, y of one planar scan from `robot` inside a box; the door (1.1 m wide, in the
    -y wall of the box's frame) shows a far wall 5 m away when open."""
    c, s = math.cos(yaw), math.sin(yaw)
    to_box = np.array([[c, s], [-s, c]])
    origin = to_box @ (np.array(robot) - np.array(centre))
    ang = rng.uniform(-math.pi, math.pi, n_rays)
    d = np.column_stack([np.cos(ang), np.sin(ang)])
    with np.errstate(divide="ignore"):
        tx = np.where(d[:, 0] > 0, half[0] - origin[0], -half[0] - origin[0]) / d[:, 0]
        ty = np.where(d[:, 1] > 0, half[1] - origin[1], -half[1] - origin[1]) / d[:, 1]
    t = np.minimum(np.abs(tx), np.abs(ty))
    hit = origin + d * t[:, None]
    if door_open:
        through = (np.abs(ty) < np.abs(tx)) & (d[:, 1] < 0) & (np.abs(hit[:, 0]) < 0.55)
        t = np.where(through, (-half[1] - 5.0 - origin[1]) / d[:, 1], t)
    # Polished walls: a share of the hits come back at a longer, wrong range.
    t = t * np.where(rng.random(n_rays) < spurious, rng.uniform(1.2, 2.2, n_rays), 1.0)
    t = t + rng.normal(0.0, 0.01, n_rays)
    local = origin + d * t[:, None]
    return np.asarray(local @ to_box + np.array(centre))


@pytest.mark.parametrize("yaw_deg", [0.0, 12.0, -30.0])
def test_fit_finds_the_box_around_the_robot(yaw_deg: float) -> None:
    rng = np.random.default_rng(3)
    centre, half, yaw = (4.2, -1.3), (1.0, 0.8), math.radians(yaw_deg)
    robot = (4.35, -1.2)
    xy = np.concatenate([_box_scan(centre, yaw, half, robot, rng) for _ in range(20)])
    fit = fit_cabin_box(xy, np.array(robot))
    assert fit is not None
    got_centre, got_yaw, size, _ = fit
    assert np.hypot(*(got_centre - centre)) < 0.02
    # The heading is found modulo 90 degrees; the sizes follow it.
    turn = round((got_yaw - yaw) / (math.pi / 2))
    assert abs(got_yaw - yaw - turn * math.pi / 2) < math.radians(0.5)
    expected = np.array([2 * half[0], 2 * half[1]])
    if turn % 2:
        expected = expected[::-1]
    assert np.allclose(size, expected, atol=0.02)


def test_fit_needs_a_box() -> None:
    rng = np.random.default_rng(0)
    assert fit_cabin_box(rng.uniform(-10, 10, (5000, 2)), np.zeros(2)) is None


def test_door_side_and_width_from_open_door_scans() -> None:
    rng = np.random.default_rng(5)
    centre, half, yaw = (0.0, 0.0), (1.0, 1.0), math.radians(20.0)
    phase = _Phase("door", 0)
    for _ in range(15):
        phase.xy.append(_box_scan(centre, yaw, half, (0.05, 0.1), rng, door_open=True))
        phase.origin.append(np.array([0.05, 0.1]))
    door = door_of(phase, np.array(centre), yaw, np.array([2.0, 2.0]))
    assert door is not None
    assert door.side == "back"
    assert abs(door.offset_m) < 0.08
    assert abs(door.width_m - 1.1) < 0.12


def test_no_door_while_the_doors_stay_shut() -> None:
    rng = np.random.default_rng(6)
    phase = _Phase("door", 0)
    for _ in range(15):
        phase.xy.append(_box_scan((0.0, 0.0), 0.0, (1.0, 1.0), (0.0, 0.0), rng))
        phase.origin.append(np.zeros(2))
    assert door_of(phase, np.zeros(2), 0.0, np.array([2.0, 2.0])) is None


def test_a_lift_never_seen_is_a_warning_not_a_cabin() -> None:
    ride = _Ride(0, 10, 0, 1, np.eye(4), [_Phase("ride", -1), _Phase("door", 0), _Phase("door", 1)])
    cabins, warnings = measure_cabins([ride])
    assert cabins == []
    assert len(warnings) == 1 and "no lidar scan during its rides" in warnings[0]


def test_rides_of_one_shaft_give_one_cabin_with_a_door_per_floor() -> None:
    rng = np.random.default_rng(8)
    centre, half = (2.0, 3.0), (1.0, 1.0)
    rides = []
    for a, b in ((0, 1), (1, 2)):
        pose = np.eye(4)
        pose[:2, 3] = (2.05, 3.02)
        ride = _Ride(0, 10, a, b, pose)
        phases = [_Phase("ride", -1), _Phase("door", a), _Phase("door", b)]
        for _ in range(10):
            phases[0].xy.append(_box_scan(centre, 0.0, half, (2.05, 3.02), rng))
            phases[0].origin.append(pose[:2, 3].copy())
            for p in phases[1:]:
                p.xy.append(_box_scan(centre, 0.0, half, (2.05, 3.02), rng, door_open=True))
                p.origin.append(pose[:2, 3].copy())
        ride.phases = phases
        rides.append(ride)
    cabins, warnings = measure_cabins(rides)
    assert warnings == []
    assert len(cabins) == 1
    cabin: Cabin = cabins[0]
    assert cabin.floors == (0, 1, 2) and sorted(cabin.doors) == [0, 1, 2]
    assert math.hypot(cabin.x_m - centre[0], cabin.y_m - centre[1]) < 0.02
    assert all(d.side == "back" for d in cabin.doors.values())
