"""The boxes of a building's floors, drawn from its spec.

Every floor gets its slab (holes for the shaft and the flights from below), the outer walls, the
elevator shaft, the stairwell (straight or switch-back flights), extra walls, pillars and fixtures
from the spec, and the rooms of each block: their walls, doorways and furniture drawn from the
building's seeded generator, floor after floor.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from mfmap.sim.boxes import Box, Kind, rect_minus_holes, wall
from mfmap.sim.spec import (
    DOOR_HEIGHT_M,
    INNER_WALL_M,
    OUTER_WALL_M,
    SLAB_M,
    Block,
    BuildingSpec,
    StairGeometry,
    StairwellSpec,
)

Rect = tuple[float, float, float, float]  # x0, x1, y0, y1


@dataclass
class FloorGeometry:
    """One floor: its index, its slab top's height and its boxes."""

    floor_id: int
    elevation_m: float
    boxes: list[Box] = field(default_factory=list)


class FloorPlan:
    """A spec's static geometry: the slab holes and the boxes of each floor."""

    def __init__(self, spec: BuildingSpec, flights: list[StairGeometry]) -> None:
        self.spec = spec
        self.n_floors = spec.n_floors
        self.flights = flights

    def storey_height(self, floor_id: int) -> float:
        """From this floor's slab top to the next one's (the top floor's: to the roof's)."""
        return self.spec.storey_heights_m[floor_id]

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

    def build_floor(self, floor: FloorGeometry, rng: np.random.Generator) -> None:
        """Add the floor's boxes; its blocks' rooms draw from `rng`."""
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
        for x0, x1, y0, y1 in rect_minus_holes(out, holes):
            boxes.append(Box((x0, y0, e - SLAB_M), (x1, y1, e), Kind.SLAB))
        if floor.floor_id == self.n_floors - 1:
            boxes.append(Box((out[0], out[2], e + h - SLAB_M), (out[1], out[3], e + h), Kind.SLAB))
        t = OUTER_WALL_M
        boxes += wall("x", out[0], out[1], ya - t / 2, e, top, t)
        boxes += wall("x", out[0], out[1], yb + t / 2, e, top, t)
        boxes += wall("y", ya, yb, xa - t / 2, e, top, t)
        boxes += wall("y", ya, yb, xb + t / 2, e, top, t)
        self._shaft(floor)
        if self.spec.stairwell.kind == "straight":
            self._stairwell(floor)
        else:
            self._switchback(floor)
        for axis, a0, a1, c in self.spec.extra_walls:
            boxes += wall(axis, a0, a1, c, e, top, INNER_WALL_M)
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
        floor.boxes += wall("x", x0, x1, y0 + w / 2, z0, top, w, door if sh.door == "s" else ())
        floor.boxes += wall("x", x0, x1, y1 - w / 2, z0, top, w, door if sh.door == "n" else ())
        floor.boxes += wall("y", y0, y1, x0 + w / 2, z0, top, w, door if sh.door == "w" else ())
        floor.boxes += wall("y", y0, y1, x1 - w / 2, z0, top, w, door if sh.door == "e" else ())

    def _stairwell(self, floor: FloorGeometry) -> None:
        st = self.spec.stairwell
        e, h, k = floor.elevation_m, self.storey_height(floor.floor_id), floor.floor_id
        top = e + h - SLAB_M
        doors = [(a, b, DOOR_HEIGHT_M) for a, b in st.doors_x]
        floor.boxes += _stair_walls(st, e, top, doors)
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

    def _switchback(self, floor: FloorGeometry) -> None:
        st = self.spec.stairwell
        k = floor.floor_id
        e, h = floor.elevation_m, self.storey_height(k)
        top = e + h - SLAB_M
        sx0, sx1, sy0, sy1 = st.rect
        floor.boxes += _stair_walls(st, e, top, [(a, b, DOOR_HEIGHT_M) for a, b in st.doors_x])
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
        """A block's rooms, their doorways and furniture, and its walls that face corridors."""
        x0, x1, y0, y1 = block.x0, block.x1, block.y0, block.y1
        e = floor.elevation_m
        top = e + self.storey_height(floor.floor_id) - SLAB_M
        t = INNER_WALL_M
        rooms = _rooms(floor, block, top, rng)
        # Perimeter walls facing corridors, with one doorway per room on a corridor side.
        openings = _doorways(floor, block, rooms, rng)
        fx0, fx1, fy0, fy1 = self.spec.footprint
        outer = {("n", fy1), ("s", fy0), ("w", fx0), ("e", fx1)}
        for s in "nswe":
            if (s, {"n": y1, "s": y0, "w": x0, "e": x1}[s]) in outer:
                continue
            if s == "n":
                floor.boxes += wall("x", x0, x1, y1, e, top, t, openings[s])
            elif s == "s":
                floor.boxes += wall("x", x0, x1, y0, e, top, t, openings[s])
            elif s == "w":
                floor.boxes += wall("y", y0, y1, x0, e, top, t, openings[s])
            else:
                floor.boxes += wall("y", y0, y1, x1, e, top, t, openings[s])


def _stair_walls(st: StairwellSpec, e: float, top: float, doors: list[tuple[float, float, float]]) -> list[Box]:
    """The stairwell's own walls, doorways in the door wall."""
    t = INNER_WALL_M
    sx0, sx1, sy0, sy1 = st.rect
    boxes: list[Box] = []
    if "n" in st.walls:
        boxes += wall("x", sx0, sx1, sy1, e, top, t, doors if st.door_side == "n" else ())
    if "w" in st.walls:
        boxes += wall("y", sy0, sy1, sx0, e, top, t)
    if "s" in st.walls:
        boxes += wall("x", sx0, sx1, sy0, e, top, t, doors if st.door_side == "s" else ())
    if "e" in st.walls:
        boxes += wall("y", sy0, sy1, sx1, e, top, t)
    return boxes


def _rooms(floor: FloorGeometry, block: Block, top: float, rng: np.random.Generator) -> list[Rect]:
    """A block cut into rooms along its longer side (none narrower than 2.2 m), with the walls
    between them."""
    x0, x1, y0, y1 = block.x0, block.x1, block.y0, block.y1
    e = floor.elevation_m
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
            floor.boxes += wall("y", y0, y1, c, e, top, t)
        else:
            floor.boxes += wall("x", x0, x1, c, e, top, t)
    return rooms


def _doorways(
    floor: FloorGeometry, block: Block, rooms: list[Rect], rng: np.random.Generator
) -> dict[str, list[tuple[float, float, float]]]:
    """One doorway per room on a side that faces a corridor (the openings of each side's wall),
    and the room's furniture, clear of its doorway."""
    sides = block.sides
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
        _furniture(floor, (rx0, rx1, ry0, ry1), s, (start, start + width), rng)
    return openings


def _furniture(
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
