"""Reading a build's output folder and the ground-truth files; a small PLY reader/writer.

Every problem with a file raises GroundTruthError (ground truth) or OutputError (the build)
naming the file, so the CLI prints one line.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from mfmap.atomic import atomic_open
from mfmap.errors import GroundTruthError, MfmapError, OutputError, read_text
from mfmap.types import F64, I64

POINTS_COLUMNS = ("label", "floor", "x", "y", "z", "t_start", "t_end")
INCOMPLETE_MARKER = ".incomplete"

# ---------------------------------------------------------------------------------------- PLY

_PLY_TYPES: dict[str, str] = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip


def read_ply(path: Path, error: type[MfmapError] = GroundTruthError) -> dict[str, np.ndarray]:
    """The vertex properties of a PLY file (ascii or binary) as {name: 1-D array}."""
    try:
        with path.open("rb") as f:
            if f.readline().strip() != b"ply":
                raise error("not a PLY file (no 'ply' magic line)", path)
            fmt = ""
            n_vertex = -1
            props: list[tuple[str, str]] = []
            element = ""
            while True:
                raw = f.readline()
                if not raw:
                    raise error("PLY header has no end_header", path)
                words = raw.decode("ascii", errors="replace").split()
                if not words or words[0] in ("comment", "obj_info"):
                    continue
                if words[0] == "end_header":
                    break
                if words[0] == "format":
                    fmt = words[1]
                elif words[0] == "element":
                    element = words[1]
                    if element == "vertex":
                        n_vertex = int(words[2])
                    elif n_vertex < 0 and int(words[2]) > 0:
                        raise error(f"element '{element}' before the vertices is not supported", path)
                elif words[0] == "property" and element == "vertex":
                    if words[1] == "list":
                        raise error("list properties on vertices are not supported", path)
                    if words[1] not in _PLY_TYPES:
                        raise error(f"unknown PLY property type '{words[1]}'", path)
                    props.append((words[2], _PLY_TYPES[words[1]]))
            if n_vertex < 0:
                raise error("PLY file has no vertex element", path)
            if fmt == "ascii":
                names = [p[0] for p in props]
                table = np.loadtxt(f, max_rows=n_vertex, ndmin=2) if n_vertex else np.empty((0, len(props)))
                if table.shape != (n_vertex, len(props)):
                    raise error(f"expected {n_vertex} vertices of {len(props)} values", path)
                return {name: table[:, i].astype(props[i][1]) for i, name in enumerate(names)}
            if fmt not in ("binary_little_endian", "binary_big_endian"):
                raise error(f"unknown PLY format '{fmt}'", path)
            order = "<" if fmt == "binary_little_endian" else ">"
            dtype = np.dtype([(name, order + code) for name, code in props])
            data = np.fromfile(f, dtype=dtype, count=n_vertex)
            if data.shape[0] != n_vertex:
                raise error(f"truncated PLY: {data.shape[0]} of {n_vertex} vertices", path)
    except (OSError, ValueError, UnicodeError) as err:
        raise error(f"cannot read PLY ({err})", path) from err
    # Native-order fields stay views into the record array (no copy of a 5M-point cloud).
    return {
        name: data[name] if data[name].dtype.isnative else data[name].astype(data[name].dtype.newbyteorder("="))
        for name in data.dtype.names or ()
    }


def write_ply(path: Path, xyz: np.ndarray, floor: np.ndarray | None = None) -> None:
    """Binary PLY with float32 x y z and an optional int `floor`, written atomically."""
    fields: list[tuple[str, str]] = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if floor is not None:
        fields.append(("floor", "<i4"))
    data = np.empty(len(xyz), dtype=np.dtype(fields))
    data["x"], data["y"], data["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    if floor is not None:
        data["floor"] = floor
    ply_type = {"<f4": "float", "<i4": "int"}
    header = "ply\nformat binary_little_endian 1.0\n"
    header += f"element vertex {len(xyz)}\n"
    header += "".join(f"property {ply_type[code]} {name}\n" for name, code in fields)
    header += "end_header\n"
    with atomic_open(path, "wb") as f:
        f.write(header.encode("ascii"))
        data.tofile(f)


@dataclass(frozen=True)
class PointSet:
    """A cloud read for scoring: positions (float64 is not needed; float32 keeps memory small)."""

    xyz: npt.NDArray[np.float32]  # (N, 3)
    floor: I64 | None  # (N,) floor id per point, when the file has one


def read_cloud(path: Path, error: type[MfmapError] = GroundTruthError) -> PointSet:
    """A PLY (own reader, keeps a `floor` property) or PCD/other (open3d) point cloud."""
    if not path.is_file():
        raise error("file not found", path)
    if path.suffix.lower() == ".ply":
        props = read_ply(path, error)
        missing = [k for k in ("x", "y", "z") if k not in props]
        if missing:
            raise error(f"PLY vertices lack {', '.join(missing)}", path)
        xyz = np.stack([props["x"], props["y"], props["z"]], axis=1).astype(np.float32)
        floor = props["floor"].astype(np.int64) if "floor" in props else None
    else:
        import open3d as o3d

        pcd = o3d.t.io.read_point_cloud(path)
        if "positions" not in pcd.point or len(pcd.point.positions) == 0:
            raise error("no points could be read", path)
        xyz = pcd.point.positions.numpy().astype(np.float32)
        floor = pcd.point.floor.numpy().reshape(-1).astype(np.int64) if "floor" in pcd.point else None
    finite = np.isfinite(xyz).all(axis=1)
    if not finite.all():
        xyz = xyz[finite]
        floor = floor[finite] if floor is not None else None
    if len(xyz) == 0:
        raise error("the cloud has no points", path)
    return PointSet(np.ascontiguousarray(xyz), floor)


# ---------------------------------------------------------------------------------------- TUM


@dataclass(frozen=True)
class TumTrajectory:
    """Poses read from a TUM file: time in seconds, position, unit quaternion."""

    stamps_s: F64  # (N,) sorted
    xyz: F64  # (N, 3)
    quat_xyzw: F64  # (N, 4) unit


def read_tum(path: Path, error: type[MfmapError] = GroundTruthError) -> TumTrajectory:
    """A TUM file `t x y z qx qy qz qw` (spaces or commas, '#' comments), sorted by time."""
    if not path.is_file():
        raise error("file not found", path)
    rows: list[list[float]] = []
    for number, line in enumerate(read_text(path, error).splitlines(), start=1):
        text = line.split("#", 1)[0].replace(",", " ").strip()
        if not text:
            continue
        parts = text.split()
        if len(parts) != 8:
            raise error(f"line {number}: expected 8 values 't x y z qx qy qz qw', got {len(parts)}", path)
        try:
            rows.append([float(p) for p in parts])
        except ValueError as err:
            raise error(f"line {number}: not a number ({err})", path) from err
    if not rows:
        raise error("no poses in the trajectory", path)
    mat = np.asarray(rows, dtype=np.float64)
    if not np.isfinite(mat).all():
        raise error("non-finite value in the trajectory", path)
    norms = np.linalg.norm(mat[:, 4:8], axis=1)
    if (np.abs(norms - 1.0) > 1e-3).any():
        bad = int(np.argmax(np.abs(norms - 1.0)))
        raise error(f"pose {bad + 1}: quaternion is not unit length ({norms[bad]:.4f})", path)
    order = np.argsort(mat[:, 0], kind="stable")
    mat = mat[order]
    return TumTrajectory(mat[:, 0].copy(), mat[:, 1:4].copy(), mat[:, 4:8] / norms[order, None])


# ------------------------------------------------------------------------------------- points


@dataclass(frozen=True)
class GtPoint:
    label: str
    floor: int
    xyz: tuple[float, float, float]
    t_start_s: float
    t_end_s: float
    line: int


def read_points_csv(path: Path) -> list[GtPoint]:
    """Checkpoints CSV with header `label,floor,x,y,z,t_start,t_end`."""
    if not path.is_file():
        raise GroundTruthError("file not found", path)
    # utf-8-sig: a spreadsheet's byte-order mark must not rename the first column.
    text = read_text(path, GroundTruthError, encoding="utf-8-sig")
    with io.StringIO(text, newline="") as f:
        reader = csv.DictReader(f)
        header = [h.strip() for h in (reader.fieldnames or [])]
        missing = [c for c in POINTS_COLUMNS if c not in header]
        if missing:
            raise GroundTruthError(
                f"missing column(s) {', '.join(missing)}; expected header "
                f"{','.join(POINTS_COLUMNS)}, got {','.join(header) or '(empty)'}",
                path,
            )
        reader.fieldnames = header
        points: list[GtPoint] = []
        for row in reader:
            line = reader.line_num
            if not any((v or "").strip() for v in row.values() if isinstance(v, str)):
                continue
            try:
                floor_text = (row["floor"] or "").strip()
                floor = int(floor_text)
                values = [float((row[c] or "").strip()) for c in ("x", "y", "z", "t_start", "t_end")]
            except (ValueError, TypeError) as err:
                raise GroundTruthError(f"line {line}: bad value ({err})", path) from err
            if not all(math.isfinite(v) for v in values):
                raise GroundTruthError(f"line {line}: non-finite value", path)
            if values[4] < values[3]:
                raise GroundTruthError(f"line {line}: t_end is before t_start", path)
            label = (row["label"] or "").strip()
            if not label:
                raise GroundTruthError(f"line {line}: empty label", path)
            points.append(
                GtPoint(label, floor, (values[0], values[1], values[2]), values[3], values[4], line)
            )
    if not points:
        raise GroundTruthError("no points in the file", path)
    return points


# ------------------------------------------------------------------------------------- floors


@dataclass(frozen=True)
class FloorInfo:
    id: int
    elevation_m: float
    visits_s: tuple[tuple[float, float], ...]


@dataclass(frozen=True)
class TransitionInfo:
    kind: str
    from_id: int
    to_id: int
    t_start_s: float
    t_end_s: float
    xy_start: tuple[float, float] | None
    xy_end: tuple[float, float] | None


@dataclass(frozen=True)
class FloorsFile:
    floors: tuple[FloorInfo, ...]  # sorted by id
    transitions: tuple[TransitionInfo, ...]

    def elevation(self, floor_id: int) -> float:
        return next(f.elevation_m for f in self.floors if f.id == floor_id)

    @property
    def ids(self) -> list[int]:
        return [f.id for f in self.floors]


def read_floors_json(path: Path, error: type[MfmapError] = GroundTruthError) -> FloorsFile:
    """The shared floors.json schema (floors, transitions; connectors are not needed here)."""
    if not path.is_file():
        raise error("file not found", path)
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise error(f"not valid JSON ({err})", path) from err
    if not isinstance(data, dict) or not isinstance(data.get("floors"), list):
        raise error("expected an object with a 'floors' list", path)
    floors: list[FloorInfo] = []
    try:
        for i, item in enumerate(data["floors"]):
            for key in ("id", "elevation_m"):
                if key not in item:
                    raise error(f"floors[{i}] lacks '{key}'", path)
            visits = tuple((float(a), float(b)) for a, b in item.get("visits", []))
            floors.append(FloorInfo(int(item["id"]), float(item["elevation_m"]), visits))
        transitions: list[TransitionInfo] = []
        for i, item in enumerate(data.get("transitions", [])):
            for key in ("from", "to", "t_start", "t_end"):
                if key not in item:
                    raise error(f"transitions[{i}] lacks '{key}'", path)
            start = (float(item["x"]), float(item["y"])) if "x" in item and "y" in item else None
            end = (
                (float(item["x_end"]), float(item["y_end"]))
                if "x_end" in item and "y_end" in item
                else start
            )
            transitions.append(
                TransitionInfo(
                    str(item.get("kind", "unknown")),
                    int(item["from"]),
                    int(item["to"]),
                    float(item["t_start"]),
                    float(item["t_end"]),
                    start,
                    end,
                )
            )
    except (TypeError, ValueError) as err:
        raise error(f"bad value in floors file ({err})", path) from err
    if not floors:
        raise error("no floors in the file", path)
    ids = [f.id for f in floors]
    if len(set(ids)) != len(ids):
        raise error("duplicate floor id", path)
    for t in transitions:
        for fid in (t.from_id, t.to_id):
            if fid not in ids:
                raise error(f"transition refers to floor {fid}, which is not listed", path)
    floors.sort(key=lambda f: f.id)
    return FloorsFile(tuple(floors), tuple(transitions))


# -------------------------------------------------------------------------------------- build


def check_build(out_dir: Path, needed: list[str]) -> None:
    """Raise OutputError unless `out_dir` is a finished build holding the `needed` files."""
    if not out_dir.is_dir():
        raise OutputError("not a folder (expected a build's output folder)", out_dir)
    if (out_dir / INCOMPLETE_MARKER).exists():
        raise OutputError(f"interrupted build ({INCOMPLETE_MARKER} marker present); rebuild it", out_dir)
    if not (out_dir / "report.json").is_file():
        raise OutputError("report.json is missing: not a finished mfmap build (interrupted?)", out_dir)
    for name in needed:
        if not (out_dir / name).is_file():
            raise OutputError(f"{name} is missing: incomplete build", out_dir)


# ---------------------------------------------------------------------------------- writing


