"""Several logs of one building: sessions on different days, ground truth in one building frame.

A real building is mapped and revisited over days, floor by floor, from wherever the robot
happens to be. Each session here is a scenario of its own (`mfmap simulate office3-day2`), and
the sessions of one building share:

- the building: its plan, and its rooms and furniture drawn from the run's seed (the same
  building for every session at one seed, as for the single-log scenarios of that plan);
- the building frame: the plan's x, y and yaw, z = 0 on the top of the frame floor's slab. A
  session that starts at the plan's origin on the frame floor, facing +x (the dock), has it as
  its own world frame, so a build of that session is in the building frame too;

and differ in their route, their start floor and pose, and their day: the reference pressure
(the day's weather), its drift, the building's air, the clock and the sensors' noise are drawn
from the seed and the day, so no two sessions of a building see the same pressure on a floor.

Every session's ground truth (gt_trajectory.tum, gt_points.csv, gt_floors.json, gt_cloud.ply) is
in the building frame; gt_session.json says where the session starts in it and on which day.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mfmap.atomic import write_bytes_atomic
from mfmap.sim.route import RouteBuilder
from mfmap.sim.sensors import LidarSpec

if TYPE_CHECKING:
    from mfmap.sim.building import Building


@dataclass(frozen=True)
class Session:
    """One log of a building that other logs share (see the module docstring)."""

    building: str  # the name the sessions of one building share
    day: int  # 1, 2, ...: the day's weather, air, clock and sensor noise
    start_xy: tuple[float, float] = (0.0, 0.0)  # building frame
    start_yaw_deg: float = 0.0
    frame_floor: int = 0  # the building floor whose slab top is z = 0

    def log_seed(self, seed: int) -> int:
        """The seed of everything in this session's log that is not the building."""
        return int(np.random.SeedSequence([seed, self.day, 0x5E55]).generate_state(1)[0])

    def place(self, builder: RouteBuilder) -> None:
        """Put the route's first pose at the session's start (the builder starts at the origin)."""
        z = float(builder.xyz[0][0, 2])
        builder.xyz[0] = np.array([[self.start_xy[0], self.start_xy[1], z]])
        builder.rpy[0] = np.array([[0.0, 0.0, math.radians(self.start_yaw_deg)]])

    def document(self, scenario: str, seed: int, building: Building, start_floor: int,
                 start_ns: int) -> dict[str, Any]:
        """gt_session.json: the session within its building."""
        return {
            "building": self.building,
            "scenario": scenario,
            "seed": seed,
            "day": self.day,
            "log_seed": self.log_seed(seed),
            "start_ns": start_ns,
            "frame": "building: the plan's x, y, yaw; z = 0 on the frame floor's slab top",
            "frame_floor": self.frame_floor,
            "start_floor": start_floor,
            "start_pose": {
                "x": self.start_xy[0],
                "y": self.start_xy[1],
                "z": round(building.elevation(start_floor), 6),
                "yaw_deg": self.start_yaw_deg,
            },
            "elevations_m": [round(building.elevation(k), 6) for k in range(building.n_floors)],
        }

    def write(self, out: Path, scenario: str, seed: int, building: Building, start_floor: int,
              start_ns: int) -> Path:
        path = out / "gt_session.json"
        doc = self.document(scenario, seed, building, start_floor, start_ns)
        write_bytes_atomic(path, (json.dumps(doc, indent=2) + "\n").encode())
        return path


# ----- routes in the office block (see mfmap.sim.spec's plan) ------------------------------

P1, P2, P3, P4 = (0.0, 0.0), (6.0, -2.0), (6.0, -12.0), (0.7, -12.0)
W_NORTH, W_SOUTH = (-2.75, -1.0), (-2.75, -12.0)
E_NORTH, E_SOUTH, F_EAST = (14.25, -1.5), (14.25, -11.0), (24.0, -11.0)


def _loop(b: RouteBuilder, stop_s: float = 4.0) -> None:
    """P1 -> P2 -> P3 -> P4 and back to P1 round the west corridor, standing at each."""
    b.drive(P1)
    b.checkpoint("P1", stop_s)
    b.drive(P2)
    b.checkpoint("P2", stop_s)
    b.drive(P3)
    b.checkpoint("P3", stop_s)
    b.drive(P4)
    b.checkpoint("P4", stop_s)
    b.drive(W_SOUTH, W_NORTH, (0.0, -1.0), P1)


def _east(b: RouteBuilder) -> None:
    """Corridor N to the east, down corridor E, along corridor F and back to corridor N."""
    b.drive((10.0, -1.5), E_NORTH, E_SOUTH, F_EAST, v_max=0.9)
    b.drive(E_SOUTH, E_NORTH, (3.0, -1.5), v_max=0.9)


def _tiny_day1(b: RouteBuilder, reps: int) -> None:
    """The tiny scenario's route: P1, P2, up one floor by elevator, P2."""
    for _ in range(reps):
        b.checkpoint("P1", 3.0)
        b.drive(P2)
        b.checkpoint("P2", 3.0)
    b.elevator(1)
    for _ in range(reps):
        b.drive(P2)
        b.checkpoint("P2", 3.0)
        if reps > 1:
            b.drive(P1)


