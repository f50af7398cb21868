"""Synthetic multi-storey buildings made of boxes, ray-cast with open3d's RaycastingScene.

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

import itertools
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from mfmap.types import F32, F64

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


class Kind:
    """Surface classes, kept per box for plots and for the cabin's reflective walls."""

    SLAB = 0
    WALL = 1
    PILLAR = 2
    FURNITURE = 3
    STAIRS = 4
    DOOR = 5
    CABIN_WALL = 6
    CABIN_FLOOR = 7


@dataclass(frozen=True)
class Box:
    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    kind: int


@dataclass
class FloorGeometry:
    floor_id: int
    elevation_m: float
    boxes: list[Box] = field(default_factory=list)


def box_triangles(boxes: list[Box]) -> tuple[F32, npt.NDArray[np.uint32]]:
    """Vertices (8 per box) and triangles (12 per box) of axis-aligned boxes."""
    if not boxes:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint32)
    lo = np.array([b.lo for b in boxes], dtype=np.float64)
    hi = np.array([b.hi for b in boxes], dtype=np.float64)
    corners = np.array([[i >> 0 & 1, i >> 1 & 1, i >> 2 & 1] for i in range(8)], dtype=np.float64)
    verts = lo[:, None, :] + corners[None, :, :] * (hi - lo)[:, None, :]
    # Two triangles per face of the unit cube (corner index = x + 2y + 4z).
    faces = np.array(
        [
            [0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6],  # z-, z+
            [0, 1, 4], [1, 5, 4], [2, 6, 3], [3, 6, 7],  # y-, y+
            [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5],  # x-, x+
        ],
        dtype=np.uint32,
    )  # fmt: skip
    tris = faces[None, :, :] + (8 * np.arange(len(boxes), dtype=np.uint32))[:, None, None]
    return verts.reshape(-1, 3).astype(np.float32), tris.reshape(-1, 3)


def _rect_minus_holes(
    rect: tuple[float, float, float, float], holes: list[tuple[float, float, float, float]]
) -> list[tuple[float, float, float, float]]:
    """Split rectangle (x0, x1, y0, y1) into cells on the holes' edges, dropping cells in holes."""
    xs = sorted({rect[0], rect[1], *[v for h in holes for v in h[:2] if rect[0] < v < rect[1]]})
    ys = sorted({rect[2], rect[3], *[v for h in holes for v in h[2:] if rect[2] < v < rect[3]]})
    cells = []
    for x0, x1 in itertools.pairwise(xs):
        for y0, y1 in itertools.pairwise(ys):
            cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
            if not any(h[0] < cx < h[1] and h[2] < cy < h[3] for h in holes):
                cells.append((x0, x1, y0, y1))
    return cells


def _wall(
    axis: str,
    a0: float,
    a1: float,
    c: float,
    z0: float,
    z1: float,
    thick: float,
    openings: Sequence[tuple[float, float, float]] = (),
    kind: int = Kind.WALL,
) -> list[Box]:
    """A wall along `axis` ("x" or "y") from a0 to a1 at the other coordinate c, with openings
    (start, end, height) that leave a lintel above."""

    def mk(s0: float, s1: float, zb: float) -> Box:
        if axis == "x":
            return Box((s0, c - thick / 2, zb), (s1, c + thick / 2, z1), kind)
        return Box((c - thick / 2, s0, zb), (c + thick / 2, s1, z1), kind)

    boxes = []
    cur = a0
    for s0, s1, height in sorted(openings):
        s0, s1 = max(s0, a0), min(s1, a1)
        if s1 <= s0:
            continue
        if s0 > cur:
            boxes.append(mk(cur, s0, z0))
        if z0 + height < z1:
            boxes.append(mk(s0, s1, z0 + height))
        cur = s1
    if cur < a1:
        boxes.append(mk(cur, a1, z0))
    return boxes


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


def _rotate_box(box: Box, quarter_turns: int) -> Box:
    """A box turned about the z axis by quarter_turns * 90 deg (exact: only swaps and signs)."""
    (x0, y0, z0), (x1, y1, z1) = box.lo, box.hi
    for _ in range(quarter_turns % 4):
        x0, y0, x1, y1 = -y1, x0, -y0, x1
    return Box((x0, y0, z0), (x1, y1, z1), box.kind)


