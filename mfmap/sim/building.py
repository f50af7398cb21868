"""The seeded building a scenario runs in: its floors of boxes (`floorplan`), the elevator cabin,
ray-casting scenes and ground-truth surface samples. What a building is made of is its
`BuildingSpec` (`spec`); the office block's plan is drawn in that module's docstring.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import numpy.typing as npt

from mfmap.sim.boxes import Box, Kind, box_triangles, make_scene, rotate_box, wall
from mfmap.sim.floorplan import FloorGeometry, FloorPlan
from mfmap.sim.spec import BuildingSpec, flight_geometry
from mfmap.types import F32, F64


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
        self.plan = FloorPlan(spec, self.flights)
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
            self.plan.build_floor(floor, rng)
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
        return self.plan.shaft_rect

    def stair_hole(self, floor_id: int) -> tuple[float, float, float, float] | None:
        """The slab opening above the flights that come up from the floor below."""
        return self.plan.stair_hole(floor_id)

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

    # -- elevator cabin (in its own frame: origin at the cabin floor centre) ----------------
    def cabin_boxes(self, door_closed: bool) -> list[Box]:
        sh = self.spec.shaft
        a, w, hc, dh, dz = sh.cabin_half_m, sh.cabin_wall_m, sh.cabin_height_m, sh.door_half_m, sh.door_height_m
        boxes = [
            Box((-a, -a, -0.1), (a, a, 0.0), Kind.CABIN_FLOOR),
            Box((-a, -a, hc), (a, a, hc + 0.1), Kind.CABIN_FLOOR),
        ]
        door = [(-dh, dh, dz)]
        boxes += wall("x", -a, a, -a + w / 2, 0.0, hc, w, door, Kind.CABIN_WALL)
        boxes += wall("x", -a, a, a - w / 2, 0.0, hc, w, kind=Kind.CABIN_WALL)
        boxes += wall("y", -a, a, -a + w / 2, 0.0, hc, w, kind=Kind.CABIN_WALL)
        boxes += wall("y", -a, a, a - w / 2, 0.0, hc, w, kind=Kind.CABIN_WALL)
        if door_closed:
            boxes.append(Box((-dh, -a + 0.005, 0.0), (dh, -a + w - 0.005, dz), Kind.CABIN_WALL))
        # Built with the doors at -y, then turned to face the shaft's doors.
        turns = {"s": 0, "e": 1, "n": 2, "w": 3}[sh.door]
        return boxes if turns == 0 else [rotate_box(b, turns) for b in boxes]

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
            self._scenes[key] = make_scene(boxes)
        return self._scenes[key]

    def cabin_scene(self, door_closed: bool) -> Any:
        key = ("cabin", door_closed)
        if key not in self._scenes:
            self._scenes[key] = make_scene(self.cabin_boxes(door_closed))
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
