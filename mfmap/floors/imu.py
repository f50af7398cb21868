"""When a transition starts and ends, from the IMU: a cabin's vertical acceleration, a flight's tilt.

The barometer finds a transition and its floors, but not its ends to the second: a closed
cabin's air follows its height with a lag, and the doors opening at the end mix in the floor's
air (a pressure transient right where the ride ends); a stairwell holds its own pressure, so
crossing its door on the way to the first step moves the barometer by decimetres before any
step is climbed. The accelerometer knows better:

- a ride is the span between the first and the last vertical acceleration of the cabin near the
  barometer's, stops with the robot in the cabin included;
- a stair walk is the span between the first and the last flight, a flight being where the
  robot is tilted by the stairs' slope (20-40 degrees; a robot driving on a level floor tilts by
  a degree or two).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from mfmap.types import F64, I64, ImuSeries

# Smoothing of the vertical specific force (s): the cabin's acceleration lasts a second or more,
# a robot's vibration much less.
SMOOTH_S = 0.2
# A cabin accelerates at 0.3-1.2 m/s^2; driving on a level floor moves the vertical force far less.
MOTION_M_S2 = 0.2
# The ride's ends are where the smoothed force falls back into the stand-still's noise (this
# many of its sigmas, and at least QUIET_MIN_M_S2).
QUIET_SIGMAS = 4.0
QUIET_MIN_M_S2 = 0.03
# The IMU's span must lie within this much of the barometer's (s) and cover this share of it:
# else it is not the same ride (a bump, a missing stretch of samples) and the barometer's stays.
SEARCH_S = 2.5
MIN_COVER = 0.5
# A cabin's acceleration is held for a second or so; a bump (a door sill under a wheel) is not.
MIN_PUSH_S = 0.3


# A flight tilts the robot by more than this (deg) for at least FLIGHT_S (s); the specific
# force is averaged over TILT_SMOOTH_S so that a step's jolt is not a tilt.
FLIGHT_TILT_DEG = 10.0
FLIGHT_S = 1.0
TILT_SMOOTH_S = 0.5
# The flights are looked for this far outside the barometer's stair walk (s).
FLIGHT_SEARCH_S = 5.0
# A walk starts at the foot of the first flight, a moment before the robot tilts on it, and ends
# a moment after the last (s).
FLIGHT_PAD_S = 1.0


@dataclass(frozen=True)
class ImuTiming:
    """The IMU's smoothed specific force along up minus its median (gravity and bias), and the
    robot's tilt from its usual attitude."""

    stamp_ns: I64
    accel_m_s2: F64
    quiet_m_s2: float  # below this the cabin is at rest
    dt_s: float
    tilt_deg: F64

    @classmethod
    def of(cls, imu: ImuSeries | None) -> ImuTiming | None:
        """From an IMU at any mounting (up is the median specific force); None without one."""
        if imu is None or len(imu) < 50:
            return None
        t = np.asarray(imu.stamp_ns, dtype=np.int64)
        dt_s = float(np.median(np.diff(t))) / 1e9
        acc = np.asarray(imu.accel_m_s2, dtype=np.float64)
        up = np.median(acc, axis=0)
        norm = float(np.linalg.norm(up))
        if not dt_s > 0 or norm < 1.0:
            return None
        n = max(1, round(SMOOTH_S / dt_s))
        f_up = ndimage.uniform_filter1d(acc @ (up / norm), size=n, mode="nearest")
        a = f_up - float(np.median(f_up))
        # The noise of the smoothed force where the robot is not moving vertically: the spread
        # of most samples (rides are a small share of a log).
        sigma = 1.4826 * float(np.median(np.abs(a)))
        mean = ndimage.uniform_filter1d(acc, size=max(1, round(TILT_SMOOTH_S / dt_s)), axis=0, mode="nearest")
        cos = (mean @ (up / norm)) / np.maximum(np.linalg.norm(mean, axis=1), 1e-9)
        tilt = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        return cls(t, a, max(QUIET_SIGMAS * sigma, QUIET_MIN_M_S2), dt_s, tilt)

    def ride_span(self, start_ns: int, end_ns: int) -> tuple[int, int] | None:
        """The cabin's motion (first to last sample out of rest) for a ride the barometer puts at
        [start_ns, end_ns]; None when the accelerometer shows no ride there."""
        pad = int(SEARCH_S * 1e9)
        lo, hi = np.searchsorted(self.stamp_ns, [start_ns - pad, end_ns + pad])
        a = np.abs(self.accel_m_s2[lo:hi])
        push = np.ones(max(1, round(MIN_PUSH_S / self.dt_s)), dtype=bool)
        moving = np.flatnonzero(ndimage.binary_opening(a > MOTION_M_S2, push))
        if moving.shape[0] == 0:
            return None
        i, j = int(moving[0]), int(moving[-1])
        # Out to where the force is back at rest: the ride starts and ends smoothly.
        quiet = np.flatnonzero(a <= self.quiet_m_s2)
        before, after = quiet[quiet < i], quiet[quiet > j]
        i = int(before[-1]) + 1 if before.shape[0] else i
        j = int(after[0]) - 1 if after.shape[0] else j
        # The smoothing spread the force by half its window either way.
        half = int(0.5 * SMOOTH_S * 1e9)
        t0, t1 = int(self.stamp_ns[lo + i]) + half, int(self.stamp_ns[lo + j]) - half
        overlap = min(t1, end_ns) - max(t0, start_ns)
        if overlap < MIN_COVER * (end_ns - start_ns):
            return None
        return t0, t1

    def flight_span(self, start_ns: int, end_ns: int) -> tuple[int, int] | None:
        """From the first flight's start to the last flight's end of a stair walk the barometer
        puts at [start_ns, end_ns]; None when the IMU shows no flight there (a robot that does
        not tilt on stairs, a person's phone)."""
        pad = int(FLIGHT_SEARCH_S * 1e9)
        lo, hi = np.searchsorted(self.stamp_ns, [start_ns - pad, end_ns + pad])
        hold = np.ones(max(1, round(FLIGHT_S / self.dt_s)), dtype=bool)
        flights = np.flatnonzero(ndimage.binary_opening(self.tilt_deg[lo:hi] > FLIGHT_TILT_DEG, hold))
        if flights.shape[0] == 0:
            return None
        t0 = int(self.stamp_ns[lo + int(flights[0])]) - int(FLIGHT_PAD_S * 1e9)
        t1 = int(self.stamp_ns[lo + int(flights[-1])]) + int(FLIGHT_PAD_S * 1e9)
        if min(t1, end_ns) - max(t0, start_ns) < MIN_COVER * (end_ns - start_ns):
            return None
        return t0, t1
