"""building.yaml: the building as Open-RMF's building map (rmf_building_map_tools' format).

The schema is what `rmf_building_map_tools/building_map` (building.py, level.py, lift.py,
vertex.py) and the traffic editor (gui/building.cpp, level.cpp, lift.cpp, layer.cpp) read:

- `coordinate_system: cartesian_meters`: vertices and lifts in metres in the build's world frame
  (the parser passes them through; no reference-image scaling, no y flip).
- one level per floor (`L<id>`, as in floors/index.yaml) with its `elevation`; its nav2 grid
  image is a traffic-editor `layers` entry whose transform puts pixel rows in metres. Not a
  `drawing`: building_map_server reads a drawing's placement from `level.transform.scale` and
  `.translation`, which a cartesian_meters level's PassthroughTransform does not have.
- per floor, named vertices where each connector puts the robot (the nav2 index's poses), so a
  nav graph can be drawn from them; stairs, which Open-RMF has no element for, are such
  vertices on the floors they join, with `connector` parameters.
- one lift per measured elevator cabin: `x`, `y`, `yaw` of the cabin's centre, `width` and
  `depth` its outer size (the interior the lidar measured plus the walls that
  rmf_building_map_tools draws inside that size, Lift.wall_thickness), one door per wall seen
  open, and `level_doors` for the floors where it opened.
"""

from __future__ import annotations

import math
from typing import Any

from mfmap.export.cabin import Cabin
from mfmap.export.nav2 import level_name

# rmf_building_map_tools draws the cabin's walls this thick inside width x depth (lift.py).
RMF_CABIN_WALL_M = 0.05
# Lift door types of the traffic editor (gui/lift_door.h, DoorType).
DOUBLE_SLIDING = 2
# ParamValue types of rmf_building_map_tools (param_value.py).
_STRING, _INT = 1, 2


def _door_pose(side: str, offset_m: float, door_width_m: float, width_m: float,
               depth_m: float) -> dict[str, Any]:
    """A lift door as LiftDoor reads it: x, y from the cabin's centre on the wall of `side`
    (LiftDoor assigns the side by the nearer wall), sliding along that wall."""
    if side in ("front", "back"):
        x, y, axis, wall = offset_m, (depth_m if side == "front" else -depth_m) / 2, 0.0, width_m
    else:
        x, y, axis, wall = (width_m if side == "right" else -width_m) / 2, offset_m, math.pi / 2, depth_m
    return {"door_type": DOUBLE_SLIDING, "x": round(x, 3), "y": round(y, 3),
            "motion_axis_orientation": round(axis, 4), "width": round(min(door_width_m, wall), 3)}


def _lift(index: int, cabin: Cabin, levels: set[int]) -> tuple[str, dict[str, Any]] | None:
    width = round(cabin.inner_width_m + 2 * RMF_CABIN_WALL_M, 3)
    depth = round(cabin.inner_depth_m + 2 * RMF_CABIN_WALL_M, 3)
    doors: dict[str, dict[str, Any]] = {}
    level_doors: dict[str, list[str]] = {}
    for floor in sorted(cabin.doors):
        if floor not in levels:
            continue
        door = cabin.doors[floor]
        name = f"door_{door.side}"
        doors.setdefault(name, _door_pose(door.side, door.offset_m, door.width_m, width, depth))
        level_doors[level_name(floor)] = [name]
    if not level_doors:
        return None
    served = sorted(int(name[1:]) for name in level_doors)
    lift = {
        "x": cabin.x_m, "y": cabin.y_m, "yaw": round(cabin.yaw_rad, 4),
        "width": width, "depth": depth,
        "reference_floor_name": level_name(served[0]),
        "initial_floor_name": level_name(served[0]),
        "lowest_floor": level_name(served[0]),
        "highest_floor": level_name(served[-1]),
        "plugins": True,
        "doors": doors,
        "level_doors": level_doors,
    }
    return f"lift_{index}", lift


def building_yaml(name: str, floors_doc: dict[str, Any], grids: dict[int, dict[str, Any]],
                  cabins: list[Cabin], index_doc: dict[str, Any]) -> tuple[dict[str, Any], list[str]]:
    """The building map and warnings for what it cannot hold.

    `grids` maps floor id -> {"image": path from the output folder, "resolution": m/cell,
    "origin": [x, y], "height": rows}; a floor without one is a level without an image.
    `index_doc` is floors/index.yaml's document (connector poses per floor).
    """
    warnings: list[str] = []
    floor_ids = {f["id"] for f in floors_doc["floors"]}
    poses = {f["id"]: f["connectors"] for f in index_doc["floors"]}
    levels: dict[str, Any] = {}
    for floor in floors_doc["floors"]:
        fid = floor["id"]
        if grids.get(fid) is None:
            warnings.append(f"building.yaml: floor {fid} has no grid; its level has no map image")
        levels[level_name(fid)] = _level(floor, grids.get(fid), poses.get(fid, []))
    lifts: dict[str, Any] = {}
    for cabin in cabins:
        made = _lift(len(lifts), cabin, floor_ids)
        if made is None:
            warnings.append(f"building.yaml: the elevator at ({cabin.x_m:.1f}, {cabin.y_m:.1f}) was "
                            "never seen with its doors open on a mapped floor; no lift is written")
            continue
        lifts[made[0]] = made[1]
    for conn in floors_doc["connectors"]:
        if conn["kind"] == "elevator" and not any(
                math.hypot(c.x_m - conn["x"], c.y_m - conn["y"]) < 2.5 for c in cabins):
            warnings.append(f"building.yaml: elevator connector {conn['id']} has no measured cabin; "
                            "no lift is written for it")
    doc = {
        "name": name,
        "coordinate_system": "cartesian_meters",
        "reference_level_name": level_name(min(floor_ids)) if floor_ids else "L0",
        "levels": levels,
        "lifts": lifts,
    }
    return doc, warnings


def _level(floor: dict[str, Any], grid: dict[str, Any] | None,
           connectors: list[dict[str, Any]]) -> dict[str, Any]:
    """One floor's level: its elevation, its grid image as a layer, its connector poses."""
    fid = floor["id"]
    level: dict[str, Any] = {"elevation": float(floor["elevation_m"])}
    if grid is not None:
        res = float(grid["resolution"])
        level["layers"] = {"grid": {
            "filename": grid["image"],
            "visible": True,
            "color": [0.0, 0.0, 1.0, 0.5],
            # Pixel (col, row) at (tx + col * scale, ty - row * scale): row 0 is the top.
            "transform": {"scale": res, "yaw": 0.0,
                          "translation_x": round(float(grid["origin"][0]), 4),
                          "translation_y": round(float(grid["origin"][1]) + grid["height"] * res, 4)},
        }}
    vertices = []
    for conn in connectors:
        for when in ("depart", "arrive"):
            if when not in conn:
                continue
            p = conn[when]
            vertices.append([p["x"], p["y"], 0.0, f"{conn['kind']}_{conn['id']}_{when}_{level_name(fid)}",
                             {"connector": [_STRING, conn["kind"]], "connector_id": [_INT, conn["id"]]}])
    level.update({"vertices": vertices, "lanes": [], "walls": [], "doors": [], "measurements": [],
                  "models": [], "floors": [], "holes": [], "fiducials": []})
    return level
