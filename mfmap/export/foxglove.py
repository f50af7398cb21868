"""map.mcap: the building for Foxglove, in its own schemas (protobuf), and a layout to open it.

Topics (every one in a Foxglove schema, so the 3D panel draws it without a converter):

| topic | schema | content |
|---|---|---|
| `/floors/transforms` | foxglove.FrameTransforms | `world` -> `floor_<id>` at each floor's elevation (once) |
| `/robot/transforms` | foxglove.FrameTransforms | `world` -> `base_link` at every lidar scan |
| `/robot/pose` | foxglove.PoseInFrame | the base pose at every lidar scan (playback follows it) |
| `/trajectory` | foxglove.PosesInFrame | the whole optimised trajectory (once) |
| `/floor_<id>/cloud` | foxglove.PointCloud | the floor's cloud in `world`, coloured by floor (once) |
| `/floor_<id>/grid` | foxglove.Grid | the floor's occupancy grid in `floor_<id>` (once) |
| `/building/connectors` | foxglove.SceneUpdate | elevator cabins and stairwells on the floors they serve |
| `/building/labels` | foxglove.SceneUpdate | a label per floor: name and elevation |

The maps are stamped at the trajectory's first scan, so they are there from the start of
playback. One topic per floor lets Foxglove's topic list toggle floors.
"""

from __future__ import annotations

import io
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import IO, Any

import numpy as np

from mfmap.export.cabin import Cabin
from mfmap.export.files import rotation_to_quat_xyzw
from mfmap.export.grid import OccupancyGrid
from mfmap.export.nav2 import level_name

# matplotlib's tab10, the floors' colours in report.html too.
FLOOR_COLOURS = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
                 (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207))
CABIN_HEIGHT_M = 2.4  # drawn height of a cabin and a stairwell's marker (not measured)
WORLD, BASE = "world", "base_link"


def floor_colour(floor_id: int) -> tuple[int, int, int]:
    return FLOOR_COLOURS[floor_id % len(FLOOR_COLOURS)]


@dataclass(frozen=True)
class FloorMap:
    """One floor as Foxglove shows it."""

    floor_id: int
    elevation_m: float
    cloud: np.ndarray  # (N, 3) float32 world
    grid: OccupancyGrid | None


def _time(pb: Any, stamp_ns: int) -> Any:
    pb.seconds, pb.nanos = divmod(int(stamp_ns), 1_000_000_000)
    return pb


def _pose(pb: Any, pose: np.ndarray) -> Any:
    q = rotation_to_quat_xyzw(pose[:3, :3])
    pb.position.x, pb.position.y, pb.position.z = (float(v) for v in pose[:3, 3])
    pb.orientation.x, pb.orientation.y, pb.orientation.z, pb.orientation.w = (float(v) for v in q)
    return pb


