"""The building exports for what their formats cannot hold: a floor with no grid, an elevator
whose cabin was never seen or never seen open. Written without that element, with a warning."""

from __future__ import annotations

import io
import math
from typing import Any

import numpy as np
import pytest
import yaml

from mfmap.export.cabin import Cabin, CabinDoor
from mfmap.export.foxglove import FloorMap, mcap_bytes
from mfmap.export.grid import OccupancyGrid
from mfmap.export.nav2 import floors_index
from mfmap.export.rmf import building_yaml
from tests.export.rmf_schema import check_building

T0 = 1_700_000_000_000_000_000


def _doc() -> dict[str, Any]:
    return {
        "floors": [{"id": 0, "elevation_m": 0.0, "pressure_pa": 1e5, "visits": [], "connectors": [0, 1]},
                   {"id": 1, "elevation_m": 3.9, "pressure_pa": 1e5, "visits": [], "connectors": [0, 1]}],
        "transitions": [
            {"kind": "elevator", "from": 0, "to": 1, "t_start": T0 / 1e9 + 10, "t_end": T0 / 1e9 + 20,
             "connector": 0},
            {"kind": "stairs", "from": 1, "to": 0, "t_start": T0 / 1e9 + 40, "t_end": T0 / 1e9 + 60,
             "connector": 1}],
        "connectors": [{"id": 0, "kind": "elevator", "x": 1.0, "y": 2.0, "floors": [0, 1]},
                       {"id": 1, "kind": "stairs", "x": 9.0, "y": -3.0, "floors": [0, 1]}],
    }


def _trajectory() -> tuple[np.ndarray, np.ndarray]:
    stamps = T0 + np.arange(0, 80) * 1_000_000_000
    poses = np.tile(np.eye(4), (len(stamps), 1, 1))
    poses[:, 0, 3] = np.where(stamps < T0 + 30e9, 1.0, 9.0)
    poses[:, 1, 3] = np.where(stamps < T0 + 30e9, 2.0, -3.0)
    poses[:, 2, 3] = np.where((stamps > T0 + 15e9) & (stamps < T0 + 50e9), 3.9, 0.0)
    return stamps, poses


def _cabin(doors: dict[int, CabinDoor]) -> Cabin:
    return Cabin(x_m=1.02, y_m=2.01, yaw_rad=0.0, inner_width_m=1.8, inner_depth_m=1.6, floors=(0, 1),
                 doors=doors, rides=1, scans=25)


def _grid() -> OccupancyGrid:
    occ = np.zeros((40, 60), bool)
    occ[0] = True
    return OccupancyGrid(occ, ~occ, np.array([-1.0, -1.0]), 0.05)


def test_floor_without_a_grid_is_listed_without_a_map() -> None:
    stamps, poses = _trajectory()
    index, warnings = floors_index(_doc(), {0: "0/grid.yaml"}, stamps, poses)
    assert "map" not in index["floors"][1] and index["floors"][0]["map"] == "0/grid.yaml"
    assert len(warnings) == 1 and "floor 1 has no grid" in warnings[0]
    # The connectors' poses are still there for the floor: the stairs left it, the lift reached it.
    conns = {c["kind"]: c for c in index["floors"][1]["connectors"]}
    assert "arrive" in conns["elevator"] and "depart" not in conns["elevator"]
    assert math.hypot(conns["stairs"]["depart"]["x"] - 9.0, conns["stairs"]["depart"]["y"] + 3.0) < 1e-6
    building, more = building_yaml("b", _doc(), {0: {"image": "floors/0/grid.pgm", "resolution": 0.05,
                                                     "origin": [-1.0, -1.0], "height": 40}},
                                   [_cabin({0: CabinDoor("back", 0.0, 0.9, 0.2), 1: CabinDoor("back", 0.0, 0.9, 0.2)})],
                                   index)
    check_building(building)
    assert "layers" not in building["levels"]["L1"] and "layers" in building["levels"]["L0"]
    assert any("floor 1 has no grid" in w for w in more)
    # The layer puts the image's top row at the grid's top edge.
    assert building["levels"]["L0"]["layers"]["grid"]["transform"]["translation_y"] == pytest.approx(1.0)


def test_an_elevator_never_measured_has_no_lift() -> None:
    stamps, poses = _trajectory()
    index, _ = floors_index(_doc(), {0: "0/grid.yaml", 1: "1/grid.yaml"}, stamps, poses)
    building, warnings = building_yaml("b", _doc(), {}, [], index)
    check_building(building)
    assert building["lifts"] == {}
    assert any("elevator connector 0 has no measured cabin" in w for w in warnings)
    # A cabin whose doors were never seen open serves no floor: no lift either.
    building, warnings = building_yaml("b", _doc(), {}, [_cabin({})], index)
    check_building(building)
    assert building["lifts"] == {}
    assert any("never seen with its doors open" in w for w in warnings)


def test_lift_serves_the_floors_where_its_door_opened() -> None:
    stamps, poses = _trajectory()
    index, _ = floors_index(_doc(), {0: "0/grid.yaml", 1: "1/grid.yaml"}, stamps, poses)
    cabin = _cabin({0: CabinDoor("back", 0.05, 0.9, 0.2), 1: CabinDoor("right", 0.0, 1.0, 0.2)})
    building, warnings = building_yaml("b", _doc(), {}, [cabin], index)
    sides = check_building(building)
    lift = building["lifts"]["lift_0"]
    assert warnings == [] or all("no grid" in w for w in warnings)
    assert lift["level_doors"] == {"L0": ["door_back"], "L1": ["door_right"]}
    assert sides["lift_0"] == {"door_back": "back", "door_right": "right"}
    assert lift["width"] == pytest.approx(1.9) and lift["depth"] == pytest.approx(1.7)
    # Stairs, which Open-RMF cannot hold as such, are named vertices on both floors.
    names = {v[3] for lvl in building["levels"].values() for v in lvl["vertices"]}
    assert {"stairs_1_depart_L1", "stairs_1_arrive_L0"} <= names
    yaml.safe_load(yaml.safe_dump(building))  # plain YAML types only


def test_mcap_without_a_floor_grid_still_reads_back() -> None:
    from mcap.reader import make_reader

    stamps, poses = _trajectory()
    floors = [FloorMap(0, 0.0, np.random.default_rng(0).normal(size=(500, 3)).astype(np.float32), _grid()),
              FloorMap(1, 3.9, np.zeros((0, 3), np.float32), None)]
    data = mcap_bytes(floors, _doc(), [], stamps, poses)
    assert data == mcap_bytes(floors, _doc(), [], stamps, poses)  # same input, same bytes
    reader = make_reader(io.BytesIO(data))
    summary = reader.get_summary()
    assert summary is not None
    topics = {ch.topic for ch in summary.channels.values()}
    assert "/floor_0/grid" in topics and "/floor_1/grid" not in topics and "/floor_1/cloud" in topics
    counts = summary.statistics.channel_message_counts if summary.statistics else {}
    by_topic = {summary.channels[k].topic: v for k, v in counts.items()}
    assert by_topic["/robot/pose"] == len(stamps) and by_topic["/floor_0/cloud"] == 1
