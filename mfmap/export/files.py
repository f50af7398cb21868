"""Atomic file writers: PLY clouds, TUM trajectories, JSON, YAML, raw bytes."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from mfmap.atomic import write_bytes_atomic as write_bytes
from mfmap.types import F64

__all__ = ["write_bytes"]


def write_text(path: Path, text: str) -> None:
    write_bytes(path, text.encode())


def write_json(path: Path, data: Any) -> None:
    write_text(path, json.dumps(data, indent=2) + "\n")


def write_yaml(path: Path, data: Any) -> None:
    write_text(path, yaml.safe_dump(data, sort_keys=False))


def ply_bytes(xyz: np.ndarray, floor: np.ndarray | None = None, rgb: np.ndarray | None = None) -> bytes:
    """Binary little-endian PLY: float32 x y z, plus int32 `floor` and uchar `red green blue`
    when given."""
    n = int(xyz.shape[0])
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if floor is not None:
        fields.append(("floor", "<i4"))
    if rgb is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    rec = np.empty(n, dtype=fields)
    rec["x"], rec["y"], rec["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    if floor is not None:
        rec["floor"] = floor
    if rgb is not None:
        rec["red"], rec["green"], rec["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {n}"]
    header += ["property float x", "property float y", "property float z"]
    if floor is not None:
        header.append("property int floor")
    if rgb is not None:
        header += ["property uchar red", "property uchar green", "property uchar blue"]
    header.append("end_header")
    return ("\n".join(header) + "\n").encode() + rec.tobytes()


def write_ply(path: Path, xyz: np.ndarray, floor: np.ndarray | None = None,
              rgb: np.ndarray | None = None) -> None:
    write_bytes(path, ply_bytes(xyz, floor, rgb))


def read_ply(path: Path) -> dict[str, np.ndarray]:
    """Read a binary little-endian or ASCII PLY's vertex properties (as written by mfmap/sim)."""
    raw = path.read_bytes()
    end = raw.index(b"end_header") + len(b"end_header")
    end = raw.index(b"\n", end) + 1
    header = raw[:end].decode().splitlines()
    types = {"float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8", "int": "<i4",
             "int32": "<i4", "uint": "<u4", "uint32": "<u4", "uchar": "u1", "uint8": "u1",
             "short": "<i2", "ushort": "<u2", "char": "i1", "int8": "i1"}
    fields: list[tuple[str, str]] = []
    n = 0
    in_vertex = False
    ascii_format = any(line.startswith("format ascii") for line in header)
    for line in header:
        parts = line.split()
        if parts[:2] == ["element", "vertex"]:
            n, in_vertex = int(parts[2]), True
        elif parts and parts[0] == "element":
            in_vertex = False
        elif parts and parts[0] == "property" and in_vertex:
            fields.append((parts[2], types[parts[1]]))
    if ascii_format:
        table = np.loadtxt(raw[end:].decode().splitlines()[:n], ndmin=2)
        return {name: table[:, k] for k, (name, _) in enumerate(fields)}
    rec = np.frombuffer(raw, dtype=np.dtype(fields), count=n, offset=end)
    return {name: np.asarray(rec[name]) for name, _ in fields}


def rotation_to_quat_xyzw(rot: F64) -> F64:
    """Unit quaternion (x, y, z, w) of a rotation matrix (Shepperd's method)."""
    m = rot
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s]
    quat = np.asarray(q, dtype=np.float64)
    quat /= np.linalg.norm(quat)
    return quat if quat[3] >= 0 else -quat


def tum_text(stamps_ns: np.ndarray, poses: np.ndarray) -> str:
    """TUM lines `t x y z qx qy qz qw` (t in epoch seconds)."""
    lines = []
    for stamp, pose in zip(stamps_ns, poses, strict=True):
        q = rotation_to_quat_xyzw(pose[:3, :3])
        t = pose[:3, 3]
        lines.append(
            f"{int(stamp) / 1e9:.9f} {t[0]:.6f} {t[1]:.6f} {t[2]:.6f} "
            f"{q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}"
        )
    return "\n".join(lines) + "\n"