def _yaw_pose(x: float, y: float, z: float, yaw: float) -> np.ndarray:
    pose = np.eye(4)
    pose[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    pose[:3, 3] = (x, y, z)
    return pose


def _colour(pb: Any, rgb: tuple[int, int, int], alpha: float) -> Any:
    pb.r, pb.g, pb.b, pb.a = rgb[0] / 255, rgb[1] / 255, rgb[2] / 255, alpha
    return pb


def cloud_message(floor: FloorMap, stamp_ns: int) -> Any:
    """foxglove.PointCloud: x, y, z float32 and the floor's colour, darker low, lighter high."""
    from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
    from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud

    pts = np.asarray(floor.cloud, dtype=np.float32)
    rec = np.zeros(pts.shape[0], dtype=[("xyz", "<f4", 3), ("rgba", "u1", 4)])
    rec["xyz"] = pts
    rel = np.clip((pts[:, 2] - floor.elevation_m) / 3.0, 0.0, 1.0)
    shade = (0.55 + 0.45 * rel)[:, None]
    rec["rgba"][:, :3] = np.clip(np.array(floor_colour(floor.floor_id))[None, :] * shade, 0, 255)
    rec["rgba"][:, 3] = 255
    msg = PointCloud(frame_id=WORLD, point_stride=16, data=rec.tobytes())
    _time(msg.timestamp, stamp_ns)
    _pose(msg.pose, np.eye(4))
    for name, offset, kind in (("x", 0, PackedElementField.FLOAT32), ("y", 4, PackedElementField.FLOAT32),
                               ("z", 8, PackedElementField.FLOAT32), ("red", 12, PackedElementField.UINT8),
                               ("green", 13, PackedElementField.UINT8), ("blue", 14, PackedElementField.UINT8),
                               ("alpha", 15, PackedElementField.UINT8)):
        msg.fields.add(name=name, offset=offset, type=kind)
    return msg


def grid_message(floor: FloorMap, grid: OccupancyGrid, stamp_ns: int) -> Any:
    """foxglove.Grid in the floor's frame: occupied dark, free in the floor's colour, unknown clear."""
    from foxglove_schemas_protobuf.Grid_pb2 import Grid
    from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField

    h, w = grid.shape
    rgba = np.zeros((h, w, 4), dtype=np.uint8)  # row 0 = lowest y, as Grid's rows run along +y
    light = np.array(floor_colour(floor.floor_id)) * 0.35 + 255 * 0.65
    rgba[grid.free, :3] = light.astype(np.uint8)
    rgba[grid.free, 3] = 200
    rgba[grid.occupied] = (20, 20, 20, 255)
    msg = Grid(frame_id=f"floor_{floor.floor_id}", column_count=w, row_stride=4 * w, cell_stride=4,
               data=rgba.tobytes())
    _time(msg.timestamp, stamp_ns)
    _pose(msg.pose, _yaw_pose(float(grid.origin_xy[0]), float(grid.origin_xy[1]), 0.0, 0.0))
    msg.cell_size.x = msg.cell_size.y = float(grid.resolution_m)
    for name, offset in (("red", 0), ("green", 1), ("blue", 2), ("alpha", 3)):
        msg.fields.add(name=name, offset=offset, type=PackedElementField.UINT8)
    return msg


def _transforms(stamp_ns: int, items: Sequence[tuple[str, str, np.ndarray]]) -> Any:
    from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms

    msg = FrameTransforms()
    for parent, child, pose in items:
        tf = msg.transforms.add(parent_frame_id=parent, child_frame_id=child)
        _time(tf.timestamp, stamp_ns)
        q = rotation_to_quat_xyzw(pose[:3, :3])
        tf.translation.x, tf.translation.y, tf.translation.z = (float(v) for v in pose[:3, 3])
        tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w = (float(v) for v in q)
    return msg


def connector_scene(floors_doc: dict[str, Any], cabins: Sequence[Cabin], elevation_m: dict[int, float],
                    stamp_ns: int) -> Any:
    """Cabins (measured size, or a 2 m box where none was measured) and stairwells per floor."""
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    scene = SceneUpdate()
    for conn in floors_doc["connectors"]:
        cabin = next((c for c in cabins if conn["kind"] == "elevator"
                      and math.hypot(c.x_m - conn["x"], c.y_m - conn["y"]) < 2.5), None)
        if cabin is not None:
            x, y, yaw = cabin.x_m, cabin.y_m, cabin.yaw_rad
            size = (cabin.inner_width_m, cabin.inner_depth_m)
        else:
            x, y, yaw, size = conn["x"], conn["y"], 0.0, (2.0, 2.0)
        rgb = (230, 180, 40) if conn["kind"] == "elevator" else (60, 200, 200)
        entity = scene.entities.add(frame_id=WORLD, id=f"{conn['kind']}_{conn['id']}")
        _time(entity.timestamp, stamp_ns)
        entity.metadata.add(key="kind", value=conn["kind"])
        entity.metadata.add(key="floors", value=",".join(level_name(f) for f in conn["floors"]))
        zs = sorted(elevation_m[f] for f in conn["floors"] if f in elevation_m)
        for z in zs:
            cube = entity.cubes.add()
            _pose(cube.pose, _yaw_pose(x, y, z + CABIN_HEIGHT_M / 2, yaw))
            cube.size.x, cube.size.y, cube.size.z = size[0], size[1], CABIN_HEIGHT_M
            _colour(cube.color, rgb, 0.35)
        if len(zs) > 1:
            line = entity.lines.add(type=0, thickness=0.08)
            _pose(line.pose, np.eye(4))
            _colour(line.color, rgb, 1.0)
            for z in (zs[0], zs[-1] + CABIN_HEIGHT_M):
                line.points.add(x=x, y=y, z=z)
        text = entity.texts.add(billboard=True, font_size=14.0, scale_invariant=True,
                                text=f"{conn['kind']} {conn['id']}")
        _pose(text.pose, _yaw_pose(x, y, (zs[-1] if zs else 0.0) + CABIN_HEIGHT_M + 0.4, 0.0))
        _colour(text.color, rgb, 1.0)
    return scene


def label_scene(floors: Sequence[FloorMap], stamp_ns: int) -> Any:
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    scene = SceneUpdate()
    for floor in floors:
        entity = scene.entities.add(frame_id=WORLD, id=f"label_{level_name(floor.floor_id)}")
        _time(entity.timestamp, stamp_ns)
        if floor.cloud.shape[0]:
            lo = floor.cloud[:, :2].min(axis=0)
            at = (float(lo[0]) - 1.0, float(lo[1]) - 1.0)
        else:
            at = (0.0, 0.0)
        text = entity.texts.add(billboard=True, font_size=18.0, scale_invariant=True,
                                text=f"{level_name(floor.floor_id)}  {floor.elevation_m:+.2f} m")
        _pose(text.pose, _yaw_pose(at[0], at[1], floor.elevation_m + 0.5, 0.0))
        _colour(text.color, floor_colour(floor.floor_id), 1.0)
    return scene


def mcap_bytes(floors: Sequence[FloorMap], floors_doc: dict[str, Any], cabins: Sequence[Cabin],
               stamps_ns: np.ndarray, poses: np.ndarray) -> bytes:
    """map.mcap in memory (for tests; `write_mcap` streams it to its file)."""
    buf = io.BytesIO()
    write_mcap(buf, floors, floors_doc, cabins, stamps_ns, poses)
    return buf.getvalue()


def write_mcap(out: IO[bytes], floors: Sequence[FloorMap], floors_doc: dict[str, Any],
               cabins: Sequence[Cabin], stamps_ns: np.ndarray, poses: np.ndarray) -> None:
    """Write the building's MCAP to `out`, chunk by chunk (zstd)."""
    from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
    from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
    from mcap.writer import CompressionType, Writer
    from mcap_protobuf.schema import build_file_descriptor_set

    writer = Writer(out, compression=CompressionType.ZSTD, chunk_size=4 * 1024 * 1024)
    writer.start(profile="", library="mfmap")
    schemas: dict[str, int] = {}
    channels: dict[str, int] = {}

    def write(topic: str, msg: Any, stamp_ns: int) -> None:
        name = type(msg).DESCRIPTOR.full_name
        if name not in schemas:
            schemas[name] = writer.register_schema(
                name=name, encoding="protobuf",
                data=build_file_descriptor_set(type(msg)).SerializeToString())
        if topic not in channels:
            channels[topic] = writer.register_channel(topic=topic, message_encoding="protobuf",
                                                      schema_id=schemas[name])
        writer.add_message(channels[topic], log_time=int(stamp_ns), publish_time=int(stamp_ns),
                           data=msg.SerializeToString())

    t0 = int(stamps_ns[0]) if stamps_ns.shape[0] else 0
    elevation = {f.floor_id: f.elevation_m for f in floors}
    write("/floors/transforms", _transforms(t0, [(WORLD, f"floor_{f.floor_id}",
                                                  _yaw_pose(0.0, 0.0, f.elevation_m, 0.0)) for f in floors]), t0)
    for floor in floors:
        write(f"/floor_{floor.floor_id}/cloud", cloud_message(floor, t0), t0)
        if floor.grid is not None:
            write(f"/floor_{floor.floor_id}/grid", grid_message(floor, floor.grid, t0), t0)
    write("/building/connectors", connector_scene(floors_doc, cabins, elevation, t0), t0)
    write("/building/labels", label_scene(floors, t0), t0)
    trajectory = PosesInFrame(frame_id=WORLD)
    _time(trajectory.timestamp, t0)
    for pose in poses:
        _pose(trajectory.poses.add(), pose)
    write("/trajectory", trajectory, t0)
    for stamp, pose in zip(stamps_ns.tolist(), poses, strict=True):
        write("/robot/transforms", _transforms(stamp, [(WORLD, BASE, pose)]), stamp)
        msg = PoseInFrame(frame_id=WORLD)
        _time(msg.timestamp, stamp)
        _pose(msg.pose, pose)
        write("/robot/pose", msg, stamp)
    writer.finish()


def layout(floors: Sequence[FloorMap]) -> dict[str, Any]:
    """A Foxglove layout (import it from the layout menu): one 3D panel following the robot,
    with every floor, the trajectory and the connectors shown."""
    topics: dict[str, Any] = {
        "/trajectory": {"visible": True, "type": "line", "lineWidth": 0.05, "gradient": ["#d62728ff", "#d62728ff"]},
        "/robot/pose": {"visible": True, "type": "arrow", "arrowScale": [0.6, 0.15, 0.15]},
        "/building/connectors": {"visible": True},
        "/building/labels": {"visible": True},
    }
    for floor in floors:
        topics[f"/floor_{floor.floor_id}/cloud"] = {"visible": True, "colorMode": "rgba-fields",
                                                    "pointSize": 2, "pointShape": "circle"}
        if floor.grid is not None:
            topics[f"/floor_{floor.floor_id}/grid"] = {"visible": True, "colorMode": "rgba-fields"}
    panel = {
        "cameraState": {"perspective": True, "distance": 45.0, "phi": 55.0, "thetaOffset": 45.0,
                        "target": [0, 0, 0], "targetOffset": [0, 0, 0], "targetOrientation": [0, 0, 0, 1],
                        "fovy": 45, "near": 0.5, "far": 5000},
        "followMode": "follow-position",
        "followTf": BASE,
        "scene": {"transforms": {"showLabel": False, "axisScale": 1.0}},
        "transforms": {},
        "topics": topics,
        "layers": {"grid": {"visible": False, "layerId": "foxglove.Grid"}},
        "publish": {"type": "point"},
    }
    return {"configById": {"3D!mfmap": panel}, "globalVariables": {}, "userNodes": {},
            "playbackConfig": {"speed": 1.0}, "layout": "3D!mfmap"}


def layout_json(floors: Sequence[FloorMap]) -> str:
    return json.dumps(layout(floors), indent=2) + "\n"
