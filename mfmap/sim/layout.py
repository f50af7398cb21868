"""Generated office buildings, a different one per seed, and routes along their corridors.

A generated building is a rectangle of 24-38 x 18-26 m cut by one or two corridors along x and
one to three along y, each 1.8-2.8 m wide and running wall to wall; the blocks between them hold
rooms. The elevator shaft and a switch-back stairwell sit in blocks beside an x corridor, their
doors on it, each carved out of its block as a strip; wide corridors have pillars along one side.
The storeys are drawn too: their count, and heights from 2.6 to 6 m, equal or not (a tall lobby
under lower offices). Checkpoints are corridor crossings and ends; the first is the start, the
world origin, with the robot facing +x along an x corridor.

`plan_path` finds the shortest way between two points on the corridors' centre lines.
"""

from __future__ import annotations

import heapq
import itertools
import math
from dataclasses import dataclass, replace

import numpy as np

from mfmap.sim.spec import (
    Block,
    BuildingSpec,
    Corridor,
    ShaftSpec,
    StairwellSpec,
    flight_geometry,
)

Range = tuple[float, float]

_SHAFT_HALF = 1.35  # outer half-size of the shaft (as the office block's)
_LANE_M = 1.8
_STAIR_DEPTH_M = 4.0  # two lanes, a divider, clearances
_FLOOR_LANDING_M = 1.5
_HALF_LANDING_M = (1.3, 1.7)
_END_INSET_M = 0.6  # a corridor's centre line stops this short of its end wall


@dataclass(frozen=True)
class FamilySpec:
    """The ranges a generated building is drawn from."""

    n_floors: tuple[int, int] = (3, 5)  # inclusive
    width_m: Range = (24.0, 38.0)
    depth_m: Range = (18.0, 26.0)
    # "equal": every storey one height from storey_m; "lobby": a storey of lobby_m under equal
    # storeys of office_m; "mixed": each storey its own from storey_m, a lobby half the time.
    storeys: str = "mixed"
    storey_m: Range = (2.6, 4.2)
    lobby_m: Range = (4.5, 6.0)
    office_m: Range = (3.2, 3.8)
    elevator_speed_m_s: Range = (1.0, 1.6)
    elevator_acc_m_s2: Range = (0.5, 0.9)


def _u(rng: np.random.Generator, r: Range) -> float:
    return float(rng.uniform(*r)) if r[1] > r[0] else float(r[0])


def _storeys(rng: np.random.Generator, fam: FamilySpec, n: int) -> tuple[float, ...]:
    if fam.storeys == "equal":
        h = round(_u(rng, fam.storey_m), 2)
        return (h,) * n
    if fam.storeys == "lobby":
        office = round(_u(rng, fam.office_m), 2)
        return (round(_u(rng, fam.lobby_m), 2),) + (office,) * (n - 1)
    hs = [round(_u(rng, fam.storey_m), 2) for _ in range(n)]
    if rng.random() < 0.5:
        hs[0] = round(_u(rng, fam.lobby_m), 2)
    return tuple(hs)


def _bands(rng: np.random.Generator, length: float, n: int, width: Range, min_band: float) -> list[tuple[float, float]]:
    """n corridors (lo, hi) across `length`, spread evenly with jitter, each band between them
    (and the walls) at least min_band long."""
    for _ in range(200):
        widths = [_u(rng, width) for _ in range(n)]
        centres = sorted(length * (i + 1) / (n + 1) + float(rng.uniform(-0.12, 0.12)) * length / (n + 1) for i in range(n))
        spans = [(c - w / 2, c + w / 2) for c, w in zip(centres, widths, strict=True)]
        edges = [0.0, *[v for s in spans for v in s], length]
        if all(b - a >= min_band for a, b in zip(edges[::2], edges[1::2], strict=True)):
            return [(round(a, 3), round(b, 3)) for a, b in spans]
    raise ValueError(f"no room for {n} corridors across {length:.1f} m")


