"""Routes through buildings unlike the one the estimator was tuned on: switch-back stairs with
half landings and pauses, floors passed through on the stairs, elevator stops at floors nobody
visits, storeys of different heights. Trajectories only (no sensors): fast."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mfmap.sim.building import Building
from mfmap.sim.groundtruth import floors_document
from mfmap.sim.run import build_trajectory, make_barometer
from mfmap.sim.scenarios import SCENARIOS, building_for
from mfmap.sim.trajectory import DT_S, Trajectory


def _route(name: str, seed: int = 0) -> tuple[Building, Trajectory]:
    spec = SCENARIOS[name]
    building = building_for(spec, seed)
    return building, build_trajectory(spec, building, seed, 1)


def _held(z: np.ndarray, level: float, tol: float = 0.02) -> list[tuple[int, int]]:
    """Runs of ticks [i0, i1) where z stays within tol of level."""
    near = np.abs(z - level) < tol
    edges = np.flatnonzero(np.diff(np.concatenate([[0], near.astype(np.int8), [0]])))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def test_unequal_storeys() -> None:
    building, traj = _route("office-switchback")
    assert [building.elevation(k) for k in range(3)] == [0.0, 5.5, 9.0]
    assert building.storey_height(0) == 5.5 and not building.uniform
    # The switch-back flights of the lobby are longer than the offices' (same riser, more steps).
    assert building.flights[0].run_m > building.flights[1].run_m
    assert 0.16 < building.flights[0].rise_m < 0.19 and 0.16 < building.flights[1].rise_m < 0.19
    spec = SCENARIOS["office-switchback"]
    doc = floors_document(spec, building, traj, make_barometer(spec, building, traj, 0), 0, 0)
    assert {f["id"]: f["elevation_m"] for f in doc["floors"]} == {0: 0.0, 1: 5.5, 2: 9.0}
    assert doc["sim"]["floor_height_m"] is None and doc["sim"]["storey_heights_m"] == [5.5, 3.5, 3.5]
    for f in doc["floors"]:
        for v0, v1 in f["visits"]:
            i0, i1 = round(v0 / DT_S), round(v1 / DT_S)
            assert np.abs(traj.xyz[i0:i1, 2] - f["elevation_m"]).max() < 1e-6  # on its floor


def test_switchback_walk_with_landings_pauses_and_a_floor_passed_through() -> None:
    _, traj = _route("office-switchback")
    kinds = [(t.kind, t.from_floor, t.to_floor) for t in traj.transitions]
    assert kinds == [("stairs", 0, 2), ("elevator", 2, 0), ("elevator", 0, 1), ("stairs", 1, 0)]
    walk = traj.transitions[0]
    i0, i1 = round(walk.t_start_s / DT_S), round(walk.t_end_s / DT_S)
    z = traj.xyz[i0:i1 + 1, 2]
    assert z[0] == pytest.approx(0.0, abs=1e-9) and z[-1] == pytest.approx(9.0, abs=1e-9)
    assert walk.height_change_m == pytest.approx(9.0)
    # Two half landings (2.75 m and 7.25 m), each with a stand of 5-30 s besides the turn.
    pose = np.column_stack([traj.xyz[i0:i1 + 1], traj.rpy[i0:i1 + 1, 2]])
    for level in (2.75, 5.5 + 1.75):
        runs = [(a, b) for a, b in _held(z, level) if (b - a) * DT_S > 4.0]
        assert len(runs) == 1
        a, b = runs[0]
        moving = np.abs(np.diff(pose[a:b], axis=0)).max(axis=1) > 0
        stands = [(q - p) * DT_S for p, q in _held(moving.astype(float), 0.0, 0.5)]
        assert 5.0 - 1e-6 <= max(stands) <= 30.0 + 1e-6
    # Floor 1 is passed through: its height is held for a few seconds (across the landing)
    # but it is no visit, and the walk is one transition.
    runs = [(a, b) for a, b in _held(z, 5.5) if (b - a) * DT_S > 1.0]
    assert len(runs) == 1 and 2.0 < (runs[0][1] - runs[0][0]) * DT_S < 20.0
    assert not any(f == 1 and t0 < walk.t_end_s for f, t0, _ in traj.floor_visits)
    # Somewhere mid-flight the carrier stops (neither a floor nor a landing height).
    levels = [0.0, 2.75, 5.5, 7.25, 9.0]
    still = np.flatnonzero(np.abs(np.diff(traj.xyz[i0:i1 + 1, 0])) < 1e-9)
    mid = still[np.min(np.abs(z[still, None] - np.array(levels)[None]), axis=1) > 0.2]
    assert len(mid) * DT_S > 3.0
    # Climbing, not flying: the pitch follows the flights both ways.
    pitch = np.degrees(traj.rpy[i0:i1, 1])
    assert pitch.min() < -15 and np.abs(pitch).max() < 30
    down = traj.transitions[3]
    j0, j1 = round(down.t_start_s / DT_S), round(down.t_end_s / DT_S)
    assert np.degrees(traj.rpy[j0:j1, 1]).max() > 15
    assert traj.xyz[j1, 2] == pytest.approx(0.0, abs=1e-9)


def test_the_carrier_is_on_the_steps_with_headroom() -> None:
    import open3d as o3d

    building, traj = _route("office-switchback")
    scene = building.scene(None)
    for tr in (traj.transitions[0], traj.transitions[3]):
        i0, i1 = round(tr.t_start_s / DT_S), round(tr.t_end_s / DT_S)
        pts = traj.xyz[i0:i1:40]
        base = pts + np.array([0.0, 0.0, 0.6])
        down = np.column_stack([base, np.tile([0, 0, -1.0], (len(pts), 1))]).astype(np.float32)
        up = np.column_stack([base, np.tile([0, 0, 1.0], (len(pts), 1))]).astype(np.float32)
        gap = scene.cast_rays(o3d.core.Tensor(down))["t_hit"].numpy() - 0.6
        head = scene.cast_rays(o3d.core.Tensor(up))["t_hit"].numpy()
        rise = max(g.rise_m for g in building.flights)
        assert np.all(np.abs(gap) < rise + 0.03)  # a step, a landing or a floor under it
        assert head.min() > 1.2  # the flights above leave room for the carrier and the lidar


def test_elevator_stops_at_floors_nobody_visits() -> None:
    building, traj = _route("office-switchback")
    ride = traj.transitions[1]  # 2 -> 0, stopping at 1
    i0, i1 = round(ride.t_start_s / DT_S), round(ride.t_end_s / DT_S)
    cx, cy = building.shaft_center
    assert np.abs(traj.xyz[i0:i1, :2] - np.array([cx, cy])).max() < 1e-9  # in the cabin throughout
    stops = [(t0, t1, f) for t0, t1, f in traj.door_open if ride.t_start_s < t0 < ride.t_end_s]
    assert [f for _, _, f in stops] == [1]
    t0, t1, _ = stops[0]
    assert t1 - t0 == pytest.approx(5.0)
    # The doors open only while the cabin stands at floor 1.
    k0, k1 = round(t0 / DT_S), round(t1 / DT_S)
    assert np.abs(traj.xyz[k0 - 200 : k1 + 200, 2] - 5.5).max() < 1e-9
    assert traj.cabin_z_at(np.array([(t0 + t1) / 2]))[0] == pytest.approx(5.5)
    assert ride.height_change_m == pytest.approx(-9.0)
    # Floor 1's only visit comes later, by the elevator from the lobby.
    assert [f for f, _, _ in traj.floor_visits] == [0, 2, 0, 1, 0]


def test_ground_truth_numbers_the_visited_floors(tmp_path: Path) -> None:
    """gen-mixed at seed 1 visits the building's floors 0 and 2 and only passes floor 1 (in the
    cabin and on the stairs): the ground truth has two floors, 0 and 1, as a build would."""
    from mfmap.sim.groundtruth import write_points

    spec = SCENARIOS["gen-mixed"]
    building, traj = _route("gen-mixed", 1)
    assert building.n_floors == 3 and {f for f, _, _ in traj.floor_visits} == {0, 2}
    doc = floors_document(spec, building, traj, make_barometer(spec, building, traj, 1), 0, 1)
    assert [(f["id"], f["building_floor"]) for f in doc["floors"]] == [(0, 0), (1, 2)]
    assert doc["floors"][1]["elevation_m"] == pytest.approx(building.elevation(2))
    assert [(t["kind"], t["from"], t["to"]) for t in doc["transitions"]] == [("elevator", 0, 1), ("stairs", 1, 0)]
    assert doc["transitions"][1]["height_change_m"] == pytest.approx(-building.elevation(2))
    rows = write_points(tmp_path / "p.csv", traj, 0).read_text().splitlines()[1:]
    assert {r.split(",")[1] for r in rows} == {"0", "1"}
