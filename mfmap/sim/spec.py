"""What a synthetic building is made of: footprint, storeys, blocks, elevator shaft, stairwell.

The plan (world frame = the robot's base at its start, metres) is about 30 x 20 m:

    y  4 +---------------------------------------------------------------+
         | N0 |shaft|                   N1 rooms                          |
       1 +----+-dd--+-----------------------------------------------------+
         |             corridor N (P1 at (0,0), P2 at (6,-2))             |
      -3 +--+---------+---+--------+----+-------------------------------+
         |W |  block C |V  | block M|  E |           block NE            |
     -10 |  |          |   |        |    +-------------------------------+
         |  +----------+   |        |          corridor F               |
     -12 |  corridor S    |        +----+-------------------------------+
   -13.5 +----------------+        |SE0 |  stairwell (two lanes)        |
         |   block SW      |        |    |                               |
     -16 +-----------------+--------+----+-------------------------------+
        -4                7.5     12.5   16                              26  x

That block is one `BuildingSpec` (`office_block`): a building is its footprint, its storeys
(their heights may differ), blocks of rooms between corridors, the elevator shaft, the stairwell
(straight flights, or switch-back flights with half landings) and pillars. Corridors, outer walls,
the elevator shaft, the stairwell and pillars are the same on every floor; rooms inside the
blocks, their doorways and furniture are drawn per floor from the seed.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

from mfmap.sim.boxes import Box, Kind

X_MIN, X_MAX, Y_MIN, Y_MAX = -4.0, 26.0, -16.0, 4.0
OUTER_WALL_M = 0.3
INNER_WALL_M = 0.12
SLAB_M = 0.3
DOOR_HEIGHT_M = 2.1

# Elevator: shaft centre, cabin inner half-size, door half-width. The door faces -y (corridor N).
SHAFT_CENTER = (0.3, 2.35)
SHAFT_OUTER_HALF = 1.35
SHAFT_WALL_M = 0.2
CABIN_HALF = 1.05  # outer half-size of the cabin
CABIN_WALL_M = 0.05
CABIN_HEIGHT_M = 2.4
ELEVATOR_DOOR_HALF = 0.55
ELEVATOR_DOOR_HEIGHT_M = 2.2

# Stairwell: two lanes running along x, landings at both ends, doors on its north wall.
STAIR_X0, STAIR_X1, STAIR_Y0, STAIR_Y1 = 16.0, 26.0, -16.0, -12.0
STAIR_FLIGHT_X0 = 17.4
LANE_A_Y = (-15.9, -14.1)  # flights going +x start on even floors
LANE_B_Y = (-13.9, -12.1)  # flights going -x start on odd floors
STAIR_RISE_M = 0.175
STAIR_TREAD_M = 0.28
STAIR_DOOR_X = ((16.2, 17.3), (24.85, 25.85))  # doorways in the north wall at the two landings

# (name, x0, x1, y0, y1, sides facing a corridor, split along x?)
BLOCKS: tuple[tuple[str, float, float, float, float, str], ...] = (
    ("C", -1.5, 4.5, -10.5, -3.0, "nswe"),
    ("SW", -4.0, 7.5, -16.0, -13.5, "n"),
    ("M", 7.5, 12.5, -16.0, -3.0, "nwe"),
    ("NE", 16.0, 26.0, -10.0, -3.0, "nws"),
    ("SE0", 12.5, 16.0, -16.0, -12.0, "n"),
    ("N0", -4.0, -1.05, 1.0, 4.0, "s"),
    ("N1", 1.65, 26.0, 1.0, 4.0, "s"),
)
# The stretch of each corridor-facing side that really borders a corridor (others border blocks).
SIDE_LIMITS: dict[tuple[str, str], tuple[float, float]] = {
    ("M", "w"): (-13.5, -3.0),
    ("M", "e"): (-10.0, -3.0),
}
PILLARS_XY = ((5.0, 0.6), (10.0, 0.6), (15.0, 0.6), (20.0, 0.6), (10.0, -9.5), (21.0, -6.5))
PILLAR_HALF = 0.2


@dataclass(frozen=True)
class Block:
    """A block of rooms between corridors: rooms along its longer side, one doorway each on a
    side that faces a corridor (`sides`; `limits` narrows a side to the stretch that does)."""

    name: str
    x0: float
    x1: float
    y0: float
    y1: float
    sides: str
    limits: tuple[tuple[str, float, float], ...] = ()


@dataclass(frozen=True)
class ShaftSpec:
    """The elevator: shaft, cabin and landing doors. `door` is the side of the shaft the doors
    are on; `front` is where the robot waits for the cabin."""

    center: tuple[float, float]
    front: tuple[float, float]
    door: str = "s"
    outer_half_m: float = SHAFT_OUTER_HALF
    wall_m: float = SHAFT_WALL_M
    cabin_half_m: float = CABIN_HALF
    cabin_wall_m: float = CABIN_WALL_M
    cabin_height_m: float = CABIN_HEIGHT_M
    door_half_m: float = ELEVATOR_DOOR_HALF
    door_height_m: float = ELEVATOR_DOOR_HEIGHT_M
    speed_m_s: float = 1.0
    acc_m_s2: float = 0.5

    @property
    def door_normal(self) -> tuple[float, float]:
        """Unit vector from the shaft's centre out through its doors."""
        return {"s": (0.0, -1.0), "n": (0.0, 1.0), "w": (-1.0, 0.0), "e": (1.0, 0.0)}[self.door]


