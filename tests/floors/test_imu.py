"""Transition times from the IMU (mfmap.floors.imu): a cabin's acceleration, a flight's tilt."""

from __future__ import annotations

import math

import numpy as np

from mfmap.floors.imu import ImuTiming
from mfmap.types import ImuSeries

RATE_HZ = 200.0
G = 9.81


def _imu(t_s: np.ndarray, accel_up: np.ndarray, pitch_deg: np.ndarray, seed: int = 0) -> ImuSeries:
    """An IMU mounted level on the robot: specific force from the cabin's vertical acceleration
    and the robot's pitch, with white noise of 0.05 m/s^2 (a cheap MEMS part at 200 Hz)."""
    rng = np.random.default_rng(seed)
    pitch = np.radians(pitch_deg)
    f = (G + accel_up)[:, None] * np.stack([-np.sin(pitch), np.zeros_like(pitch), np.cos(pitch)], axis=1)
    f += rng.normal(0.0, 0.05, f.shape)
    n = t_s.shape[0]
    return ImuSeries((t_s * 1e9).astype(np.int64), rng.normal(0.0, 0.002, (n, 3)), f, np.full((n, 4), np.nan))


def _ride(t_s: np.ndarray, start_s: float, height_m: float, acc: float = 0.6, v_max: float = 1.0) -> np.ndarray:
    """Vertical acceleration of a rest-to-rest ride (trapezoidal speed) starting at start_s."""
    t_acc = v_max / acc
    cruise = abs(height_m) / v_max - t_acc
    sign = math.copysign(1.0, height_m)
    a = np.zeros_like(t_s)
    a[(t_s >= start_s) & (t_s < start_s + t_acc)] = sign * acc
    stop = start_s + t_acc + cruise
    a[(t_s >= stop) & (t_s < stop + t_acc)] = -sign * acc
    return a


def test_a_ride_is_timed_by_the_cabin_not_by_the_lagging_barometer() -> None:
    t = np.arange(0.0, 60.0, 1.0 / RATE_HZ)
    a = _ride(t, 20.0, 8.0)  # 1.67 s accelerating, 6.33 s cruising: ends at 29.67 s
    # A bump of a door sill under a wheel before the ride: short, so not a ride.
    a[(t >= 16.0) & (t < 16.08)] += 3.0
    timing = ImuTiming.of(_imu(t, a, np.zeros_like(t)))
    assert timing is not None
    # The barometer's span, a second late at both ends (the closed cabin's air lags).
    span = timing.ride_span(int(21.0e9), int(31.0e9))
    assert span is not None
    assert abs(span[0] / 1e9 - 20.0) < 0.15
    assert abs(span[1] / 1e9 - (20.0 + 8.0 / 1.0 + 1.0 / 0.6)) < 0.15


def test_a_ride_with_a_stop_in_the_cabin_is_one_span() -> None:
    t = np.arange(0.0, 80.0, 1.0 / RATE_HZ)
    a = _ride(t, 20.0, 4.0) + _ride(t, 36.0, 4.0)
    timing = ImuTiming.of(_imu(t, a, np.zeros_like(t), seed=1))
    assert timing is not None
    span = timing.ride_span(int(20.5e9), int(43.0e9))
    assert span is not None
    assert abs(span[0] / 1e9 - 20.0) < 0.15 and abs(span[1] / 1e9 - (36.0 + 4.0 + 1.0 / 0.6)) < 0.15


def test_no_cabin_motion_keeps_the_barometers_span() -> None:
    t = np.arange(0.0, 60.0, 1.0 / RATE_HZ)
    timing = ImuTiming.of(_imu(t, np.zeros_like(t), np.zeros_like(t), seed=2))
    assert timing is not None
    assert timing.ride_span(int(20e9), int(30e9)) is None
    assert timing.flight_span(int(20e9), int(30e9)) is None


def test_a_stair_walk_is_timed_by_its_flights_not_by_the_stairwell_door() -> None:
    # Two flights tilted 25 degrees with a level landing between; the barometer puts the walk's
    # start 15 s early (the stairwell's own pressure from its door on).
    t = np.arange(0.0, 120.0, 1.0 / RATE_HZ)
    pitch = np.zeros_like(t)
    pitch[(t >= 40.0) & (t < 52.0)] = 25.0
    pitch[(t >= 60.0) & (t < 72.0)] = 25.0
    # Turning and stepping: a few degrees of apparent tilt for short moments.
    pitch[(t >= 30.0) & (t < 30.4)] = 15.0
    timing = ImuTiming.of(_imu(t, np.zeros_like(t), pitch, seed=3))
    assert timing is not None
    span = timing.flight_span(int(25e9), int(73e9))
    assert span is not None
    assert abs(span[0] / 1e9 - 39.0) < 0.4 and abs(span[1] / 1e9 - 73.0) < 0.4


def test_no_imu_or_too_few_samples_gives_no_timing() -> None:
    assert ImuTiming.of(None) is None
    t = np.arange(0.0, 0.1, 1.0 / RATE_HZ)
    assert ImuTiming.of(_imu(t, np.zeros_like(t), np.zeros_like(t))) is None