def generate_building(seed: int, family: FamilySpec | None = None) -> BuildingSpec:
    """One building of the family, drawn from `seed` (rooms and furniture come later, per floor,
    from the same seed)."""
    fam = family or FamilySpec()
    rng = np.random.default_rng([seed, 4409])
    for _attempt in range(100):
        spec = _try_generate(rng, fam, seed)
        if spec is not None:
            return spec
    raise ValueError(f"seed {seed}: no building of the family fits its draws")


Cell = tuple[float, float, float, float, str]  # x0, x1, y0, y1, sides facing a corridor
Walls = list[tuple[str, float, float, float]]


@dataclass(frozen=True)
class _Grid:
    """A drawn footprint W x D, its storeys, its corridors along x (their y spans) and along y
    (their x spans), and the blocks between them."""

    W: float
    D: float
    storeys: tuple[float, ...]
    xc: list[tuple[float, float]]
    yc: list[tuple[float, float]]
    cells: list[Cell]


def _try_generate(rng: np.random.Generator, fam: FamilySpec, seed: int) -> BuildingSpec | None:
    grid = _draw_grid(rng, fam)
    if grid is None:
        return None
    W, D, storeys, xc, yc, cells = grid.W, grid.D, grid.storeys, grid.xc, grid.yc, grid.cells
    # The stairwell: a strip of a block beside an x corridor, long enough for the longest flight.
    stair_cfg = StairwellSpec(kind="switchback")
    run = max(flight_geometry(stair_cfg, h).run_m for h in storeys)
    half_landing = _u(rng, _HALF_LANDING_M)
    stair_len = _FLOOR_LANDING_M + run + half_landing
    order = list(rng.permutation(len(cells)))
    stair = _place_stairwell(rng, cells, order, stair_len)
    if stair is None:
        return None
    shaft = _place_shaft(rng, cells, order, stair)
    if shaft is None:
        return None
    walls: Walls = []
    carved: dict[int, list[tuple[float, float]]] = {}
    stairwell, s_cy = _stairwell(rng, grid, stair_cfg, stair, walls, carved)
    shaft_spec = _shaft(rng, fam, grid, shaft, walls, carved)
    blocks = _room_blocks(cells, carved)
    # Pillars along one side of wide corridors, clear of crossings, doors and the shaft.
    keep_clear = [shaft_spec.front, (sum(stairwell.doors_x[0]) / 2, s_cy)]
    pillars = _pillars(rng, grid, keep_clear)
    corridors = [Corridor("x", (a + b) / 2, _END_INSET_M, W - _END_INSET_M, b - a) for a, b in xc]
    corridors += [Corridor("y", (a + b) / 2, _END_INSET_M, D - _END_INSET_M, b - a) for a, b in yc]
    picks = _checkpoints(rng, grid, corridors, keep_clear)
    if picks is None:
        return None
    start = picks[0]
    spec = BuildingSpec(
        name=f"generated-{fam.storeys}{fam.n_floors[0]}{fam.n_floors[1]}-{seed}",
        footprint=(0.0, W, 0.0, D),
        storey_heights_m=storeys,
        blocks=tuple(blocks),
        shaft=shaft_spec,
        stairwell=stairwell,
        pillars=tuple(pillars),
        extra_walls=tuple(walls),
        corridors=tuple(corridors),
        checkpoints=tuple((f"C{k + 1}", x, y) for k, (x, y) in enumerate(picks)),
    )
    return shift(spec, -start[0], -start[1])