@dataclass(frozen=True)
class StairwellSpec:
    """A stairwell of two lanes along x inside `rect` (x0, x1, y0, y1).

    straight: one flight per storey from `flight_x0`, in lane a (going +x) from even floors and
    lane b (going -x) from odd ones, a doorway at each end (`doors_x`).
    switchback: two half flights per storey with a landing between: from the floor landing
    (west of `flight_x0`, or east of it when `reverse`) up lane a, the lane by the door, to the
    half landing at the far end, back up lane b to the next floor's landing; one doorway per
    floor, in the landing's stretch of the door wall.
    """

    kind: str = "straight"
    rect: tuple[float, float, float, float] = (STAIR_X0, STAIR_X1, STAIR_Y0, STAIR_Y1)
    flight_x0: float = STAIR_FLIGHT_X0
    lane_a: tuple[float, float] = LANE_A_Y
    lane_b: tuple[float, float] = LANE_B_Y
    divider: tuple[float, float] = (-14.06, -13.94)
    door_side: str = "n"
    doors_x: tuple[tuple[float, float], ...] = STAIR_DOOR_X
    walls: str = "nw"  # its own walls; the others are the building's outer walls
    reverse: bool = False
    rise_m: float = STAIR_RISE_M
    tread_m: float = STAIR_TREAD_M
    waist_m: float = 0.2  # a switch-back flight is a slab this thick under its steps
    approach_m: float = 1.0  # the route meets the stairwell this far outside its door wall

    @property
    def door_wall_y(self) -> float:
        return self.rect[3] if self.door_side == "n" else self.rect[2]

    @property
    def outward(self) -> float:
        """+1 when the door wall faces +y."""
        return 1.0 if self.door_side == "n" else -1.0


@dataclass(frozen=True)
class Corridor:
    """A corridor's centre line (for planning routes): along `axis` at the other coordinate `c`
    from a0 to a1, `width_m` wide."""

    axis: str
    c: float
    a0: float
    a1: float
    width_m: float


@dataclass(frozen=True)
class BuildingSpec:
    """Everything that makes one building: footprint, storeys, blocks, the elevator and the
    stairwell, pillars, the corridors a route may use and its checkpoints."""

    name: str
    footprint: tuple[float, float, float, float]  # x_min, x_max, y_min, y_max (inner faces)
    storey_heights_m: tuple[float, ...]  # per floor, slab top to the next slab top
    blocks: tuple[Block, ...]
    shaft: ShaftSpec
    stairwell: StairwellSpec
    pillars: tuple[tuple[float, float], ...] = ()
    pillar_half_m: float = PILLAR_HALF
    # Walls of the stretches carved out of blocks for the shaft and the stairwell:
    # (axis, a0, a1, c) full storey height on every floor.
    extra_walls: tuple[tuple[str, float, float, float], ...] = ()
    corridors: tuple[Corridor, ...] = ()
    checkpoints: tuple[tuple[str, float, float], ...] = ()
    # Boxes on every floor, z relative to its slab top (tables, wall shelves).
    fixtures: tuple[Box, ...] = ()

    @property
    def n_floors(self) -> int:
        return len(self.storey_heights_m)


