"""Barometer traces with known floors, for the floors stage's tests and benchmarks.

Only the barometer (`simulate` writes whole logs): a height profile of stays, elevator rides and
stair climbs, turned into pressure with the simulator's own air column, plus white noise,
quantisation, linear weather drift, door/HVAC steps and single-sample spikes; and a scenario's
barometer exactly as `simulate` logs it, without rendering any lidar.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from mfmap.sim.atmosphere import CALM_AIR
from mfmap.types import F64, I32, OdomSeries, PressureSeries

if TYPE_CHECKING:
    from mfmap.sim.world import WorldSpec


ELEVATOR_SPEED_M_S = 1.0
ELEVATOR_ACCEL_M_S2 = 0.5


@dataclass(frozen=True)
class Leg:
    """One piece of a walk: a stay (height_change_m == 0), an elevator ride or a stair climb."""

    kind: str  # "stay" | "elevator" | "stairs"
    duration_s: float = 0.0  # stays; stairs derive it from speed
    height_change_m: float = 0.0
    speed_m_s: float = 0.3  # stairs' vertical speed


@dataclass(frozen=True)
class TruthTransition:
    kind: str
    start_s: float
    end_s: float
    from_level: int
    to_level: int
    height_change_m: float


@dataclass
class SyntheticTrace:
    pressure: PressureSeries
    times_s: F64  # seconds since the start
    height_m: F64  # true height above the start floor
    level_of_sample: I32  # index into `elevations`, -1 while moving
    elevations: list[float]
    transitions: list[TruthTransition] = field(default_factory=list)


def _elevator_profile(t_s: F64, height_m: float) -> F64:
    """Trapezoidal speed profile (or triangular for short rides) from 0 to height_m."""
    d = abs(height_m)
    t_acc = ELEVATOR_SPEED_M_S / ELEVATOR_ACCEL_M_S2
    if d < ELEVATOR_SPEED_M_S * t_acc:  # never reaches full speed
        t_acc = float(np.sqrt(d / ELEVATOR_ACCEL_M_S2))
        cruise = 0.0
    else:
        cruise = (d - ELEVATOR_SPEED_M_S * t_acc) / ELEVATOR_SPEED_M_S
    v_max = ELEVATOR_ACCEL_M_S2 * t_acc
    t_total = 2 * t_acc + cruise
    t = np.clip(t_s, 0.0, t_total)
    up = 0.5 * ELEVATOR_ACCEL_M_S2 * np.minimum(t, t_acc) ** 2
    mid = v_max * np.clip(t - t_acc, 0.0, cruise)
    down_t = np.clip(t - t_acc - cruise, 0.0, t_acc)
    down = v_max * down_t - 0.5 * ELEVATOR_ACCEL_M_S2 * down_t**2
    return np.asarray(np.sign(height_m) * (up + mid + down), dtype=np.float64)


def elevator_duration_s(height_m: float) -> float:
    d = abs(height_m)
    t_acc = ELEVATOR_SPEED_M_S / ELEVATOR_ACCEL_M_S2
    if d < ELEVATOR_SPEED_M_S * t_acc:
        return 2 * float(np.sqrt(d / ELEVATOR_ACCEL_M_S2))
    return 2 * t_acc + (d - ELEVATOR_SPEED_M_S * t_acc) / ELEVATOR_SPEED_M_S


def synthetic_trace(
    legs: list[Leg],
    rate_hz: float = 25.0,
    noise_pa: float = 3.0,
    quantum_pa: float = 0.5,
    drift_pa_per_h: float = 0.0,
    transients: int = 0,
    transient_pa: tuple[float, float] = (5.0, 15.0),
    transient_s: tuple[float, float] = (1.0, 6.0),
    spikes: int = 0,
    start_pressure_pa: float = 101_300.0,
    start_ns: int = 1_700_000_000_000_000_000,
    seed: int = 0,
) -> SyntheticTrace:
    """A barometer trace of the walk `legs` and its truth.

    Transients are abrupt pressure steps (a door, the HVAC) that last a few seconds; they are
    placed on stays, at least 2 s away from motion, because that is where they are physical.
    """
    rng = np.random.default_rng(seed)
    spans, total_s = _leg_spans(legs)
    n = int(np.floor(total_s * rate_hz)) + 1
    t_s = np.arange(n, dtype=np.float64) / rate_hz
    height, level, elevations, truth = _walk(spans, t_s, total_s)

    pressure = CALM_AIR.pressure_pa(height, start_pressure_pa)
    pressure = pressure + drift_pa_per_h * t_s / 3600.0
    pressure = pressure + rng.normal(0.0, noise_pa, n)
    still = np.flatnonzero(level >= 0)
    for _ in range(transients):
        dur = rng.uniform(*transient_s)
        amp = rng.uniform(*transient_pa) * rng.choice([-1.0, 1.0])
        for _attempt in range(50):
            i0 = int(rng.choice(still))
            window = (t_s >= t_s[i0] - 2.0) & (t_s <= t_s[i0] + dur + 2.0)
            if np.all(level[window] >= 0):
                pressure[(t_s >= t_s[i0]) & (t_s < t_s[i0] + dur)] += amp
                break
    if spikes:
        idx = rng.choice(n, size=spikes, replace=False)
        pressure[idx] += rng.uniform(30.0, 200.0, spikes) * rng.choice([-1.0, 1.0], spikes)
    if quantum_pa > 0:
        pressure = np.round(pressure / quantum_pa) * quantum_pa
    stamp_ns = start_ns + np.round(t_s * 1e9).astype(np.int64)
    return SyntheticTrace(
        pressure=PressureSeries(stamp_ns=stamp_ns, pressure_pa=pressure, frame_id="baro"),
        times_s=t_s,
        height_m=height,
        level_of_sample=level,
        elevations=elevations,
        transitions=truth,
    )


def _leg_spans(legs: list[Leg]) -> tuple[list[tuple[Leg, float, float]], float]:
    """Each leg with its start and end time, and the walk's duration."""
    total_s = 0.0
    spans: list[tuple[Leg, float, float]] = []
    for leg in legs:
        if leg.kind == "stay":
            dur = leg.duration_s
        elif leg.kind == "elevator":
            dur = elevator_duration_s(leg.height_change_m)
        else:
            dur = abs(leg.height_change_m) / leg.speed_m_s
        spans.append((leg, total_s, total_s + dur))
        total_s += dur
    return spans, total_s


