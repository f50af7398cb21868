"""The ground truth of several logs of one building as one, for a build made from all of them.

Each simulated session's ground truth (`mfmap simulate`: gt_points.csv, gt_trajectory.tum,
gt_floors.json) is in the building frame already, but its floors are numbered from the lowest
floor that log visited; gt_floors.json says which building floor each is (`building_floor`).
Merged, the checkpoints and floors carry building floors, so a multi-log build is scored per
building floor, and the trajectories, disjoint in time, are one.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mfmap.atomic import write_bytes_atomic
from mfmap.errors import GroundTruthError

POINTS, TRAJECTORY, FLOORS = "gt_points.csv", "gt_trajectory.tum", "gt_floors.json"


@dataclass(frozen=True)
class Truth:
    """Ground-truth files for `mfmap.eval.evaluate`."""

    points: Path
    trajectory: Path
    floors: Path


def _read_floors(folder: Path) -> dict[str, Any]:
    path = folder / FLOORS
    try:
        doc: dict[str, Any] = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise GroundTruthError("not a simulated session's ground truth", path) from err
    return doc


def _building_floors(doc: dict[str, Any]) -> dict[int, int]:
    """Session floor id -> building floor id (the same when the file does not say)."""
    return {int(f["id"]): int(f.get("building_floor", f["id"])) for f in doc["floors"]}


def merge_sessions(folders: Sequence[Path], out: Path) -> Truth:
    """One set of ground-truth files in `out` from the sessions in `folders`; a single folder's
    files are returned as they are."""
    folders = [Path(f) for f in folders]
    if len(folders) == 1:
        f = folders[0]
        return Truth(f / POINTS, f / TRAJECTORY, f / FLOORS)
    docs = [_read_floors(f) for f in folders]
    maps = [_building_floors(d) for d in docs]
    out.mkdir(parents=True, exist_ok=True)
    truth = Truth(out / POINTS, out / TRAJECTORY, out / FLOORS)
    write_bytes_atomic(truth.points, _points(folders, maps).encode())
    write_bytes_atomic(truth.trajectory, _trajectory(folders).encode())
    merged = _floors(docs, maps)
    write_bytes_atomic(truth.floors, (json.dumps(merged, indent=2) + "\n").encode())
    return truth


def _points(folders: list[Path], maps: list[dict[int, int]]) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    header: list[str] | None = None
    for folder, floors in zip(folders, maps, strict=True):
        with (folder / POINTS).open(newline="", encoding="utf-8-sig") as f:
            reader = csv.DictReader(f)
            if header is None:
                header = list(reader.fieldnames or [])
                writer.writerow(header)
            for row in reader:
                row["floor"] = str(floors[int(row["floor"])])
                writer.writerow([row[c] for c in header])
    return buf.getvalue()


def _trajectory(folders: list[Path]) -> str:
    lines = [line for folder in folders for line in (folder / TRAJECTORY).read_text().splitlines()
             if line.strip() and not line.startswith("#")]
    lines.sort(key=lambda line: float(line.split()[0]))
    return "\n".join(lines) + "\n"


def _floors(docs: list[dict[str, Any]], maps: list[dict[int, int]]) -> dict[str, Any]:
    """Floors by building floor (visits of every session), transitions renamed, in time order."""
    floors: dict[int, dict[str, Any]] = {}
    transitions: list[dict[str, Any]] = []
    for doc, rename in zip(docs, maps, strict=True):
        for f in doc["floors"]:
            k = rename[int(f["id"])]
            item = floors.setdefault(k, {**f, "id": k, "building_floor": k, "visits": []})
            item["visits"] = sorted([*item["visits"], *f.get("visits", [])])
        for t in doc.get("transitions", []):
            transitions.append({**t, "from": rename[int(t["from"])], "to": rename[int(t["to"])]})
    transitions.sort(key=lambda t: float(t["t_start"]))
    return {"floors": [floors[k] for k in sorted(floors)], "transitions": transitions}


__all__ = ["Truth", "merge_sessions"]