def _tiny_day2(b: RouteBuilder, reps: int) -> None:
    """From P2 on the upper floor, facing north: down by elevator, P2 and P1 on the lower one."""
    b.wait(3.0)
    for _ in range(reps):
        b.drive((3.0, -1.2))
        b.drive(P2)
    b.elevator(0)
    for _ in range(reps):
        b.drive(P2)
        b.checkpoint("P2", 3.0)
        b.drive(P1)
        b.checkpoint("P1", 3.0)


def _tiny_day3(b: RouteBuilder, reps: int) -> None:
    """The lower floor alone: P1, P2, back to P1."""
    for _ in range(reps):
        b.checkpoint("P1", 3.0)
        b.drive(P2)
        b.checkpoint("P2", 3.0)
        b.drive(P1)
    b.checkpoint("P1", 3.0)


def _office3_day1(b: RouteBuilder, reps: int) -> None:
    """Floors 0 and 1 from the dock."""
    for _ in range(reps):
        _loop(b)
    b.elevator(1)
    for _ in range(reps):
        _loop(b)
    b.checkpoint("P1", 3.0)


def _office3_day2(b: RouteBuilder, reps: int) -> None:
    """Floors 1 and 2, from P3 on floor 1 facing north."""
    b.wait(3.0)
    for _ in range(reps):
        b.drive(P2)
        b.checkpoint("P2", 4.0)
        b.drive(P1)
        _loop(b)
    b.elevator(2)
    for _ in range(reps):
        _loop(b)
    b.checkpoint("P1", 3.0)


def _office3_day3(b: RouteBuilder, reps: int) -> None:
    """All three floors from the dock, the west loop and the east corridors on each."""
    for floor in (0, 1, 2):
        if floor:
            b.elevator(floor)
        for _ in range(reps):
            _loop(b)
            _east(b)
        b.drive(P1)
        b.checkpoint("P1", 3.0)


def _office3_day4(b: RouteBuilder, reps: int) -> None:
    """From corridor E on the top floor, facing south: corridor F and the west loop there, down
    two floors by elevator, the loop and corridor F on the ground floor, up one, the loop."""
    b.wait(3.0)
    for _ in range(reps):
        b.drive(E_SOUTH, F_EAST, v_max=0.9)
        b.drive(E_SOUTH, E_NORTH, (3.0, -1.5), v_max=0.9)
        _loop(b)
    b.elevator(0)
    for _ in range(reps):
        _loop(b)
        _east(b)
    b.elevator(1)
    for _ in range(reps):
        _loop(b)
    b.checkpoint("P1", 3.0)


SESSION_LIDAR = LidarSpec(beams=16, columns=512)


@dataclass(frozen=True)
class SessionPlan:
    """One session's scenario: the building (office block), its route, start and day."""

    name: str
    description: str
    n_floors: int
    floor_height_m: float
    route: Callable[[RouteBuilder, int], None]
    start_floor: int
    session: Session


SESSION_PLANS = (
    SessionPlan("tiny-day1", "tiny building, day 1: the tiny route (both floors from the dock), ~1.5 min",
          2, 3.5, _tiny_day1, 0, Session("tiny", 1)),
    SessionPlan("tiny-day2", "tiny building, day 2: starts on the upper floor at P2 facing north, "
          "rides down, P2 and P1, ~1.3 min", 2, 3.5, _tiny_day2, 1,
          Session("tiny", 2, start_xy=P2, start_yaw_deg=90.0)),
    SessionPlan("tiny-day3", "tiny building, day 3: the lower floor alone, P1 to P2 and back, ~40 s",
          2, 3.5, _tiny_day3, 0, Session("tiny", 3)),
    SessionPlan("office3-day1", "three-floor office (4.0 m storeys), day 1: floors 0-1 from the "
          "dock, the west loop on each, ~4 min", 3, 4.0, _office3_day1, 0, Session("office3", 1)),
    SessionPlan("office3-day2", "three-floor office, day 2: floors 1-2, starts on floor 1 at P3 "
          "facing north, ~4.5 min", 3, 4.0, _office3_day2, 1,
          Session("office3", 2, start_xy=P3, start_yaw_deg=90.0)),
    SessionPlan("office3-day3", "three-floor office, day 3: all three floors from the dock, the west "
          "loop and the east corridors on each, ~9 min", 3, 4.0, _office3_day3, 0,
          Session("office3", 3)),
    SessionPlan("office3-day4", "three-floor office, day 4: starts on the top floor in corridor E "
          "facing south, rides down to the ground floor, tours, up to floor 1, ~7 min", 3, 4.0,
          _office3_day4, 2, Session("office3", 4, start_xy=(14.25, -6.0), start_yaw_deg=-90.0)),
)


__all__ = ["SESSION_LIDAR", "SESSION_PLANS", "Session", "SessionPlan"]
