"""The robot's ground-truth motion: poses at 200 Hz (the IMU rate) with the events ground truth
needs: checkpoint windows, floor transitions, elevator door states and the cabin's height.

`mfmap.sim.route` builds it from motion primitives. A transition is one floor change as a visit
sees it: an elevator ride that stops on floors where the robot stays in the cabin, or a walk over
several flights, landings, pauses and floors passed through, is one transition from the floor
left to the floor reached.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from mfmap.types import F64

FArr = npt.NDArray[np.floating[Any]]

RATE_HZ = 200
DT_S = 1.0 / RATE_HZ


@dataclass(frozen=True)
class Checkpoint:
    label: str
    floor: int
    x: float
    y: float
    z: float
    t_start_s: float
    t_end_s: float


@dataclass(frozen=True)
class TransitionEvent:
    kind: str  # "elevator" | "stairs"
    from_floor: int
    to_floor: int
    t_start_s: float
    t_end_s: float
    x: float
    y: float
    x_end: float
    y_end: float
    height_change_m: float


@dataclass
class Trajectory:
    """Base pose at t = i * DT_S (seconds from the first lidar scan), world frame."""

    xyz: F64  # (N, 3)
    rpy: F64  # (N, 3) roll, pitch, yaw (yaw unwrapped)
    checkpoints: list[Checkpoint]
    transitions: list[TransitionEvent]
    door_open: list[tuple[float, float, int]]  # (t_open, t_close, floor) landing+cabin doors open
    cabin_z: list[tuple[float, float]]  # (t, z) knots of the cabin floor height, piecewise linear
    floor_visits: list[tuple[int, float, float]]  # (floor, t_start, t_end)

    @property
    def duration_s(self) -> float:
        return (len(self.xyz) - 1) * DT_S

    def interp(self, t_s: FArr) -> tuple[F64, F64]:
        """Positions (M, 3) and roll/pitch/yaw (M, 3) at arbitrary times (linear)."""
        f = np.clip(np.asarray(t_s, dtype=np.float64) / DT_S, 0, len(self.xyz) - 1)
        i0 = np.minimum(f.astype(np.int64), len(self.xyz) - 2)
        w = (f - i0)[:, None]
        xyz = self.xyz[i0] * (1 - w) + self.xyz[i0 + 1] * w
        rpy = self.rpy[i0] * (1 - w) + self.rpy[i0 + 1] * w
        return xyz, rpy

    def cabin_z_at(self, t_s: FArr) -> F64:
        ts, zs = zip(*self.cabin_z, strict=True)
        return np.interp(t_s, np.array(ts), np.array(zs))

    def door_open_at(self, t_s: float) -> int | None:
        for t0, t1, floor in self.door_open:
            if t0 <= t_s < t1:
                return floor
        return None


def rotation_matrices(rpy: F64) -> F64:
    """(M, 3, 3) rotations R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = rpy[:, 0], rpy[:, 1], rpy[:, 2]
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    m = np.empty((len(rpy), 3, 3))
    m[:, 0, 0] = cy * cp
    m[:, 0, 1] = cy * sp * sr - sy * cr
    m[:, 0, 2] = cy * sp * cr + sy * sr
    m[:, 1, 0] = sy * cp
    m[:, 1, 1] = sy * sp * sr + cy * cr
    m[:, 1, 2] = sy * sp * cr - cy * sr
    m[:, 2, 0] = -sp
    m[:, 2, 1] = cp * sr
    m[:, 2, 2] = cp * cr
    return m


def quaternions(rpy: F64) -> F64:
    """(M, 4) quaternions (x, y, z, w) of R = Rz(yaw) Ry(pitch) Rx(roll)."""
    hr, hp, hy = rpy[:, 0] / 2, rpy[:, 1] / 2, rpy[:, 2] / 2
    cr, sr, cp, sp, cy, sy = np.cos(hr), np.sin(hr), np.cos(hp), np.sin(hp), np.cos(hy), np.sin(hy)
    q = np.stack(
        [
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy,
        ],
        axis=1,
    )
    return q