def _draw_grid(rng: np.random.Generator, fam: FamilySpec) -> _Grid | None:
    """The footprint, the storeys and the corridors; the blocks are the grid cells between the
    corridors and the outer walls. None when the corridors do not fit."""
    W = round(_u(rng, fam.width_m), 2)
    D = round(_u(rng, fam.depth_m), 2)
    n_floors = int(rng.integers(fam.n_floors[0], fam.n_floors[1] + 1))
    storeys = _storeys(rng, fam, n_floors)
    n_x = 1 if D < 22.0 else int(rng.integers(1, 3))
    n_y = int(rng.integers(1, max(2, min(3, int(W // 12)) + 1)))
    try:
        xc = _bands(rng, D, n_x, (2.0, 2.8), 4.6)  # corridors along x: their y spans
        yc = _bands(rng, W, n_y, (1.8, 2.6), 5.0)  # corridors along y: their x spans
    except ValueError:
        return None
    # Blocks: the grid cells between corridors and outer walls.
    xs = [0.0, *[v for s in yc for v in s], W]
    ys = [0.0, *[v for s in xc for v in s], D]
    cells = []
    for (x0, x1), (y0, y1) in itertools.product(zip(xs[::2], xs[1::2], strict=True), zip(ys[::2], ys[1::2], strict=True)):
        sides = "".join(s for s, edge in (("n", y1 < D), ("s", y0 > 0), ("w", x0 > 0), ("e", x1 < W)) if edge)
        cells.append((x0, x1, y0, y1, sides))
    return _Grid(W, D, storeys, xc, yc, cells)


def _place_stairwell(
    rng: np.random.Generator, cells: list[Cell], order: list[int], stair_len: float
) -> tuple[int, str, float, float] | None:
    """(cell, door side, x0, x1) of the stairwell's strip: in the first block of `order` deep
    and long enough, at its west or east end."""
    stair = None
    for i in order:
        x0, x1, y0, y1, sides = cells[i]
        opts = [s for s in "ns" if s in sides]
        if not opts or y1 - y0 < _STAIR_DEPTH_M + 0.3 or x1 - x0 < stair_len + 0.2:
            continue
        side = opts[int(rng.integers(len(opts)))]
        at_west = bool(rng.random() < 0.5)
        sx0 = x0 if at_west else x1 - stair_len
        stair = (i, side, sx0, sx0 + stair_len)
        break
    return stair


def _place_shaft(
    rng: np.random.Generator, cells: list[Cell], order: list[int], stair: tuple[int, str, float, float]
) -> tuple[int, str, float] | None:
    """(cell, door side, centre x) of the shaft: another strip, in another block or beside the
    stairwell in the same one."""
    shaft = None
    for i in order:
        x0, x1, y0, y1, sides = cells[i]
        opts = [s for s in "ns" if s in sides]
        if not opts or y1 - y0 < 2 * _SHAFT_HALF + 0.3:
            continue
        lo, hi = x0 + _SHAFT_HALF + 0.05, x1 - _SHAFT_HALF - 0.05
        if i == stair[0]:
            # Beside the stairwell, 0.5 m of wall between; on its own side of the corridor.
            opts = [stair[1]]
            if stair[2] - x0 > 2 * _SHAFT_HALF + 0.5:
                hi = stair[2] - 0.5 - _SHAFT_HALF
            elif x1 - stair[3] > 2 * _SHAFT_HALF + 0.5:
                lo = stair[3] + 0.5 + _SHAFT_HALF
            else:
                continue
        if hi < lo:
            continue
        side = opts[int(rng.integers(len(opts)))]
        shaft = (i, side, round(float(rng.uniform(lo, hi)), 3))
        break
    return shaft


def _corridor_beside(xc: list[tuple[float, float]], cell: Cell, side: str) -> tuple[float, float]:
    """(centre y, width) of the x corridor on a block's side."""
    y = cell[3] if side == "n" else cell[2]
    for a, b in xc:
        if abs((a if side == "n" else b) - y) < 1e-9:
            return (a + b) / 2, b - a
    raise AssertionError("no corridor beside the block")


def _stairwell(
    rng: np.random.Generator,
    grid: _Grid,
    stair_cfg: StairwellSpec,
    stair: tuple[int, str, float, float],
    walls: Walls,
    carved: dict[int, list[tuple[float, float]]],
) -> tuple[StairwellSpec, float]:
    """The stairwell in its strip and the y of the corridor its door opens on; the strip is
    carved out of its block and the void behind it walled."""
    W, D = grid.W, grid.D
    si, sside, sx0, sx1 = stair
    scell = grid.cells[si]
    s_cy, _ = _corridor_beside(grid.xc, scell, sside)
    door_y = scell[3] if sside == "n" else scell[2]
    out = 1.0 if sside == "n" else -1.0
    sy1, sy0 = (door_y, door_y - _STAIR_DEPTH_M) if sside == "n" else (door_y + _STAIR_DEPTH_M, door_y)
    near = (door_y - out * (0.1 + _LANE_M), door_y - out * 0.1)
    far_lane = (door_y - out * (_STAIR_DEPTH_M - 0.1), door_y - out * (_STAIR_DEPTH_M - 0.1 - _LANE_M))
    mid = door_y - out * _STAIR_DEPTH_M / 2
    reverse = bool(rng.random() < 0.5)
    fx0 = sx1 - _FLOOR_LANDING_M if reverse else sx0 + _FLOOR_LANDING_M
    door = (sx1 - 1.3, sx1 - 0.2) if reverse else (sx0 + 0.2, sx0 + 1.3)
    own = "".join(s for s, edge in (("n", sy1 < D), ("s", sy0 > 0), ("w", sx0 > 0), ("e", sx1 < W)) if edge)
    stairwell = replace(
        stair_cfg,
        rect=(sx0, sx1, sy0, sy1),
        flight_x0=fx0,
        lane_a=(min(near), max(near)),
        lane_b=(min(far_lane), max(far_lane)),
        divider=(mid - 0.06, mid + 0.06),
        door_side=sside,
        doors_x=(door,),
        walls=own,
        reverse=reverse,
        approach_m=abs(s_cy - door_y),
    )
    carved.setdefault(si, []).append((sx0, sx1))
    _strip_walls(walls, scell, sx0, sx1, sy0, sy1, D)
    return stairwell, s_cy


def _shaft(
    rng: np.random.Generator,
    fam: FamilySpec,
    grid: _Grid,
    shaft: tuple[int, str, float],
    walls: Walls,
    carved: dict[int, list[tuple[float, float]]],
) -> ShaftSpec:
    """The elevator in its strip, the robot waiting for it on the corridor's centre line; the
    strip is carved out of its block and the void behind it walled."""
    hi_, hside, hcx = shaft
    hcell = grid.cells[hi_]
    h_cy, _ = _corridor_beside(grid.xc, hcell, hside)
    hy = hcell[3] - _SHAFT_HALF if hside == "n" else hcell[2] + _SHAFT_HALF
    shaft_spec = ShaftSpec(
        center=(hcx, hy),
        front=(hcx, h_cy),
        door=hside,
        speed_m_s=round(_u(rng, fam.elevator_speed_m_s), 2),
        acc_m_s2=round(_u(rng, fam.elevator_acc_m_s2), 2),
    )
    carved.setdefault(hi_, []).append((hcx - _SHAFT_HALF, hcx + _SHAFT_HALF))
    _strip_walls(walls, hcell, hcx - _SHAFT_HALF, hcx + _SHAFT_HALF, hy - _SHAFT_HALF, hy + _SHAFT_HALF, grid.D)
    return shaft_spec


def _room_blocks(cells: list[Cell], carved: dict[int, list[tuple[float, float]]]) -> list[Block]:
    """Blocks of rooms: each cell, less its carved strips."""
    blocks: list[Block] = []
    for i, (x0, x1, y0, y1, sides) in enumerate(cells):
        cuts = sorted(carved.get(i, []))
        edges = [x0, *[v for c in cuts for v in c], x1]
        for k, (a, b) in enumerate(zip(edges[::2], edges[1::2], strict=True)):
            if b - a < 0.6:
                continue
            # A side facing a strip is no corridor side (it is the strip's wall).
            keep = "".join(
                s for s in sides if not (s == "w" and k > 0) and not (s == "e" and k < len(cuts))
            )
            blocks.append(Block(f"B{i}.{k}", a, b, y0, y1, keep))
    return blocks


def _pillars(rng: np.random.Generator, grid: _Grid, keep_clear: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Pillars along one side of each wide x corridor, clear of crossings, doors and the shaft."""
    W, xc, yc = grid.W, grid.xc, grid.yc
    pillars: list[tuple[float, float]] = []
    for a, b in xc:
        if b - a < 2.4:
            continue
        py = a + 0.4 if rng.random() < 0.5 else b - 0.4
        for px in np.arange(3.0, W - 2.0, _u(rng, (5.0, 8.0))):
            if any(abs(px - (c0 + c1) / 2) < 2.8 for c0, c1 in yc) or any(abs(px - q[0]) < 2.5 for q in keep_clear):
                continue
            pillars.append((round(float(px), 3), round(py, 3)))
    return pillars


def _checkpoints(
    rng: np.random.Generator, grid: _Grid, corridors: list[Corridor], keep_clear: list[tuple[float, float]]
) -> list[tuple[float, float]] | None:
    """The start on an x corridor's crossing with a y corridor (facing +x, with the corridor
    ahead), then three more crossings or corridor ends, at least 6 m apart; None if they do not fit."""
    W, D, xc, yc = grid.W, grid.D, grid.xc, grid.yc
    crossings = [((a + b) / 2, (c + d) / 2) for (c, d), (a, b) in itertools.product(xc, yc)]
    ends = [(_END_INSET_M, c.c) for c in corridors if c.axis == "x"] + [(W - _END_INSET_M, c.c) for c in corridors if c.axis == "x"]
    ends += [(c.c, _END_INSET_M) for c in corridors if c.axis == "y"] + [(c.c, D - _END_INSET_M) for c in corridors if c.axis == "y"]
    starts = [p for p in crossings if p[0] < W - 8.0]
    if not starts:
        return None
    start = starts[int(rng.integers(len(starts)))]
    picks = [start]
    pool = [p for p in crossings + ends if p != start]
    rng.shuffle(pool)
    for p in pool:
        if len(picks) == 4:
            break
        if all(math.dist(p, q) >= 6.0 for q in picks) and all(math.dist(p, q) >= 2.5 for q in keep_clear):
            picks.append(p)
    if len(picks) < 4:
        return None
    return picks


def _strip_walls(
    walls: list[tuple[str, float, float, float]],
    cell: tuple[float, float, float, float, str],
    x0: float,
    x1: float,
    y0: float,
    y1: float,
    depth: float,
) -> None:
    """Close the part of a block's strip behind the shaft or stairwell (a void) with walls."""
    cy0, cy1 = cell[2], cell[3]
    back = (y0, cy0) if y1 >= cy1 - 1e-9 else (y1, cy1)  # the void between the room and the far side
    if abs(back[1] - back[0]) < 0.05:
        return
    lo, hi = sorted(back)
    walls.append(("y", lo, hi, x0))
    walls.append(("y", lo, hi, x1))
    far = hi if back[1] > back[0] else lo
    if 0.0 < far < depth:
        walls.append(("x", x0, x1, far))


def shift(spec: BuildingSpec, dx: float, dy: float) -> BuildingSpec:
    """The same building with every plan coordinate moved by (dx, dy)."""

    def p(xy: tuple[float, float]) -> tuple[float, float]:
        return (xy[0] + dx, xy[1] + dy)

    def r(rect: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
        return (rect[0] + dx, rect[1] + dx, rect[2] + dy, rect[3] + dy)

    st = spec.stairwell
    stair = replace(
        st,
        rect=r(st.rect),
        flight_x0=st.flight_x0 + dx,
        lane_a=(st.lane_a[0] + dy, st.lane_a[1] + dy),
        lane_b=(st.lane_b[0] + dy, st.lane_b[1] + dy),
        divider=(st.divider[0] + dy, st.divider[1] + dy),
        doors_x=tuple((a + dx, b + dx) for a, b in st.doors_x),
    )
    walls = tuple(
        (axis, a0 + (dx if axis == "x" else dy), a1 + (dx if axis == "x" else dy), c + (dy if axis == "x" else dx))
        for axis, a0, a1, c in spec.extra_walls
    )
    corridors = tuple(
        Corridor(c.axis, c.c + (dy if c.axis == "x" else dx), c.a0 + (dx if c.axis == "x" else dy), c.a1 + (dx if c.axis == "x" else dy), c.width_m)
        for c in spec.corridors
    )
    return replace(
        spec,
        footprint=r(spec.footprint),
        blocks=tuple(Block(b.name, b.x0 + dx, b.x1 + dx, b.y0 + dy, b.y1 + dy, b.sides, b.limits) for b in spec.blocks),
        shaft=replace(spec.shaft, center=p(spec.shaft.center), front=p(spec.shaft.front)),
        stairwell=stair,
        pillars=tuple(p(q) for q in spec.pillars),
        extra_walls=walls,
        corridors=corridors,
        checkpoints=tuple((name, x + dx, y + dy) for name, x, y in spec.checkpoints),
    )


# -- routes ---------------------------------------------------------------------------------
def _on(c: Corridor, xy: tuple[float, float], tol: float = 1e-6) -> float | None:
    """Position along the corridor if xy is on its centre line."""
    along, across = (xy[0], xy[1]) if c.axis == "x" else (xy[1], xy[0])
    if abs(across - c.c) <= tol and c.a0 - tol <= along <= c.a1 + tol:
        return along
    return None


def plan_path(corridors: tuple[Corridor, ...], start: tuple[float, float], goal: tuple[float, float]) -> list[tuple[float, float]]:
    """The shortest way from start to goal along the corridors' centre lines (both on one):
    the corners and the goal, not the start."""
    nodes: list[tuple[float, float]] = [start, goal]
    for a, b in itertools.combinations(corridors, 2):
        if a.axis == b.axis:
            continue
        cx, cy = (b.c, a.c) if a.axis == "x" else (a.c, b.c)
        if _on(a, (cx, cy)) is not None and _on(b, (cx, cy)) is not None:
            nodes.append((cx, cy))
    for c in corridors:
        nodes += [(c.a0, c.c), (c.a1, c.c)] if c.axis == "x" else [(c.c, c.a0), (c.c, c.a1)]
    uniq: list[tuple[float, float]] = []
    for n in nodes:
        if all(math.dist(n, q) > 1e-6 for q in uniq):
            uniq.append(n)
    index = {n: i for i, n in enumerate(uniq)}
    adj: dict[int, list[tuple[int, float]]] = {i: [] for i in range(len(uniq))}
    for c in corridors:
        on = sorted((pos, index[n]) for n in uniq if (pos := _on(c, n)) is not None)
        for (p0, i0), (p1, i1) in itertools.pairwise(on):
            adj[i0].append((i1, p1 - p0))
            adj[i1].append((i0, p1 - p0))
    s, g = index[uniq[0]], next(i for n, i in index.items() if math.dist(n, goal) <= 1e-6)
    if not adj[s] and s != g:
        raise ValueError(f"{start} is on no corridor")
    dist = {s: 0.0}
    prev: dict[int, int] = {}
    heap = [(0.0, s)]
    while heap:
        d, i = heapq.heappop(heap)
        if i == g:
            break
        if d > dist.get(i, math.inf):
            continue
        for j, w in adj[i]:
            if d + w < dist.get(j, math.inf) - 1e-12:
                dist[j] = d + w
                prev[j] = i
                heapq.heappush(heap, (d + w, j))
    if g not in dist:
        raise ValueError(f"no way along the corridors from {start} to {goal}")
    path = [g]
    while path[-1] != s:
        path.append(prev[path[-1]])
    pts = [uniq[i] for i in reversed(path)]
    # Keep the corners only: a straight run is one drive.
    out = [pts[0]]
    for q0, q1, q2 in zip(pts, pts[1:], pts[2:], strict=False):
        if abs((q1[0] - q0[0]) * (q2[1] - q1[1]) - (q1[1] - q0[1]) * (q2[0] - q1[0])) > 1e-9:
            out.append(q1)
    if len(pts) > 1:
        out.append(pts[-1])
    return out[1:]
