"""floors/index.yaml: one nav2 map per floor, and where each connector puts the robot on it.

nav2 knows one map at a time (nav2_map_server). A multi-floor robot swaps the map at a ride:
it stands at the connector on its floor, rides, then loads the next floor's map and sets its
initial pose to where the connector lets it off there. This file gives both per floor, in the
frame every floor's grid shares (the build's world frame, so no map needs an offset).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

FORMAT = "mfmap-floors-index/1"


def level_name(floor_id: int) -> str:
    """The floor's name in every export (nav2 index, Open-RMF levels, Foxglove labels)."""
    return f"L{floor_id}"


def _pose_at(stamps_ns: np.ndarray, poses: np.ndarray, t_s: float) -> np.ndarray | None:
    if stamps_ns.shape[0] == 0:
        return None
    stamp = round(t_s * 1e9)
    i = int(np.clip(np.searchsorted(stamps_ns, stamp), 0, len(stamps_ns) - 1))
    if i > 0 and abs(int(stamps_ns[i - 1]) - stamp) < abs(int(stamps_ns[i]) - stamp):
        i -= 1
    return np.asarray(poses[i])


def _mean_pose(poses: list[np.ndarray]) -> dict[str, float]:
    xy = np.mean([p[:2, 3] for p in poses], axis=0)
    yaws = [math.atan2(p[1, 0], p[0, 0]) for p in poses]
    yaw = math.atan2(sum(math.sin(a) for a in yaws), sum(math.cos(a) for a in yaws))
    return {"x": round(float(xy[0]), 4), "y": round(float(xy[1]), 4), "yaw": round(yaw, 4)}


def floors_index(floors_doc: dict[str, Any], map_files: dict[int, str], stamps_ns: np.ndarray,
                 poses: np.ndarray) -> tuple[dict[str, Any], list[str]]:
    """The index document and warnings (a floor without a grid is listed without a map).

    `map_files` maps floor id -> its grid yaml, relative to the folder of index.yaml.
    Per floor and connector: `depart`, the mean pose in which rides or walks off this floor
    began, and `arrive`, the mean pose in which those onto it ended (either absent when the
    log has none).
    """
    warnings: list[str] = []
    depart: dict[tuple[int, int], list[np.ndarray]] = {}
    arrive: dict[tuple[int, int], list[np.ndarray]] = {}
    transitions = []
    for tr in floors_doc["transitions"]:
        conn = tr.get("connector")
        if conn is None:
            continue
        start = _pose_at(stamps_ns, poses, tr["t_start"])
        end = _pose_at(stamps_ns, poses, tr["t_end"])
        if start is not None:
            depart.setdefault((tr["from"], conn), []).append(start)
        if end is not None:
            arrive.setdefault((tr["to"], conn), []).append(end)
        transitions.append({"connector": conn, "kind": tr["kind"], "from": level_name(tr["from"]),
                            "to": level_name(tr["to"]), "t_start": tr["t_start"],
                            "t_end": tr["t_end"]})
    floors = []
    for floor in floors_doc["floors"]:
        fid = floor["id"]
        item: dict[str, Any] = {"id": fid, "name": level_name(fid),
                                "elevation_m": floor["elevation_m"]}
        if fid in map_files:
            item["map"] = map_files[fid]
        else:
            warnings.append(f"floors/index.yaml: floor {fid} has no grid (no scans mapped on it); "
                            "it is listed without a map")
        conns = []
        for conn in floors_doc["connectors"]:
            if fid not in conn["floors"]:
                continue
            entry: dict[str, Any] = {"id": conn["id"], "kind": conn["kind"],
                                     "floors": [level_name(f) for f in conn["floors"]]}
            if (fid, conn["id"]) in depart:
                entry["depart"] = _mean_pose(depart[(fid, conn["id"])])
            if (fid, conn["id"]) in arrive:
                entry["arrive"] = _mean_pose(arrive[(fid, conn["id"])])
            conns.append(entry)
        item["connectors"] = conns
        floors.append(item)
    doc = {
        "format": FORMAT,
        "frame": "every map's frame: the build's world frame (x, y in metres, yaw in radians)",
        "floors": floors,
        "transitions": transitions,
    }
    return doc, warnings
