"""What Open-RMF's readers require of a building.yaml, read off their source.

rmf_building_map_tools is not on PyPI (it is a ROS package needing ament, fiona, pyproj and
rtree), so the tests check a building map against the reads its parser makes, line by line:
building_map/building.py (Building.parse_yaml), level.py (Level.parse_yaml), vertex.py,
edge.py, param_value.py, lift.py (Lift, LiftDoor), and the traffic editor's gui/lift.cpp and
layer.cpp. Each check names the read it stands for; nothing of the parser is run.
"""

from __future__ import annotations

from typing import Any

COORDINATE_SYSTEMS = {"reference_image", "web_mercator", "cartesian_meters", "wgs84"}
PARAM_TYPES = {1, 2, 3, 4}  # ParamValue STRING, INT, DOUBLE, BOOL
LEVEL_EDGE_LISTS = ("measurements", "lanes", "walls", "doors")


def _number(value: Any, where: str) -> float:
    assert isinstance(value, (int, float)) and not isinstance(value, bool), f"{where}: {value!r} is not a number"
    return float(value)


def _params(params: Any, where: str) -> None:
    assert isinstance(params, dict), f"{where}: params must be a map"
    for name, pv in params.items():
        # ParamValue.__init__: self.type = yaml_value[0]; self.value = yaml_value[1]
        assert isinstance(pv, list) and len(pv) == 2 and pv[0] in PARAM_TYPES, f"{where}.{name}: {pv!r}"


def _lift_door_side(x: float, y: float, width: float, depth: float) -> str:
    """LiftDoor.__init__: the side is the wall nearer to the door's (x, y)."""
    x_diff = abs(abs(x) - width / 2)
    y_diff = abs(abs(y) - depth / 2)
    if x_diff <= y_diff:
        return "right" if x > 0 else "left"
    return "front" if y > 0 else "back"


def check_building(doc: dict[str, Any]) -> dict[str, dict[str, str]]:
    """Assert the document is one the readers accept; return lift -> door name -> side."""
    # Building.parse_yaml: yaml_node['building_name'] or yaml_node['name']
    assert "building_name" in doc or isinstance(doc.get("name"), str)
    # CoordinateSystem[cs_name]
    assert doc.get("coordinate_system", "reference_image") in COORDINATE_SYSTEMS
    levels = doc["levels"]
    assert isinstance(levels, dict) and levels
    # reference_level_name, when given, indexes self.levels
    assert doc.get("reference_level_name", next(iter(levels))) in levels
    for name, level in levels.items():
        where = f"levels.{name}"
        # Level.parse_yaml: yaml_node['drawing']['filename']; float(yaml_node['elevation'])
        if "drawing" in level:
            assert isinstance(level["drawing"]["filename"], str)
        _number(level.get("elevation", 0.0), f"{where}.elevation")
        vertices = level.get("vertices") or []
        for i, v in enumerate(vertices):
            # Vertex.__init__: float(yaml_node[0..2]); name = yaml_node[3]; params yaml_node[4]
            assert isinstance(v, list) and len(v) >= 4, f"{where}.vertices[{i}]"
            for k in range(3):
                _number(v[k], f"{where}.vertices[{i}][{k}]")
            assert isinstance(v[3], str)
            if len(v) > 4:
                _params(v[4], f"{where}.vertices[{i}]")
        for key in LEVEL_EDGE_LISTS:
            for e in level.get(key, []):
                # Edge.parse_yaml: int(yaml_node[0]), int(yaml_node[1]), yaml_node[2] params
                assert 0 <= int(e[0]) < len(vertices) and 0 <= int(e[1]) < len(vertices)
                _params(e[2], f"{where}.{key}")
        for key in ("models", "floors", "holes", "fiducials"):
            assert isinstance(level.get(key, []), list)
        # traffic editor Layer::from_yaml: y["filename"], y["transform"] (translation, yaw, scale)
        for lname, layer in (level.get("layers") or {}).items():
            assert isinstance(layer["filename"], str), f"{where}.layers.{lname}"
            for key in ("translation_x", "translation_y", "yaw", "scale"):
                _number(layer["transform"][key], f"{where}.layers.{lname}.transform.{key}")
            assert _number(layer["transform"]["scale"], "scale") > 0
    sides: dict[str, dict[str, str]] = {}
    for name, lift in (doc.get("lifts") or {}).items():
        where = f"lifts.{name}"
        # Lift.__init__: float depth, width, yaw, x, y
        width = _number(lift["width"], f"{where}.width")
        depth = _number(lift["depth"], f"{where}.depth")
        _number(lift["yaw"], f"{where}.yaw")
        _number(lift["x"], f"{where}.x")
        _number(lift["y"], f"{where}.y")
        assert width > 0 and depth > 0
        # gui/lift.cpp: data["reference_floor_name"].as<string>() (no default)
        assert lift["reference_floor_name"] in levels
        # levels[self.highest_floor] / levels[self.lowest_floor]
        for key in ("highest_floor", "lowest_floor", "initial_floor_name"):
            if lift.get(key):
                assert lift[key] in levels, f"{where}.{key}"
        # level_doors: levels[level_name].elevation for every key
        doors = lift.get("doors") or {}
        for level_name, door_names in (lift.get("level_doors") or {}).items():
            assert level_name in levels
            assert door_names and all(d in doors for d in door_names), f"{where}.level_doors.{level_name}"
        sides[name] = {}
        for door_name, door in doors.items():
            # LiftDoor.__init__: door_type, float x, y, motion_axis_orientation, width
            assert isinstance(door["door_type"], int)
            x, y = _number(door["x"], "x"), _number(door["y"], "y")
            _number(door["motion_axis_orientation"], "motion_axis_orientation")
            assert 0 < _number(door["width"], "width") <= max(width, depth)
            sides[name][door_name] = _lift_door_side(x, y, width, depth)
    return sides
