"""mfmap.sim.layout: a different building per seed, laid out so routes can use it, and the
shortest way along its corridors."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from mfmap.sim.building import Building
from mfmap.sim.layout import FamilySpec, generate_building, plan_path
from mfmap.sim.run import build_trajectory
from mfmap.sim.scenarios import SCENARIOS, building_for
from mfmap.sim.spec import BuildingSpec, Corridor
from mfmap.sim.trajectory import DT_S


def _on_a_corridor(spec: BuildingSpec, xy: tuple[float, float]) -> bool:
    for c in spec.corridors:
        along, across = (xy[0], xy[1]) if c.axis == "x" else (xy[1], xy[0])
        if abs(across - c.c) < 1e-6 and c.a0 - 1e-6 <= along <= c.a1 + 1e-6:
            return True
    return False


def _overlap(a: tuple[float, float, float, float], b: tuple[float, float, float, float]) -> bool:
    """Overlapping by more than a rounding error (touching is fine)."""
    e = 1e-6
    return a[0] < b[1] - e and b[0] < a[1] - e and a[2] < b[3] - e and b[2] < a[3] - e


@pytest.mark.parametrize("storeys", ["mixed", "lobby", "equal"])
def test_a_different_building_per_seed(storeys: str) -> None:
    specs = [generate_building(seed, FamilySpec(storeys=storeys)) for seed in range(40)]
    sizes = np.array([(s.footprint[1] - s.footprint[0], s.footprint[3] - s.footprint[2]) for s in specs])
    assert sizes[:, 0].min() >= 24.0 and sizes[:, 0].max() <= 38.0 and np.std(sizes[:, 0]) > 2.5
    assert sizes[:, 1].min() >= 18.0 and sizes[:, 1].max() <= 26.0 and np.std(sizes[:, 1]) > 1.5
    assert {s.n_floors for s in specs} == {3, 4, 5}
    assert len({(len([c for c in s.corridors if c.axis == "x"]), len(s.corridors)) for s in specs}) >= 3
    assert len({s.shaft.door for s in specs}) == 2 and len({s.stairwell.reverse for s in specs}) == 2
    # The shaft and the stairwell are somewhere else in each building (relative to its corner).
    where = {(round(s.shaft.center[0] - s.footprint[0]), round(s.stairwell.rect[0] - s.footprint[0])) for s in specs}
    assert len(where) > 30
    heights = np.array([h for s in specs for h in s.storey_heights_m])
    assert heights.min() >= 2.6 and heights.max() <= 6.0
    if storeys == "mixed":
        assert heights.min() < 2.8 and heights.max() > 5.7
        assert any(len(set(s.storey_heights_m)) > 1 for s in specs)
    if storeys == "lobby":
        assert all(s.storey_heights_m[0] >= 4.5 > max(s.storey_heights_m[1:]) for s in specs)
    if storeys == "equal":
        assert all(len(set(s.storey_heights_m)) == 1 for s in specs)
    assert generate_building(7, FamilySpec(storeys=storeys)) == specs[7]  # deterministic


@pytest.mark.parametrize("seed", range(25))
def test_layout_holds_together(seed: int) -> None:
    spec = generate_building(seed)
    fx0, fx1, fy0, fy1 = spec.footprint
    building = Building(spec, 0, seed)
    shaft = building.shaft_rect
    stair = spec.stairwell.rect
    for rect in (shaft, stair):
        assert fx0 - 1e-9 <= rect[0] and rect[1] <= fx1 + 1e-9 and fy0 - 1e-9 <= rect[2] and rect[3] <= fy1 + 1e-9
    assert not _overlap(shaft, stair)
    for c in spec.corridors:  # no corridor runs through the shaft or the stairwell
        half = c.width_m / 2
        band = (c.a0, c.a1, c.c - half, c.c + half) if c.axis == "x" else (c.c - half, c.c + half, c.a0, c.a1)
        assert not _overlap(band, shaft) and not _overlap(band, stair)
    # The longest flight and its half landing fit in the stairwell.
    run = max(g.run_m for g in building.flights)
    x_far = spec.stairwell.flight_x0 + (-run if spec.stairwell.reverse else run)
    assert stair[0] + 1.2 <= x_far <= stair[1] - 1.2
    # The robot starts at the origin on an x corridor; every point a route needs is on a
    # corridor and reachable from every other.
    assert spec.checkpoints[0][1:] == (0.0, 0.0)
    st = spec.stairwell
    points = [(x, y) for _, x, y in spec.checkpoints]
    points += [spec.shaft.front, (sum(st.doors_x[0]) / 2, st.door_wall_y + st.outward * st.approach_m)]
    assert all(_on_a_corridor(spec, p) for p in points)
    for a, b in itertools.permutations(points, 2):
        path = [a, *plan_path(spec.corridors, a, b)]
        assert math.dist(path[-1], b) < 1e-9
        for p, q in itertools.pairwise(path):  # along the corridors: axis-aligned legs
            assert min(abs(p[0] - q[0]), abs(p[1] - q[1])) < 1e-9
    # Every block of rooms lies inside the footprint and clear of the shaft and stairwell.
    for blk in spec.blocks:
        r = (blk.x0, blk.x1, blk.y0, blk.y1)
        assert not _overlap(r, shaft) and not _overlap(r, stair)


def test_plan_path_takes_the_shortest_way() -> None:
    # A square ring of corridors with one cross corridor through the middle.
    corridors = (
        Corridor("x", 0.0, 0.0, 20.0, 2.0),
        Corridor("x", 10.0, 0.0, 20.0, 2.0),
        Corridor("y", 0.0, 0.0, 10.0, 2.0),
        Corridor("y", 20.0, 0.0, 10.0, 2.0),
        Corridor("y", 12.0, 0.0, 10.0, 2.0),
    )
    assert plan_path(corridors, (3.0, 0.0), (3.0, 10.0)) == [(0.0, 0.0), (0.0, 10.0), (3.0, 10.0)]
    assert plan_path(corridors, (11.0, 0.0), (13.0, 10.0)) == [(12.0, 0.0), (12.0, 10.0), (13.0, 10.0)]
    assert plan_path(corridors, (5.0, 0.0), (9.0, 0.0)) == [(9.0, 0.0)]
    with pytest.raises(ValueError, match="no way"):
        plan_path((*corridors, Corridor("x", 30.0, 0.0, 5.0, 2.0)), (3.0, 0.0), (3.0, 30.0))


@pytest.mark.parametrize(("name", "seed"), [("gen-stairs", 1), ("gen-stairs", 11), ("gen-mixed", 4)])
def test_generated_stairs_carry_the_robot_on_their_steps(name: str, seed: int) -> None:
    import open3d as o3d

    spec = SCENARIOS[name]
    building = building_for(spec, seed)
    traj = build_trajectory(spec, building, seed, 1)
    scene = building.scene(None)
    walks = [t for t in traj.transitions if t.kind == "stairs"]
    assert walks and any(abs(t.to_floor - t.from_floor) >= 2 for t in walks)
    rise = max(g.rise_m for g in building.flights)
    for tr in walks:
        i0, i1 = round(tr.t_start_s / DT_S), round(tr.t_end_s / DT_S)
        assert traj.xyz[i1, 2] - traj.xyz[i0, 2] == pytest.approx(tr.height_change_m, abs=1e-9)
        base = traj.xyz[i0:i1:40] + np.array([0.0, 0.0, 0.6])
        n = len(base)
        down = np.column_stack([base, np.tile([0, 0, -1.0], (n, 1))]).astype(np.float32)
        up = np.column_stack([base, np.tile([0, 0, 1.0], (n, 1))]).astype(np.float32)
        gap = scene.cast_rays(o3d.core.Tensor(down))["t_hit"].numpy() - 0.6
        head = scene.cast_rays(o3d.core.Tensor(up))["t_hit"].numpy()
        assert np.all(np.abs(gap) < rise + 0.03)
        assert head.min() > 1.0
