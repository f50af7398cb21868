"""map.mcap, building.yaml and floors/index.yaml of real builds of multi-floor logs, against the
simulator's truth (its ground-truth files, and its cabin's size)."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from mfmap.export.files import read_ply
from tests.export.rmf_schema import check_building

pytestmark = pytest.mark.slow
SCENARIOS = ["two-floor", "three-floor-revisit"]
SCHEMAS = {"foxglove.PointCloud", "foxglove.Grid", "foxglove.PosesInFrame", "foxglove.PoseInFrame",
           "foxglove.SceneUpdate", "foxglove.FrameTransforms"}
SIDE_NORMAL = {"right": (1.0, 0.0), "left": (-1.0, 0.0), "front": (0.0, 1.0), "back": (0.0, -1.0)}


def _truth(sim: Path) -> dict[str, Any]:
    """The simulated elevator: its centre from gt_floors.json, its cabin's outer size and door
    direction from the simulator's building (the ground-truth files do not carry them)."""
    from mfmap.sim import spec

    gt = json.loads((sim / "gt_floors.json").read_text())
    elevator = next(c for c in gt["connectors"] if c["kind"] == "elevator")
    return {"gt": gt, "centre": (elevator["x"], elevator["y"]), "floors": elevator["floors"],
            "size": 2 * spec.CABIN_HALF, "door_normal": (0.0, -1.0)}  # "The door faces -y"


@pytest.fixture(scope="module", params=SCENARIOS)
def built(request: pytest.FixtureRequest, sim_build: Callable[[str], tuple[Path, Path]]) -> tuple[str, Path, Path]:
    sim, out = sim_build(request.param)
    return request.param, sim, out


def _messages(path: Path) -> tuple[dict[str, str], dict[str, list[Any]]]:
    """Topic -> schema name, and topic -> decoded messages, by the plain mcap reader."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None
        schema_of = {ch.topic: summary.schemas[ch.schema_id].name for ch in summary.channels.values()}
        msgs: dict[str, list[Any]] = {}
        for _, channel, _, decoded in reader.iter_decoded_messages():
            msgs.setdefault(channel.topic, []).append(decoded)
    return schema_of, msgs


def test_map_mcap_holds_the_building_in_foxglove_schemas(built: tuple[str, Path, Path]) -> None:
    _, _, out = built
    floors = json.loads((out / "floors.json").read_text())["floors"]
    schema_of, msgs = _messages(out / "map.mcap")
    assert set(schema_of.values()) == SCHEMAS
    traj = np.loadtxt(out / "trajectory.tum")
    assert len(msgs["/robot/pose"]) == len(msgs["/robot/transforms"]) == traj.shape[0]
    assert len(msgs["/trajectory"]) == 1 and len(msgs["/trajectory"][0].poses) == traj.shape[0]
    frames = {tf.child_frame_id: tf.translation.z for tf in msgs["/floors/transforms"][0].transforms}
    for floor in floors:
        fid = floor["id"]
        assert schema_of[f"/floor_{fid}/cloud"] == "foxglove.PointCloud"
        cloud = msgs[f"/floor_{fid}/cloud"][0]
        ply = read_ply(out / "floors" / str(fid) / "cloud.ply")
        assert len(cloud.data) // cloud.point_stride == ply["x"].shape[0]
        # The cloud's points are the floor's, at its elevation.
        xyz = np.frombuffer(cloud.data, dtype=[("xyz", "<f4", 3), ("rgba", "u1", 4)])["xyz"]
        assert abs(float(np.median(xyz[:, 2])) - floor["elevation_m"]) < 1.5
        grid = msgs[f"/floor_{fid}/grid"][0]
        meta = yaml.safe_load((out / "floors" / str(fid) / "grid.yaml").read_text())
        assert grid.frame_id == f"floor_{fid}"
        assert math.isclose(grid.cell_size.x, meta["resolution"])
        assert math.isclose(grid.pose.position.x, meta["origin"][0], abs_tol=1e-6)
        assert math.isclose(frames[f"floor_{fid}"], floor["elevation_m"], abs_tol=1e-6)
    scene = msgs["/building/connectors"][0]
    assert {e.id for e in scene.entities} >= {"elevator_0"}
    layout = json.loads((out / "foxglove_layout.json").read_text())
    topics = layout["configById"][layout["layout"]]["topics"]
    assert {f"/floor_{f['id']}/cloud" for f in floors} <= set(topics)


def test_building_yaml_has_the_levels_and_the_measured_lift(built: tuple[str, Path, Path]) -> None:
    scenario, sim, out = built
    truth = _truth(sim)
    doc = yaml.safe_load((out / "building.yaml").read_text())
    sides = check_building(doc)
    floors = json.loads((out / "floors.json").read_text())["floors"]
    assert doc["coordinate_system"] == "cartesian_meters"
    assert {name: lvl["elevation"] for name, lvl in doc["levels"].items()} == {
        f"L{f['id']}": f["elevation_m"] for f in floors}
    assert len(floors) == len(truth["floors"])
    for f in floors:
        assert (out / doc["levels"][f"L{f['id']}"]["layers"]["grid"]["filename"]).is_file()
    assert len(doc["lifts"]) == 1
    lift = next(iter(doc["lifts"].values()))
    assert set(lift["level_doors"]) == {f"L{f}" for f in truth["floors"]}
    err = math.hypot(lift["x"] - truth["centre"][0], lift["y"] - truth["centre"][1])
    assert err < 0.10, f"{scenario}: lift centre {err:.3f} m from the cabin's"
    assert abs(lift["width"] - truth["size"]) < 0.10 and abs(lift["depth"] - truth["size"]) < 0.10
    # Every landing's door is on the cabin's wall facing the corridor.
    for door_names in lift["level_doors"].values():
        side = sides[next(iter(doc["lifts"]))][door_names[0]]
        c, s = math.cos(lift["yaw"]), math.sin(lift["yaw"])
        n = SIDE_NORMAL[side]
        world = (c * n[0] - s * n[1], s * n[0] + c * n[1])
        assert world[0] * truth["door_normal"][0] + world[1] * truth["door_normal"][1] > 0.99


def test_floors_index_lists_each_map_and_the_connector_poses(built: tuple[str, Path, Path]) -> None:
    _, sim, out = built
    truth = _truth(sim)
    index = yaml.safe_load((out / "floors" / "index.yaml").read_text())
    floors = json.loads((out / "floors.json").read_text())["floors"]
    assert [f["id"] for f in index["floors"]] == [f["id"] for f in floors]
    rides = [t for t in truth["gt"]["transitions"] if t["kind"] == "elevator"]
    for item, floor in zip(index["floors"], floors, strict=True):
        assert item["elevation_m"] == floor["elevation_m"]
        meta = yaml.safe_load((out / "floors" / item["map"]).read_text())
        assert (out / "floors" / Path(item["map"]).parent / meta["image"]).is_file()
        elevator = next(c for c in item["connectors"] if c["kind"] == "elevator")
        # The robot rides standing at the cabin's centre: where it departs and arrives.
        leaves = any(t["from"] == floor["id"] for t in rides)
        enters = any(t["to"] == floor["id"] for t in rides)
        assert ("depart" in elevator) == leaves and ("arrive" in elevator) == enters
        for when in ("depart", "arrive"):
            if when in elevator:
                p = elevator[when]
                assert math.hypot(p["x"] - truth["centre"][0], p["y"] - truth["centre"][1]) < 0.15
    assert len(index["transitions"]) == len(truth["gt"]["transitions"])
