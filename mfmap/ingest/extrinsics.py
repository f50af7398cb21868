"""Sensor extrinsics: the log's static transform tree, the config's additions, what is missing.

A sensor frame the transforms do not connect to the base cannot be guessed: placed at the base
with no rotation, a lidar mounted half a metre up and turned a degree gives a map with its floor
half a metre off and every wall turned. So a missing transform stops the build, naming the
frames and the two ways out (`ingest.extrinsics`, `--assume-identity-extrinsics`).

ROS 1 had no /tf_static before Hydro, and many bags still carry their static transforms on /tf,
republished by a static_transform_publisher: a parent-child pair whose transform on /tf never
changes is taken as static.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from mfmap.ingest.config import ExtrinsicConfig
from mfmap.types import F64

# A transform on /tf that moves less than this over the log is static.
STATIC_M = 1e-6
STATIC_RAD = 1e-6


@dataclass(frozen=True)
class Edge:
    parent: str
    child: str
    matrix: F64  # child's pose in the parent frame
    source: str  # "/tf_static", "/tf (constant)" or "config"


@dataclass
class TfPair:
    """One parent-child pair seen on /tf: its first transform and how far it ever moved."""

    first: F64
    count: int = 1
    moved_m: float = 0.0
    turned_rad: float = 0.0

    def add(self, matrix: F64) -> None:
        self.count += 1
        self.moved_m = max(self.moved_m, float(np.linalg.norm(matrix[:3, 3] - self.first[:3, 3])))
        cos = (float(np.trace(self.first[:3, :3].T @ matrix[:3, :3])) - 1.0) / 2.0
        self.turned_rad = max(self.turned_rad, math.acos(min(1.0, max(-1.0, cos))))

    @property
    def static(self) -> bool:
        return self.moved_m <= STATIC_M and self.turned_rad <= STATIC_RAD


@dataclass
class TfSeen:
    """What /tf held, kept small: an hour of 100 Hz odometry on /tf is one entry per pair."""

    pairs: dict[tuple[str, str], TfPair] = field(default_factory=dict)

    def add(self, parent: str, child: str, matrix: F64) -> None:
        pair = self.pairs.get((parent, child))
        if pair is None:
            self.pairs[(parent, child)] = TfPair(matrix.copy())
        else:
            pair.add(matrix)

    def static_edges(self) -> list[Edge]:
        return [Edge(p, c, pair.first, "/tf (constant)")
                for (p, c), pair in sorted(self.pairs.items()) if pair.static]

    def moving(self) -> list[Edge]:
        return [Edge(p, c, pair.first, "/tf (moving)")
                for (p, c), pair in sorted(self.pairs.items()) if not pair.static]


def matrix_of(spec: ExtrinsicConfig) -> F64:
    """ingest.extrinsics entry -> 4x4 pose of the frame in its parent (tf2's RPY: fixed axes)."""
    out = np.eye(4)
    out[:3, :3] = Rotation.from_euler("xyz", spec.rpy_deg, degrees=True).as_matrix()
    out[:3, 3] = spec.xyz
    return out


def config_edges(extrinsics: dict[str, ExtrinsicConfig]) -> list[Edge]:
    return [Edge(spec.parent.lstrip("/"), frame.lstrip("/"), matrix_of(spec), "config")
            for frame, spec in sorted(extrinsics.items())]


@dataclass(frozen=True)
class Tree:
    """Every frame the edges connect to the base: its pose in the base and where it came from."""

    poses: dict[str, F64]
    sources: dict[str, str]
    frames: tuple[str, ...]  # every frame the edges name


def connect(base: str, edges: list[Edge]) -> Tree:
    """Poses in `base` of the frames the edges reach (the tree walked both ways). A frame given
    by the config takes the config's parent, whatever the log says."""
    configured = {e.child for e in edges if e.source == "config"}
    kept = [e for e in edges if e.source == "config" or e.child not in configured]
    links: dict[str, list[tuple[str, F64, str]]] = {}
    for e in kept:
        links.setdefault(e.parent, []).append((e.child, e.matrix, e.source))
        links.setdefault(e.child, []).append((e.parent, np.asarray(np.linalg.inv(e.matrix), np.float64), e.source))
    poses: dict[str, F64] = {base: np.eye(4)}
    sources: dict[str, str] = {base: "base"}
    queue = deque([base])
    while queue:
        frame = queue.popleft()
        for other, t_frame_other, source in links.get(frame, []):
            if other not in poses:
                poses[other] = poses[frame] @ t_frame_other
                before = sources[frame]
                sources[other] = source if before in ("base", source) else f"{before} + {source}"
                queue.append(other)
    frames = tuple(sorted({e.parent for e in edges} | {e.child for e in edges}))
    return Tree(poses, sources, frames)


def missing_message(base: str, missing: dict[str, list[str]], tree: Tree, searched: str,
                    edges: list[Edge], moving: list[Edge]) -> str:
    """One line: the frames with no transform to the base, what was searched, the two ways out."""
    named = ", ".join(f"'{f}' ({', '.join(r)})" for f, r in missing.items())
    plural = len(missing) > 1
    known = [f for f in tree.frames if f != base]
    seen = f"frames there: {', '.join(known)}" if known else "no transforms there"
    if tree.frames and base not in tree.frames:
        seen += f"; none of them is '{base}' (set ingest.base_frame?)"
    # A frame that only a moving transform would reach (a sensor under odom, say).
    through = connect(base, [*edges, *moving])
    if moving and any(f in through.poses for f in missing):
        seen += f"; {', '.join(f'{e.parent}->{e.child}' for e in moving)} moves on /tf"
    example = next(iter(missing))
    return (
        f"no transform from '{base}' to frame{'s' if plural else ''} {named} in {searched} "
        f"({seen}): give {'them' if plural else 'it'} in the config as ingest.extrinsics "
        f"(e.g. {{{example}: {{parent: {base}, xyz: [x, y, z], rpy_deg: [roll, pitch, yaw]}}}}), "
        "or pass --assume-identity-extrinsics"
    )
