"""Build folders and ground-truth files written in tmp_path, shaped like DESIGN.md's OUT/."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from mfmap.eval.io import write_ply

T0_S = 1_700_000_000.0


def write_tum(path: Path, stamps_s: np.ndarray, xyz: np.ndarray, quat_xyzw: np.ndarray) -> Path:
    lines = [
        " ".join(f"{v:.9f}" for v in (t, *p, *q))
        for t, p, q in zip(stamps_s, xyz, quat_xyzw, strict=True)
    ]
    path.write_text("# t x y z qx qy qz qw\n" + "\n".join(lines) + "\n")
    return path


def yaw_quat(yaw_rad: np.ndarray) -> np.ndarray:
    yaw_rad = np.asarray(yaw_rad, dtype=np.float64)
    return np.stack(
        [np.zeros_like(yaw_rad), np.zeros_like(yaw_rad), np.sin(yaw_rad / 2), np.cos(yaw_rad / 2)],
        axis=1,
    )


def floors_doc(
    elevations_m: list[float],
    visits: dict[int, list[tuple[float, float]]],
    transitions: list[dict[str, Any]],
) -> dict[str, Any]:
    return {
        "floors": [
            {"id": i, "elevation_m": e, "pressure_pa": 101300.0 - 12.0 * e, "visits": visits.get(i, [])}
            for i, e in enumerate(elevations_m)
        ],
        "transitions": transitions,
        "connectors": [],
    }


@pytest.fixture
def make_build(tmp_path: Path) -> Callable[..., Path]:
    """make_build(name, trajectory=(t, xyz, q), floors=dict, cloud=(xyz, floor)) -> OUT folder."""

    def make(
        name: str = "build",
        trajectory: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
        floors: dict[str, Any] | None = None,
        cloud: tuple[np.ndarray, np.ndarray | None] | None = None,
    ) -> Path:
        out = tmp_path / name
        out.mkdir()
        (out / "report.json").write_text(json.dumps({"counts": {}, "warnings": []}))
        (out / "config.yaml").write_text("{}\n")
        if trajectory is not None:
            write_tum(out / "trajectory.tum", *trajectory)
        if floors is not None:
            (out / "floors.json").write_text(json.dumps(floors))
        if cloud is not None:
            write_ply(out / "map.ply", cloud[0], cloud[1])
        return out

    return make


@pytest.fixture
def h() -> SimpleNamespace:
    """The helpers above (test files cannot import conftest under --import-mode=importlib)."""
    return SimpleNamespace(write_tum=write_tum, yaw_quat=yaw_quat, floors_doc=floors_doc, T0_S=T0_S)
