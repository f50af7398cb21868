"""Axis-aligned boxes, the simulator's only solid: surface kinds, walls with doorways, their
triangles and open3d's RaycastingScene over them."""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from mfmap.types import F32


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


def rect_minus_holes(
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


def wall(
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


def rotate_box(box: Box, quarter_turns: int) -> Box:
    """A box turned about the z axis by quarter_turns * 90 deg (exact: only swaps and signs)."""
    (x0, y0, z0), (x1, y1, z1) = box.lo, box.hi
    for _ in range(quarter_turns % 4):
        x0, y0, x1, y1 = -y1, x0, -y0, x1
    return Box((x0, y0, z0), (x1, y1, z1), box.kind)


def make_scene(boxes: list[Box]) -> Any:
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