class Building:
    """A seeded building: floors of boxes, an elevator cabin, ray-casting scenes, GT samples."""

    def __init__(self, spec: BuildingSpec, start_floor: int, seed: int) -> None:
        self.spec = spec
        self.n_floors = spec.n_floors
        self.storeys_m = spec.storey_heights_m
        self.uniform = len(set(self.storeys_m)) == 1
        self.start_floor = start_floor
        self.seed = seed
        self.flights = [flight_geometry(spec.stairwell, h) for h in self.storeys_m]
        self.stairs = self.flights[0]
        if self.uniform:
            h = self.storeys_m[0]
            elevations = [(k - start_floor) * h for k in range(self.n_floors)]
        else:
            base = sum(self.storeys_m[:start_floor])
            elevations = [sum(self.storeys_m[:k]) - base for k in range(self.n_floors)]
        self.floors = [FloorGeometry(k, e) for k, e in enumerate(elevations)]
        rng = np.random.default_rng([seed, 7919])
        for floor in self.floors:
            self._build_floor(floor, rng)
        self._scenes: dict[Any, Any] = {}

    # -- geometry -------------------------------------------------------------------------
    @property
    def floor_height_m(self) -> float:
        """The storey height of a building whose storeys are all equal (an error otherwise)."""
        if not self.uniform:
            raise ValueError(f"storeys differ: {self.storeys_m}")
        return self.storeys_m[0]

    def elevation(self, floor_id: int) -> float:
        return self.floors[floor_id].elevation_m

    def storey_height(self, floor_id: int) -> float:
        """From this floor's slab top to the next one's (the top floor's: to the roof's)."""
        return self.storeys_m[floor_id]

    def floor_of_height(self, z_m: float) -> int:
        """The floor whose elevation is nearest to z (for ground-truth labels)."""
        if self.uniform:
            return int(np.clip(round(z_m / self.storeys_m[0]) + self.start_floor, 0, self.n_floors - 1))
        return int(self.floor_index_of_heights(np.array([z_m]))[0])

    def floor_index_of_heights(self, z_m: F64) -> npt.NDArray[np.int64]:
        """The nearest floor of each height."""
        elev = np.array([f.elevation_m for f in self.floors])
        return np.argmin(np.abs(np.asarray(z_m)[:, None] - elev[None, :]), axis=1).astype(np.int64)

    def floor_of_points(self, z_m: F64) -> npt.NDArray[np.int32]:
        """The floor whose space (its slab's top up to the next slab's underside) holds z."""
        e0 = self.floors[0].elevation_m
        if self.uniform:
            k = np.floor((z_m - e0 + 0.01) / self.storeys_m[0])
            return np.clip(k, 0, self.n_floors - 1).astype(np.int32)
        elev = np.array([f.elevation_m for f in self.floors])
        k = np.searchsorted(elev, np.asarray(z_m) + 0.01, side="right") - 1
        return np.clip(k, 0, self.n_floors - 1).astype(np.int32)

    @property
    def shaft_center(self) -> tuple[float, float]:
        return self.spec.shaft.center

    @property
    def cabin_half_m(self) -> float:
        return self.spec.shaft.cabin_half_m

    @property
    def stair_rect(self) -> tuple[float, float, float, float]:
        return self.spec.stairwell.rect

    @property
    def shaft_rect(self) -> tuple[float, float, float, float]:
        cx, cy = self.spec.shaft.center
        a = self.spec.shaft.outer_half_m
        return (cx - a, cx + a, cy - a, cy + a)

    def stair_hole(self, floor_id: int) -> tuple[float, float, float, float] | None:
        """The slab opening above the flights that come up from the floor below."""
        if floor_id == 0:
            return None
        st = self.spec.stairwell
        below = self.flights[floor_id - 1]
        if st.kind == "straight":
            lane = st.lane_a if (floor_id - 1) % 2 == 0 else st.lane_b
            return (st.flight_x0, below.flight_x1, lane[0], lane[1])
        x0, x1, y0, y1 = st.rect
        return (x0, st.flight_x0, y0, y1) if st.reverse else (st.flight_x0, x1, y0, y1)

    def _build_floor(self, floor: FloorGeometry, rng: np.random.Generator) -> None:
        e = floor.elevation_m
        h = self.storey_height(floor.floor_id)
        top = e + h - SLAB_M  # underside of the slab above
        boxes = floor.boxes
        xa, xb, ya, yb = self.spec.footprint
        out = (xa - OUTER_WALL_M, xb + OUTER_WALL_M, ya - OUTER_WALL_M, yb + OUTER_WALL_M)
        holes = []
        if floor.floor_id > 0:
            holes.append(self.shaft_rect)
            hole = self.stair_hole(floor.floor_id)
            if hole is not None:
                holes.append(hole)
        for x0, x1, y0, y1 in _rect_minus_holes(out, holes):
            boxes.append(Box((x0, y0, e - SLAB_M), (x1, y1, e), Kind.SLAB))
        if floor.floor_id == self.n_floors - 1:
            boxes.append(Box((out[0], out[2], e + h - SLAB_M), (out[1], out[3], e + h), Kind.SLAB))
        t = OUTER_WALL_M
        boxes += _wall("x", out[0], out[1], ya - t / 2, e, top, t)
        boxes += _wall("x", out[0], out[1], yb + t / 2, e, top, t)
        boxes += _wall("y", ya, yb, xa - t / 2, e, top, t)
        boxes += _wall("y", ya, yb, xb + t / 2, e, top, t)
        self._shaft(floor)
        if self.spec.stairwell.kind == "straight":
            self._stairwell(floor)
        else:
            self._switchback(floor)
        for axis, a0, a1, c in self.spec.extra_walls:
            boxes += _wall(axis, a0, a1, c, e, top, INNER_WALL_M)
        ph = self.spec.pillar_half_m
        for px, py in self.spec.pillars:
            boxes.append(Box((px - ph, py - ph, e), (px + ph, py + ph, top), Kind.PILLAR))
        for fx in self.spec.fixtures:
            boxes.append(Box((fx.lo[0], fx.lo[1], e + fx.lo[2]), (fx.hi[0], fx.hi[1], e + fx.hi[2]), fx.kind))
        for block in self.spec.blocks:
            self._block(floor, block, rng)

    def _shaft(self, floor: FloorGeometry) -> None:
        sh = self.spec.shaft
        e, h = floor.elevation_m, self.storey_height(floor.floor_id)
        x0, x1, y0, y1 = self.shaft_rect
        w = sh.wall_m
        cx, cy = sh.center
        z0 = e - SLAB_M if floor.floor_id > 0 else e
        top = e + h - SLAB_M
        c = cx if sh.door in "ns" else cy
        door = [(c - sh.door_half_m, c + sh.door_half_m, e + sh.door_height_m - z0)]
        floor.boxes += _wall("x", x0, x1, y0 + w / 2, z0, top, w, door if sh.door == "s" else ())
        floor.boxes += _wall("x", x0, x1, y1 - w / 2, z0, top, w, door if sh.door == "n" else ())
        floor.boxes += _wall("y", y0, y1, x0 + w / 2, z0, top, w, door if sh.door == "w" else ())
        floor.boxes += _wall("y", y0, y1, x1 - w / 2, z0, top, w, door if sh.door == "e" else ())

    def landing_door(self, floor_id: int) -> Box:
        sh = self.spec.shaft
        e = self.elevation(floor_id)
        cx, cy = sh.center
        x0, x1, y0, y1 = self.shaft_rect
        d, z1 = sh.door_half_m, e + sh.door_height_m
        if sh.door == "s":
            return Box((cx - d, y0 + 0.06, e), (cx + d, y0 + 0.1, z1), Kind.DOOR)
        if sh.door == "n":
            return Box((cx - d, y1 - 0.1, e), (cx + d, y1 - 0.06, z1), Kind.DOOR)
        if sh.door == "w":
            return Box((x0 + 0.06, cy - d, e), (x0 + 0.1, cy + d, z1), Kind.DOOR)
        return Box((x1 - 0.1, cy - d, e), (x1 - 0.06, cy + d, z1), Kind.DOOR)

    def _stairwell(self, floor: FloorGeometry) -> None:
        st = self.spec.stairwell
        e, h, k = floor.elevation_m, self.storey_height(floor.floor_id), floor.floor_id
        top = e + h - SLAB_M
        doors = [(a, b, DOOR_HEIGHT_M) for a, b in st.doors_x]
        floor.boxes += self._stair_walls(e, top, doors)
        s = self.flights[k]
        x1 = s.flight_x1
        fx0 = st.flight_x0
        # The divider between the lanes reaches through the slab so nobody falls into a hole.
        z_div = e - SLAB_M if k > 0 else e
        floor.boxes.append(Box((fx0, st.divider[0], z_div), (x1, st.divider[1], top), Kind.WALL))
        hole = self.stair_hole(k)
        if hole is not None:
            # Railing at the end of the hole where no flight arrives.
            x_rail = fx0 if (k - 1) % 2 == 0 else hole[1]
            floor.boxes.append(Box((x_rail - 0.03, hole[2], e), (x_rail + 0.03, hole[3], e + 1.0), Kind.WALL))
        if k < self.n_floors - 1:
            lane = st.lane_a if k % 2 == 0 else st.lane_b
            for i in range(1, s.n_risers):
                z_top = e + i * s.rise_m
                if k % 2 == 0:
                    xa, xb = fx0 + (i - 1) * st.tread_m, fx0 + i * st.tread_m
                else:
                    xa, xb = x1 - i * st.tread_m, x1 - (i - 1) * st.tread_m
                floor.boxes.append(Box((xa, lane[0], e), (xb, lane[1], z_top), Kind.STAIRS))

    def _stair_walls(self, e: float, top: float, doors: list[tuple[float, float, float]]) -> list[Box]:
        """The stairwell's own walls, doorways in the door wall."""
        st = self.spec.stairwell
        t = INNER_WALL_M
        sx0, sx1, sy0, sy1 = st.rect
        boxes: list[Box] = []
        if "n" in st.walls:
            boxes += _wall("x", sx0, sx1, sy1, e, top, t, doors if st.door_side == "n" else ())
        if "w" in st.walls:
            boxes += _wall("y", sy0, sy1, sx0, e, top, t)
        if "s" in st.walls:
            boxes += _wall("x", sx0, sx1, sy0, e, top, t, doors if st.door_side == "s" else ())
        if "e" in st.walls:
            boxes += _wall("y", sy0, sy1, sx1, e, top, t)
        return boxes

    def _switchback(self, floor: FloorGeometry) -> None:
        st = self.spec.stairwell
        k = floor.floor_id
        e, h = floor.elevation_m, self.storey_height(k)
        top = e + h - SLAB_M
        sx0, sx1, sy0, sy1 = st.rect
        floor.boxes += self._stair_walls(e, top, [(a, b, DOOR_HEIGHT_M) for a, b in st.doors_x])
        g = self.flights[k]
        sgn = -1.0 if st.reverse else 1.0
        fx0, T = st.flight_x0, st.tread_m
        far = fx0 + sgn * g.run_m  # where the flights meet the half landing
        # The divider between the lanes reaches down through the slab to the one below, but
        # where this storey's flights run on over the half landing below (a longer flight than
        # the storey's below) it stops at their underside, leaving headroom on that landing.
        prev_run = self.flights[k - 1].run_m if k > 0 else g.run_m
        reach = min(prev_run, g.run_m)
        cut = fx0 + sgn * reach
        z_div = e - SLAB_M if k > 0 else e
        lo, hi = sorted((fx0, cut))
        floor.boxes.append(Box((lo, st.divider[0], z_div), (hi, st.divider[1], top), Kind.WALL))
        if g.run_m > reach:
            z_under = e + (h / 2) * (reach / g.run_m) - g.rise_m - st.waist_m
            lo, hi = sorted((cut, far))
            floor.boxes.append(Box((lo, st.divider[0], z_under), (hi, st.divider[1], top), Kind.WALL))
        if k == self.n_floors - 1:
            # The top floor: no flight leaves it, so a railing closes lane a at the landing's edge.
            a0, a1 = st.lane_a
            floor.boxes.append(Box((fx0 - 0.03, a0, e), (fx0 + 0.03, a1, e + 1.0), Kind.WALL))
            return
        z_mid = e + h / 2
        m0, m1 = sorted((far, sx1 if sgn > 0 else sx0))
        floor.boxes.append(Box((m0, sy0, z_mid - SLAB_M), (m1, sy1, z_mid), Kind.SLAB))
        for i in range(1, g.n_risers):
            # Lane a up from the floor, lane b up from the half landing; each step a slice of a
            # slab `waist_m` thick, so the flights above and below leave headroom.
            for lane, z_base, start, step in ((st.lane_a, e, fx0, sgn * T), (st.lane_b, z_mid, far, -sgn * T)):
                z_top = z_base + i * g.rise_m
                xa, xb = sorted((start + (i - 1) * step, start + i * step))
                floor.boxes.append(Box((xa, lane[0], z_top - g.rise_m - st.waist_m), (xb, lane[1], z_top), Kind.STAIRS))

    def _block(self, floor: FloorGeometry, block: Block, rng: np.random.Generator) -> None:
        x0, x1, y0, y1, sides = block.x0, block.x1, block.y0, block.y1, block.sides
        e = floor.elevation_m
        top = e + self.storey_height(floor.floor_id) - SLAB_M
        t = INNER_WALL_M
        along_x = (x1 - x0) >= (y1 - y0)
        length = (x1 - x0) if along_x else (y1 - y0)
        n_rooms = int(rng.integers(max(1, int(length // 7)), max(2, int(length // 3.5)) + 1))
        cuts = np.sort(rng.uniform(0.15, 0.85, n_rooms - 1)) if n_rooms > 1 else np.zeros(0)
        edges = [0.0, *[float(c) * length for c in cuts], length]
        # Drop rooms narrower than 2.2 m: merge by removing their cut.
        merged = [edges[0]]
        for v in edges[1:]:
            if v - merged[-1] < 2.2 and v != length:
                continue
            if v == length and v - merged[-1] < 2.2 and len(merged) > 1:
                merged[-1] = v
                continue
            merged.append(v)
        edges = merged
        base = x0 if along_x else y0
        rooms = []
        for a, b in itertools.pairwise(edges):
            if along_x:
                rooms.append((x0 + a, x0 + b, y0, y1))
            else:
                rooms.append((x0, x1, y0 + a, y0 + b))
        for a in edges[1:-1]:
            c = base + a
            if along_x:
                floor.boxes += _wall("y", y0, y1, c, e, top, t)
            else:
                floor.boxes += _wall("x", x0, x1, c, e, top, t)
        # Perimeter walls facing corridors, with one doorway per room on a corridor side.
        openings: dict[str, list[tuple[float, float, float]]] = {s: [] for s in "nswe"}
        for rx0, rx1, ry0, ry1 in rooms:
            options = []
            for s in sides:
                lo, hi = (rx0, rx1) if s in "ns" else (ry0, ry1)
                lim = next(((a, b) for side, a, b in block.limits if side == s), None)
                if lim is not None:
                    lo, hi = max(lo, lim[0]), min(hi, lim[1])
                if hi - lo >= 1.8:
                    options.append((s, lo, hi))
            if not options:
                continue
            s, lo, hi = options[int(rng.integers(len(options)))]
            width = min(float(rng.uniform(0.9, 1.3)), hi - lo - 0.7)
            start = float(rng.uniform(lo + 0.3, hi - 0.3 - width))
            openings[s].append((start, start + width, DOOR_HEIGHT_M))
            self._furniture(floor, (rx0, rx1, ry0, ry1), s, (start, start + width), rng)
        fx0, fx1, fy0, fy1 = self.spec.footprint
        outer = {("n", fy1), ("s", fy0), ("w", fx0), ("e", fx1)}
        for s in "nswe":
            if (s, {"n": y1, "s": y0, "w": x0, "e": x1}[s]) in outer:
                continue
            if s == "n":
                floor.boxes += _wall("x", x0, x1, y1, e, top, t, openings[s])
            elif s == "s":
                floor.boxes += _wall("x", x0, x1, y0, e, top, t, openings[s])
            elif s == "w":
                floor.boxes += _wall("y", y0, y1, x0, e, top, t, openings[s])
            else:
                floor.boxes += _wall("y", y0, y1, x1, e, top, t, openings[s])

    def _furniture(
        self,
        floor: FloorGeometry,
        room: tuple[float, float, float, float],
        door_side: str,
        door_span: tuple[float, float],
        rng: np.random.Generator,
    ) -> None:
        rx0, rx1, ry0, ry1 = room
        e = floor.elevation_m
        m = 0.15
        n = int(rng.integers(1, 5))
        for _ in range(n):
            kind = int(rng.integers(3))
            if kind == 0:  # desk/table
                w, d, hgt = float(rng.uniform(1.0, 1.8)), float(rng.uniform(0.6, 0.9)), 0.75
            elif kind == 1:  # cabinet/shelf
                w, d, hgt = float(rng.uniform(0.6, 1.4)), 0.45, float(rng.uniform(1.6, 2.1))
            else:  # box/crate/sofa
                w, d, hgt = float(rng.uniform(0.5, 1.0)), float(rng.uniform(0.5, 1.0)), float(rng.uniform(0.4, 1.0))
            if rng.random() < 0.5:
                w, d = d, w
            if rx1 - rx0 < w + 2 * m or ry1 - ry0 < d + 2 * m:
                continue
            x = float(rng.uniform(rx0 + m, rx1 - m - w))
            y = float(rng.uniform(ry0 + m, ry1 - m - d))
            # Keep the doorway clear: 1.2 m in front of the door.
            da, db = door_span
            if door_side in "ns":
                yd = ry1 if door_side == "n" else ry0
                if x < db + 0.3 and x + w > da - 0.3 and min(abs(y - yd), abs(y + d - yd)) < 1.5:
                    continue
            else:
                xd = rx1 if door_side == "e" else rx0
                if y < db + 0.3 and y + d > da - 0.3 and min(abs(x - xd), abs(x + w - xd)) < 1.5:
                    continue
            floor.boxes.append(Box((x, y, e), (x + w, y + d, e + hgt), Kind.FURNITURE))

    # -- elevator cabin (in its own frame: origin at the cabin floor centre) ----------------
    def cabin_boxes(self, door_closed: bool) -> list[Box]:
        sh = self.spec.shaft
        a, w, hc, dh, dz = sh.cabin_half_m, sh.cabin_wall_m, sh.cabin_height_m, sh.door_half_m, sh.door_height_m
        boxes = [
            Box((-a, -a, -0.1), (a, a, 0.0), Kind.CABIN_FLOOR),
            Box((-a, -a, hc), (a, a, hc + 0.1), Kind.CABIN_FLOOR),
        ]
        door = [(-dh, dh, dz)]
        boxes += _wall("x", -a, a, -a + w / 2, 0.0, hc, w, door, Kind.CABIN_WALL)
        boxes += _wall("x", -a, a, a - w / 2, 0.0, hc, w, kind=Kind.CABIN_WALL)
        boxes += _wall("y", -a, a, -a + w / 2, 0.0, hc, w, kind=Kind.CABIN_WALL)
        boxes += _wall("y", -a, a, a - w / 2, 0.0, hc, w, kind=Kind.CABIN_WALL)
        if door_closed:
            boxes.append(Box((-dh, -a + 0.005, 0.0), (dh, -a + w - 0.005, dz), Kind.CABIN_WALL))
        # Built with the doors at -y, then turned to face the shaft's doors.
        turns = {"s": 0, "e": 1, "n": 2, "w": 3}[sh.door]
        return boxes if turns == 0 else [_rotate_box(b, turns) for b in boxes]

    # -- ray casting ---------------------------------------------------------------------
    def static_boxes(self) -> list[Box]:
        return [b for f in self.floors for b in f.boxes]

    def scene(self, open_floor: int | None) -> Any:
        """Building scene with every landing door closed except the one on `open_floor`."""
        key = ("building", open_floor)
        if key not in self._scenes:
            boxes = self.static_boxes() + [
                self.landing_door(k) for k in range(self.n_floors) if k != open_floor
            ]
            self._scenes[key] = _make_scene(boxes)
        return self._scenes[key]

    def cabin_scene(self, door_closed: bool) -> Any:
        key = ("cabin", door_closed)
        if key not in self._scenes:
            self._scenes[key] = _make_scene(self.cabin_boxes(door_closed))
        return self._scenes[key]

    # -- ground truth surface samples ------------------------------------------------------
    def surface_samples(
        self, spacing_m: float, seed: int, chunk: int = 250_000
    ) -> tuple[int, Iterator[tuple[F32, npt.NDArray[np.int32]]]]:
        """Uniform random samples of every static surface with floor ids: the building and its
        closed landing doors (closed nearly all the time), not the moving cabin. Labels follow
        `floor_of_points`: a slab's underside is the ceiling of the floor below.

        Returns the total count and an iterator of chunks, so a writer can stream them."""
        count_rng = np.random.default_rng([seed, 104729, 0])
        density = 1.0 / spacing_m**2
        per_floor = []
        for floor in self.floors:
            verts, tris = box_triangles([*floor.boxes, self.landing_door(floor.floor_id)])
            tri = verts.astype(np.float64)[tris]
            area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
            per_floor.append((tri, count_rng.poisson(area * density)))
        total = int(sum(int(c.sum()) for _, c in per_floor))

        def chunks() -> Iterator[tuple[F32, npt.NDArray[np.int32]]]:
            rng = np.random.default_rng([seed, 104729, 1])
            for tri, counts in per_floor:
                idx = np.repeat(np.arange(len(tri), dtype=np.int32), counts)
                for start in range(0, len(idx), chunk):
                    sub = idx[start : start + chunk]
                    u = rng.random((len(sub), 2))
                    flip = u.sum(axis=1) > 1
                    u[flip] = 1 - u[flip]
                    t = tri[sub]
                    p = t[:, 0] + u[:, :1] * (t[:, 1] - t[:, 0]) + u[:, 1:] * (t[:, 2] - t[:, 0])
                    yield p.astype(np.float32), self.floor_of_points(p[:, 2])

        return total, chunks()

    def sample_surfaces(self, spacing_m: float, seed: int) -> tuple[F32, npt.NDArray[np.int32]]:
        """All of `surface_samples` in memory: (N, 3) points and their floor ids."""
        _, it = self.surface_samples(spacing_m, seed)
        parts = list(it)
        return np.concatenate([p for p, _ in parts]), np.concatenate([f for _, f in parts])


def _make_scene(boxes: list[Box]) -> Any:
    import open3d as o3d

    verts, tris = box_triangles(boxes)
    tensor: Any = o3d.core.Tensor
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(tensor(verts), tensor(tris))
    return scene


def cast_rays(scene: Any, rays: F32) -> tuple[F32, npt.NDArray[np.uint32], F32]:
    """Distances along the (N, 6) rays' unit directions (inf on a miss), hit triangle ids, normals."""
    import open3d as o3d

    tensor: Any = o3d.core.Tensor
    ans = scene.cast_rays(tensor(np.ascontiguousarray(rays, dtype=np.float32)), nthreads=0)
    return (
        ans["t_hit"].numpy(),
        ans["primitive_ids"].numpy(),
        ans["primitive_normals"].numpy(),
    )


def kinds_of(boxes: list[Box]) -> npt.NDArray[np.int8]:
    """Per-triangle surface kind for a scene built from `boxes`."""
    return np.repeat(np.array([b.kind for b in boxes], dtype=np.int8), 12)
