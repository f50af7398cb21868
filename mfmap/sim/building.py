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

Corridors, outer walls, the elevator shaft, the stairwell and pillars are the same on every
floor; rooms inside the blocks, their doorways and furniture are drawn per floor from the seed.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]

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
_OUTER_SIDES = {("n", Y_MAX), ("s", Y_MIN), ("w", X_MIN), ("e", X_MAX)}


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
class StairGeometry:
    n_risers: int
    rise_m: float
    run_m: float  # horizontal length of one flight

    @property
    def flight_x1(self) -> float:
        return STAIR_FLIGHT_X0 + self.run_m


class Building:
    """A seeded building: floors of boxes, an elevator cabin, ray-casting scenes, GT samples."""

    def __init__(self, n_floors: int, floor_height_m: float, start_floor: int, seed: int) -> None:
        self.n_floors = n_floors
        self.floor_height_m = floor_height_m
        self.start_floor = start_floor
        self.seed = seed
        n_risers = max(2, round(floor_height_m / STAIR_RISE_M))
        self.stairs = StairGeometry(
            n_risers, floor_height_m / n_risers, (n_risers - 1) * STAIR_TREAD_M
        )
        self.floors = [
            FloorGeometry(k, (k - start_floor) * floor_height_m) for k in range(n_floors)
        ]
        rng = np.random.default_rng([seed, 7919])
        for floor in self.floors:
            self._build_floor(floor, rng)
        self._scenes: dict[Any, Any] = {}

    # -- geometry -------------------------------------------------------------------------
    def elevation(self, floor_id: int) -> float:
        return self.floors[floor_id].elevation_m

    def floor_of_height(self, z_m: float) -> int:
        """The floor whose elevation is nearest to z (for ground-truth labels)."""
        return int(np.clip(round(z_m / self.floor_height_m) + self.start_floor, 0, self.n_floors - 1))

    def floor_index_of_heights(self, z_m: F64) -> npt.NDArray[np.int64]:
        """`floor_of_height` for an array of heights."""
        elev = np.array([f.elevation_m for f in self.floors])
        return np.argmin(np.abs(np.asarray(z_m)[:, None] - elev[None, :]), axis=1).astype(np.int64)

    def storey_height(self, floor_id: int) -> float:
        """From this floor's slab top to the next one's."""
        return self.floor_height_m

    @property
    def shaft_center(self) -> tuple[float, float]:
        return SHAFT_CENTER

    @property
    def cabin_half_m(self) -> float:
        return CABIN_HALF

    @property
    def stair_rect(self) -> tuple[float, float, float, float]:
        return (STAIR_X0, STAIR_X1, STAIR_Y0, STAIR_Y1)

    def floor_of_points(self, z_m: F64) -> npt.NDArray[np.int32]:
        """The floor whose space (its slab's top up to the next slab's underside) holds z."""
        e0 = self.floors[0].elevation_m
        k = np.floor((z_m - e0 + 0.01) / self.floor_height_m)
        return np.clip(k, 0, self.n_floors - 1).astype(np.int32)

    @property
    def shaft_rect(self) -> tuple[float, float, float, float]:
        cx, cy = SHAFT_CENTER
        return (cx - SHAFT_OUTER_HALF, cx + SHAFT_OUTER_HALF, cy - SHAFT_OUTER_HALF, cy + SHAFT_OUTER_HALF)

    def stair_hole(self, floor_id: int) -> tuple[float, float, float, float] | None:
        """The slab opening above the flight that comes up from the floor below."""
        if floor_id == 0:
            return None
        lane = LANE_A_Y if (floor_id - 1) % 2 == 0 else LANE_B_Y
        return (STAIR_FLIGHT_X0, self.stairs.flight_x1, lane[0], lane[1])

    def _build_floor(self, floor: FloorGeometry, rng: np.random.Generator) -> None:
        e = floor.elevation_m
        h = self.floor_height_m
        top = e + h - SLAB_M  # underside of the slab above
        boxes = floor.boxes
        out = (X_MIN - OUTER_WALL_M, X_MAX + OUTER_WALL_M, Y_MIN - OUTER_WALL_M, Y_MAX + OUTER_WALL_M)
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
        boxes += _wall("x", out[0], out[1], Y_MIN - t / 2, e, top, t)
        boxes += _wall("x", out[0], out[1], Y_MAX + t / 2, e, top, t)
        boxes += _wall("y", Y_MIN, Y_MAX, X_MIN - t / 2, e, top, t)
        boxes += _wall("y", Y_MIN, Y_MAX, X_MAX + t / 2, e, top, t)
        self._shaft(floor)
        self._stairwell(floor)
        for px, py in PILLARS_XY:
            boxes.append(Box((px - PILLAR_HALF, py - PILLAR_HALF, e), (px + PILLAR_HALF, py + PILLAR_HALF, top), Kind.PILLAR))
        for block in BLOCKS:
            self._block(floor, block, rng)

    def _shaft(self, floor: FloorGeometry) -> None:
        e, h = floor.elevation_m, self.floor_height_m
        x0, x1, y0, y1 = self.shaft_rect
        w = SHAFT_WALL_M
        cx = SHAFT_CENTER[0]
        z0 = e - SLAB_M if floor.floor_id > 0 else e
        door = [(cx - ELEVATOR_DOOR_HALF, cx + ELEVATOR_DOOR_HALF, e + ELEVATOR_DOOR_HEIGHT_M - z0)]
        floor.boxes += _wall("x", x0, x1, y0 + w / 2, z0, e + h - SLAB_M, w, door)
        floor.boxes += _wall("x", x0, x1, y1 - w / 2, z0, e + h - SLAB_M, w)
        floor.boxes += _wall("y", y0, y1, x0 + w / 2, z0, e + h - SLAB_M, w)
        floor.boxes += _wall("y", y0, y1, x1 - w / 2, z0, e + h - SLAB_M, w)

    def landing_door(self, floor_id: int) -> Box:
        e = self.elevation(floor_id)
        cx = SHAFT_CENTER[0]
        y0 = self.shaft_rect[2]
        return Box((cx - ELEVATOR_DOOR_HALF, y0 + 0.06, e), (cx + ELEVATOR_DOOR_HALF, y0 + 0.1, e + ELEVATOR_DOOR_HEIGHT_M), Kind.DOOR)

    def _stairwell(self, floor: FloorGeometry) -> None:
        e, h, k = floor.elevation_m, self.floor_height_m, floor.floor_id
        top = e + h - SLAB_M
        t = INNER_WALL_M
        doors = [(a, b, DOOR_HEIGHT_M) for a, b in STAIR_DOOR_X]
        floor.boxes += _wall("x", STAIR_X0, STAIR_X1, STAIR_Y1, e, top, t, doors)
        floor.boxes += _wall("y", STAIR_Y0, STAIR_Y1, STAIR_X0, e, top, t)
        x1 = self.stairs.flight_x1
        # The divider between the lanes reaches through the slab so nobody falls into a hole.
        z_div = e - SLAB_M if k > 0 else e
        floor.boxes.append(Box((STAIR_FLIGHT_X0, -14.06, z_div), (x1, -13.94, top), Kind.WALL))
        hole = self.stair_hole(k)
        if hole is not None:
            # Railing at the end of the hole where no flight arrives.
            x_rail = STAIR_FLIGHT_X0 if (k - 1) % 2 == 0 else x1
            floor.boxes.append(Box((x_rail - 0.03, hole[2], e), (x_rail + 0.03, hole[3], e + 1.0), Kind.WALL))
        if k < self.n_floors - 1:
            lane = LANE_A_Y if k % 2 == 0 else LANE_B_Y
            s = self.stairs
            for i in range(1, s.n_risers):
                z_top = e + i * s.rise_m
                if k % 2 == 0:
                    xa, xb = STAIR_FLIGHT_X0 + (i - 1) * STAIR_TREAD_M, STAIR_FLIGHT_X0 + i * STAIR_TREAD_M
                else:
                    xa, xb = x1 - i * STAIR_TREAD_M, x1 - (i - 1) * STAIR_TREAD_M
                floor.boxes.append(Box((xa, lane[0], e), (xb, lane[1], z_top), Kind.STAIRS))

    def _block(self, floor: FloorGeometry, block: tuple[str, float, float, float, float, str], rng: np.random.Generator) -> None:
        name, x0, x1, y0, y1, sides = block
        e = floor.elevation_m
        top = e + self.floor_height_m - SLAB_M
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
                lim = SIDE_LIMITS.get((name, s))
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
        for s in "nswe":
            if (s, {"n": y1, "s": y0, "w": x0, "e": x1}[s]) in _OUTER_SIDES:
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
        a, w, hc = CABIN_HALF, CABIN_WALL_M, CABIN_HEIGHT_M
        boxes = [
            Box((-a, -a, -0.1), (a, a, 0.0), Kind.CABIN_FLOOR),
            Box((-a, -a, hc), (a, a, hc + 0.1), Kind.CABIN_FLOOR),
        ]
        door = [(-ELEVATOR_DOOR_HALF, ELEVATOR_DOOR_HALF, ELEVATOR_DOOR_HEIGHT_M)]
        boxes += _wall("x", -a, a, -a + w / 2, 0.0, hc, w, door, Kind.CABIN_WALL)
        boxes += _wall("x", -a, a, a - w / 2, 0.0, hc, w, kind=Kind.CABIN_WALL)
        boxes += _wall("y", -a, a, -a + w / 2, 0.0, hc, w, kind=Kind.CABIN_WALL)
        boxes += _wall("y", -a, a, a - w / 2, 0.0, hc, w, kind=Kind.CABIN_WALL)
        if door_closed:
            boxes.append(Box((-ELEVATOR_DOOR_HALF, -a + 0.005, 0.0), (ELEVATOR_DOOR_HALF, -a + w - 0.005, ELEVATOR_DOOR_HEIGHT_M), Kind.CABIN_WALL))
        return boxes

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
