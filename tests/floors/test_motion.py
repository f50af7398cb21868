"""Motion evidence that tells an elevator ride (standing still) from stairs (moving)."""

from __future__ import annotations

import numpy as np

from mfmap.floors.config import FloorsConfig
from mfmap.floors.motion import motion_from_imu, motion_from_odometry
from mfmap.floors.segment import segment_pressure
from mfmap.sim.traces import Leg, synthetic_trace
from mfmap.types import ImuSeries, OdomSeries, TransitionKind

START_NS = 1_700_000_000_000_000_000


def _odometry(speed_m_s: np.ndarray, rate_hz: float = 50.0) -> OdomSeries:
    n = speed_m_s.shape[0]
    linear = np.zeros((n, 3))
    linear[:, 0] = speed_m_s
    quat = np.zeros((n, 4))
    quat[:, 3] = 1.0
    stamps = START_NS + np.round(np.arange(n) / rate_hz * 1e9).astype(np.int64)
    return OdomSeries(stamps, np.zeros((n, 3)), quat, linear, np.zeros((n, 3)))


def test_odometry_evidence_and_standstills() -> None:
    t = np.arange(0, 60.0, 0.02)
    speed = np.where((t > 20.0) & (t < 40.0), 0.35, 0.0)
    motion = motion_from_odometry(_odometry(speed), FloorsConfig())
    assert motion.fraction_moving(START_NS + 25 * 10**9, START_NS + 35 * 10**9) == 1.0
    assert motion.fraction_moving(START_NS + 2 * 10**9, START_NS + 18 * 10**9) == 0.0
    assert motion.fraction_moving(START_NS + 100 * 10**9, START_NS + 110 * 10**9) is None
    still = motion.standstill_near(START_NS + 21 * 10**9, 3 * 10**9, 0.05, before=True)
    assert still is not None and abs((still - START_NS) / 1e9 - 20.0) < 0.15


def test_imu_evidence_from_horizontal_acceleration() -> None:
    rng = np.random.default_rng(0)
    t = np.arange(0, 60.0, 0.005)
    n = t.shape[0]
    accel = np.zeros((n, 3))
    accel[:, 2] = 9.81 + np.where((t > 10) & (t < 15), 0.5, 0.0)  # a cabin accelerating up
    walking = (t > 30.0) & (t < 50.0)
    accel[:, 0] = rng.normal(0.0, 0.02, n) + walking * 1.2 * np.sin(2 * np.pi * 1.8 * t)
    imu = ImuSeries(
        START_NS + np.round(t * 1e9).astype(np.int64), np.zeros((n, 3)), accel, np.full((n, 4), np.nan)
    )
    motion = motion_from_imu(imu, FloorsConfig())
    assert motion.fraction_moving(START_NS + 9 * 10**9, START_NS + 16 * 10**9) == 0.0
    assert motion.fraction_moving(START_NS + 32 * 10**9, START_NS + 48 * 10**9) == 1.0


def test_kinds_and_stairs_ends_from_odometry() -> None:
    legs = [
        Leg("stay", 40.0),
        Leg("elevator", height_change_m=4.0),
        Leg("stay", 40.0),
        Leg("stairs", height_change_m=-4.0, speed_m_s=0.25),
        Leg("stay", 40.0),
    ]
    trace = synthetic_trace(legs, rate_hz=25.0, seed=3)
    t = np.arange(0, trace.times_s[-1], 0.02)
    stairs = trace.transitions[1]
    speed = np.where((t >= stairs.start_s) & (t <= stairs.end_s), 0.4, 0.0)
    motion = motion_from_odometry(_odometry(speed), FloorsConfig())
    # The synthetic trace starts at the same epoch as the odometry.
    assert int(trace.pressure.stamp_ns[0]) == START_NS
    seg = segment_pressure(trace.pressure, motion, FloorsConfig())
    assert [tr.kind for tr in seg.transitions] == [TransitionKind.ELEVATOR, TransitionKind.STAIRS]
    got = seg.transitions[1]
    assert abs((got.start_ns - START_NS) / 1e9 - stairs.start_s) < 0.5
    assert abs((got.end_ns - START_NS) / 1e9 - stairs.end_s) < 0.5