def _walk(
    spans: list[tuple[Leg, float, float]], t_s: F64, total_s: float
) -> tuple[F64, I32, list[float], list[TruthTransition]]:
    """Height and level (-1 while moving) at each sample time, the levels' elevations in order
    of first visit, and the true transitions."""
    n = t_s.shape[0]
    height = np.zeros(n)
    level = np.full(n, -1, dtype=np.int32)
    elevations = [0.0]
    cur_h = 0.0
    cur_level = 0
    truth: list[TruthTransition] = []
    for leg, t0, t1 in spans:
        inside = (t_s >= t0) & (t_s < t1) if t1 < total_s else (t_s >= t0)
        if leg.kind == "stay":
            height[inside] = cur_h
            level[inside] = cur_level
            continue
        rel = t_s[inside] - t0
        if leg.kind == "elevator":
            height[inside] = cur_h + _elevator_profile(rel, leg.height_change_m)
        else:
            height[inside] = cur_h + np.sign(leg.height_change_m) * leg.speed_m_s * rel
        new_h = cur_h + leg.height_change_m
        match = [i for i, e in enumerate(elevations) if abs(e - new_h) < 0.05]
        if match:
            new_level = match[0]
        else:
            elevations.append(new_h)
            new_level = len(elevations) - 1
        truth.append(TruthTransition(leg.kind, t0, t1, cur_level, new_level, leg.height_change_m))
        cur_h, cur_level = new_h, new_level
    return height, level, elevations, truth


def building_walk(floor_height_m: float = 4.0, kind: str = "elevator", stay_s: float = 40.0) -> list[Leg]:
    """0 -> +1 -> +2 -> +1 -> 0 -> -1 -> 0: revisits, a basement, both directions."""
    def move(dh: float) -> Leg:
        return Leg(kind, height_change_m=dh, speed_m_s=0.35)

    stay = Leg("stay", stay_s)
    fh = floor_height_m
    return [stay, move(fh), stay, move(fh), stay, move(-fh), stay, move(-fh), stay, move(-fh), stay, move(fh), stay]


@dataclass
class SimBarometer:
    """The simulator's barometer and motion for one scenario, without rendering any lidar."""

    pressure: PressureSeries
    odometry: OdomSeries
    gt_floors: dict[str, Any]  # the scenario's gt_floors.json document


def sim_barometer(scenario: str, seed: int = 0, world: WorldSpec | None = None) -> SimBarometer:
    """Barometer samples exactly as `mfmap simulate` models them (same trajectory, drift,
    transients, noise and rate), odometry twist from the true motion, and gt_floors.json.

    Seconds instead of the minutes a full simulated log with lidar takes, so the floors tests
    can cover every scenario. `world` replaces the scenario's (e.g. WorldSpec.harsh()).
    """
    from mfmap.sim import groundtruth
    from mfmap.sim.run import build_trajectory, make_barometer, start_stamp_ns
    from mfmap.sim.scenarios import SCENARIOS, building_for
    from mfmap.sim.trajectory import DT_S, RATE_HZ

    spec = SCENARIOS[scenario]
    if world is not None:
        spec = dataclasses.replace(spec, world=world)
    building = building_for(spec, seed)
    traj = build_trajectory(spec, building, seed, 1)
    start_ns = start_stamp_ns(seed)
    baro = make_barometer(spec, building, traj, seed)
    rate = spec.baro.rate_hz
    ks = np.arange(round(traj.duration_s) * rate)
    # One draw per second of samples, as the log writer makes them: the same values as the log.
    ticks = ks * (RATE_HZ // rate)
    pressure_pa = np.concatenate([baro.samples(ticks[i : i + rate]) for i in range(0, ticks.shape[0], rate)])
    stamp_ns = start_ns + (ks * 1_000_000_000) // rate
    # Odometry at 50 Hz: body-frame forward speed and yaw rate of the true motion.
    idx = np.arange(0, len(traj.xyz), RATE_HZ // 50)
    speed = np.linalg.norm(np.gradient(traj.xyz[:, :2], axis=0), axis=1) / DT_S
    yaw_rate = np.gradient(traj.rpy[:, 2]) / DT_S
    n = idx.shape[0]
    linear = np.zeros((n, 3))
    linear[:, 0] = speed[idx]
    angular = np.zeros((n, 3))
    angular[:, 2] = yaw_rate[idx]
    quat = np.zeros((n, 4))
    quat[:, 3] = 1.0
    odom = OdomSeries(
        stamp_ns=start_ns + np.round(idx * DT_S * 1e9).astype(np.int64),
        xyz=traj.xyz[idx].copy(),
        quat_xyzw=quat,
        linear_m_s=linear,
        angular_rad_s=angular,
        frame_id="odom",
        child_frame_id="base_link",
    )
    doc = groundtruth.floors_document(spec, building, traj, baro, start_ns, seed)
    return SimBarometer(PressureSeries(stamp_ns, pressure_pa, "baro"), odom, doc)
