"""floors.json: floors at their optimised elevations, transitions with x, y, connectors."""

from __future__ import annotations

from typing import Any

import numpy as np

from mfmap.types import FloorSegmentation

CONNECTOR_RADIUS_M = 2.5  # rides/stair walks closer than this use the same elevator/stairwell


def _position_at(stamps_ns: np.ndarray, xyz: np.ndarray, stamp_ns: int) -> tuple[float, float] | None:
    if stamps_ns.shape[0] == 0:
        return None
    i = int(np.clip(np.searchsorted(stamps_ns, stamp_ns), 0, len(stamps_ns) - 1))
    if i > 0 and abs(int(stamps_ns[i - 1]) - stamp_ns) < abs(int(stamps_ns[i]) - stamp_ns):
        i -= 1
    return float(xyz[i, 0]), float(xyz[i, 1])


def floors_json(
    seg: FloorSegmentation,
    elevation_m: dict[int, float],
    traj_stamps_ns: np.ndarray,
    traj_xyz: np.ndarray,
) -> dict[str, Any]:
    """The shared floors.json schema, with elevations from the optimised graph where known."""
    transitions: list[dict[str, Any]] = []
    for tr in seg.transitions:
        item: dict[str, Any] = {
            "kind": tr.kind.value,
            "from": tr.from_floor,
            "to": tr.to_floor,
            "t_start": tr.start_ns / 1e9,
            "t_end": tr.end_ns / 1e9,
            "height_change_m": round(
                elevation_m.get(tr.to_floor, 0.0) - elevation_m.get(tr.from_floor, 0.0), 4
            )
            if tr.from_floor in elevation_m and tr.to_floor in elevation_m
            else round(tr.height_change_m, 4),
        }
        start = _position_at(traj_stamps_ns, traj_xyz, tr.start_ns)
        end = _position_at(traj_stamps_ns, traj_xyz, tr.end_ns)
        if start is not None and end is not None:
            item.update({"x": round(start[0], 4), "y": round(start[1], 4),
                         "x_end": round(end[0], 4), "y_end": round(end[1], 4)})
        transitions.append(item)
    connectors = _connectors(transitions)
    floors = []
    for floor in seg.floors:
        floors.append(
            {
                "id": floor.id,
                "elevation_m": round(elevation_m.get(floor.id, floor.elevation_m), 4),
                "pressure_pa": floor.pressure_json(),
                "visits": [[s / 1e9, e / 1e9] for s, e in floor.visits],
                "connectors": [c["id"] for c in connectors if floor.id in c["floors"]],
            }
        )
    return {"floors": floors, "transitions": transitions, "connectors": connectors}


def _connectors(transitions: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Group the placed transitions into elevators and stairwells by their midpoints; each
    transition gets its connector's id."""
    connectors: list[dict[str, Any]] = []
    members: list[list[tuple[float, float]]] = []
    for item in transitions:
        if "x" not in item:
            continue
        mid = ((item["x"] + item["x_end"]) / 2, (item["y"] + item["y_end"]) / 2)
        for conn, pts in zip(connectors, members, strict=True):
            if conn["kind"] == item["kind"] and np.hypot(conn["x"] - mid[0], conn["y"] - mid[1]) < CONNECTOR_RADIUS_M:
                pts.append(mid)
                conn["x"] = round(float(np.mean([p[0] for p in pts])), 4)
                conn["y"] = round(float(np.mean([p[1] for p in pts])), 4)
                conn["floors"] = sorted(set(conn["floors"]) | {item["from"], item["to"]})
                item["connector"] = conn["id"]
                break
        else:
            conn = {"id": len(connectors), "kind": item["kind"], "x": round(mid[0], 4),
                    "y": round(mid[1], 4), "floors": sorted({item["from"], item["to"]})}
            connectors.append(conn)
            members.append([mid])
            item["connector"] = conn["id"]
    return connectors