def office_block(
    n_floors: int, floor_height_m: float, storey_heights_m: Sequence[float] | None = None, switchback: bool = False
) -> BuildingSpec:
    """The 30 x 20 m office block of the module docstring, with equal storeys (or the given
    ones) and straight flights (or switch-back ones: from the west landing up the north lane to
    a half landing at the east end, back up the south lane; one door per floor)."""
    storeys = tuple(storey_heights_m) if storey_heights_m is not None else (floor_height_m,) * n_floors
    stairwell = StairwellSpec()
    if switchback:
        stairwell = StairwellSpec(
            kind="switchback", lane_a=LANE_B_Y, lane_b=LANE_A_Y, doors_x=(STAIR_DOOR_X[0],)
        )
    return BuildingSpec(
        name="office-block" + ("-switchback" if switchback else ""),
        footprint=(X_MIN, X_MAX, Y_MIN, Y_MAX),
        storey_heights_m=storeys,
        blocks=tuple(
            Block(name, x0, x1, y0, y1, sides, tuple((s, *lim) for (b, s), lim in SIDE_LIMITS.items() if b == name))
            for name, x0, x1, y0, y1, sides in BLOCKS
        ),
        shaft=ShaftSpec(center=SHAFT_CENTER, front=(SHAFT_CENTER[0], -0.6)),
        stairwell=stairwell,
        pillars=PILLARS_XY,
    )


def _table(x0: float, x1: float, y0: float, y1: float, top_m: float = 0.75) -> list[Box]:
    """A table: a 4 cm top on four 5 cm legs (a 2D scan below the top sees only the legs)."""
    legs = [Box((x, y, 0.0), (x + 0.05, y + 0.05, top_m - 0.04), Kind.FURNITURE)
            for x in (x0 + 0.03, x1 - 0.08) for y in (y0 + 0.03, y1 - 0.08)]
    return [Box((x0, y0, top_m - 0.04), (x1, y1, top_m), Kind.FURNITURE), *legs]


def corridor_block(n_floors: int, floor_height_m: float) -> BuildingSpec:
    """The office block with its north corridor narrowed to 2 m (y -1 to 1) and 30 m long, as
    the corridors of Fan et al.'s experiment, without pillars, and on every floor tables along
    its north wall and wall cabinets on its south wall (tops at 0.75 m, cabinets from 1.0 to
    1.3 m: obstacles in the robot's height band that a scan at 0.3 m passes under or over)."""
    base = office_block(n_floors, floor_height_m)
    blocks = tuple(
        Block(b.name, b.x0, b.x1, b.y0, -1.0 if b.y1 == -3.0 else b.y1, b.sides, b.limits)
        for b in base.blocks
    )
    fixtures = [*_table(5.0, 6.2, 0.45, 1.0), *_table(10.5, 12.0, 0.45, 1.0)]
    for x0, x1 in ((2.0, 3.5), (8.0, 9.5)):
        fixtures.append(Box((x0, -1.0, 1.0), (x1, -0.65, 1.3), Kind.FURNITURE))
    return BuildingSpec(
        name="corridor-block", footprint=base.footprint, storey_heights_m=base.storey_heights_m,
        # The robot waits for the cabin 0.5 m into the corridor, not the office block's 0.6 m:
        # the corridor's south wall is 0.94 m from its centre, and the robot needs 0.35 m.
        blocks=blocks, shaft=replace(base.shaft, front=(base.shaft.front[0], -0.5)),
        stairwell=base.stairwell, pillars=(),
        extra_walls=base.extra_walls, fixtures=tuple(fixtures),
    )


@dataclass(frozen=True)
class StairGeometry:
    n_risers: int  # per flight
    rise_m: float
    run_m: float  # horizontal length of one flight
    x0: float = STAIR_FLIGHT_X0

    @property
    def flight_x1(self) -> float:
        return self.x0 + self.run_m


def flight_geometry(stair: StairwellSpec, storey_m: float) -> StairGeometry:
    """The flights of one storey: one of the storey's height, or two of half of it."""
    climb = storey_m if stair.kind == "straight" else storey_m / 2
    n = max(2, round(climb / stair.rise_m))
    return StairGeometry(n, climb / n, (n - 1) * stair.tread_m, stair.flight_x0)
