"""Stand-stills and turns in place, told by the wheels and the gyro, not by the lidar."""

from __future__ import annotations

import copy
import math

import numpy as np

from mfmap.mapping.config import MappingConfig
from mfmap.mapping.geometry import rotation_angle_rad
from mfmap.mapping.motion import MotionModel
from mfmap.types import F64

# Below these since the last registered scan (wheels, gyro), the robot stands still
# (`standstill_hold_s`): a few times the gyro's drift over the hold, far below any motion.
STILL_M = 0.005
STILL_RAD = math.radians(0.05)
TURN_MIN_RAD = math.radians(1.0)


class StandStill:
    """The last registered scan, and the stand-still registrations since the robot stopped."""

    def __init__(self, cfg: MappingConfig, motion: MotionModel) -> None:
        self.cfg = cfg
        self.motion = motion
        self.registered: tuple[int, F64] | None = None  # stamp and pose of the last registered scan
        self._still: list[tuple[int, F64]] = []  # stamps and x, y of stand-still registrations

    def clear(self) -> None:
        """A new visit: no stand-still carries over."""
        self._still.clear()

    def fork(self) -> StandStill:
        """A copy whose stand-stills from here on are its own."""
        twin = copy.copy(self)
        twin._still = list(self._still)
        return twin

    def _wheel_distance(self, from_ns: int, to_ns: int) -> float | None:
        """How far the wheels say the robot moved between the stamps (None without them)."""
        wheels = self.motion.wheels(from_ns, to_ns)
        return None if wheels is None else float(np.linalg.norm(wheels[:3, 3]))

    def _gyro_turn(self, from_ns: int, to_ns: int) -> float | None:
        """How far the gyro says the robot turned between the stamps (rad; None without it)."""
        gyro = self.motion.gyro
        if gyro is None or not self.motion.rotation_from_gyro(from_ns, to_ns):
            return None
        return rotation_angle_rad(gyro.delta(from_ns, to_ns))

    def in_place(self, stamp_ns: int, pose: F64) -> F64 | None:
        """The x, y to hold a registration at while the robot turns in place, else None.

        Each registration made while the wheels have moved less than `turn_hold_m` since the
        robot stopped, and the gyro has turned less than TURN_MIN_RAD since the last one, is a
        stand-still: its x, y is kept. A registration that turned more takes the median of
        those instead, so one poorly deskewed scan as the turn starts does not set the spot.
        """
        if self.registered is None or self.cfg.motion.turn_hold_m <= 0:
            return None
        since_ns, since_pose = self.registered
        moved = self._wheel_distance(self._still[0][0] if self._still else since_ns, stamp_ns)
        turn = None if moved is None or moved >= self.cfg.motion.turn_hold_m else self._gyro_turn(
            since_ns, stamp_ns)
        if turn is None:
            self._still.clear()
            return None
        if turn <= TURN_MIN_RAD:
            self._still.append((stamp_ns, pose[:2, 3].copy()))
            return None
        if not self._still:
            self._still.append((since_ns, since_pose[:2, 3].copy()))
        return np.median(np.array([xy for _, xy in self._still]), axis=0)

    def standing_still(self, stamp_ns: int) -> bool:
        """Whether the wheels and the gyro say the robot has not moved since the last registered
        scan, and that was less than `standstill_hold_s` ago: then the scan needs no registration.

        Without wheel odometry (or a gyro) nothing independent of the lidar says so, and every
        scan is registered. False until a scan has been registered.
        """
        if self.registered is None or self.cfg.motion.standstill_hold_s <= 0:
            return False
        since_ns, _ = self.registered
        if stamp_ns - since_ns > self.cfg.motion.standstill_hold_s * 1e9:
            return False
        moved = self._wheel_distance(since_ns, stamp_ns)
        turn = self._gyro_turn(since_ns, stamp_ns)
        return moved is not None and turn is not None and moved < STILL_M and turn < STILL_RAD
