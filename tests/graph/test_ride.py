"""An elevator ride's height change from the IMU (mfmap/graph/ride.py), alone and in the graph."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from mfmap.config import MfmapConfig
from mfmap.graph.config import AblationConfig, GraphConfig
from mfmap.graph.optimize import optimize_building
from mfmap.graph.ride import SIGMA_FLOOR_M, ride_height
from mfmap.ingest import open_log
from mfmap.pipeline import segment_floors
from mfmap.types import F64, ImuSeries, PressureSeries
from tests.graph.synthetic import START_NS, make_building, ride_imu

RIDE_NS = (START_NS, START_NS + 15 * 10**9)


def test_tiny_scenario_ride_within_2cm_of_truth(sim_run: Any) -> None:
    """The simulator's IMU (200 Hz, 0.03 m/s^2 noise, ~0.03 m/s^2 bias) across tiny's ride."""
    folder = Path(sim_run("tiny", "mcap", 0))
    truth = json.loads((folder / "gt_floors.json").read_text())["transitions"]
    cfg = MfmapConfig()
    with open_log(folder / "log.mcap", cfg.ingest) as src:
        _, seg = segment_floors(src, cfg)
        imu = src.imu()
    assert len(seg.transitions) == len(truth) == 1
    tr = seg.transitions[0]
    ride = ride_height(imu, tr.start_ns, tr.end_ns)
    assert ride.reason == "ok"
    assert ride.height_change_m is not None
    assert abs(ride.height_change_m - truth[0]["height_change_m"]) < 0.02
    assert 0.005 < ride.sigma_m < 0.03
    # The integration window hugs the ride (3.5 m at 1 m/s, 0.5 m/s^2: 5.5 s) plus its pads.
    assert 5.5 < (ride.end_ns - ride.start_ns) / 1e9 < 7.5


@pytest.mark.parametrize("dz_m", [4.0, -8.0])
def test_biased_tilted_imu(dz_m: float) -> None:
    """0.05 m/s^2 bias on a 2-degree tilted IMU: the stand-still and zero-velocity ends remove it."""
    imu = ride_imu([(*RIDE_NS, dz_m)], seed=1, accel_bias_m_s2=(0.05, 0.05, 0.05), tilt_deg=2.0)
    ride = ride_height(imu, *RIDE_NS)
    assert ride.reason == "ok"
    assert ride.height_change_m is not None
    assert abs(ride.height_change_m - dz_m) < 0.02
    # Bias along up: 0.05 (z) + 0.05 sin(2 deg) (y) ~ 0.052, plus gravity's 9.80665 removed.
    assert ride.bias_m_s2 == pytest.approx(0.05 * math.cos(math.radians(2)) + 0.05 * math.sin(math.radians(2)), abs=0.005)
    # Without the zero-velocity update the same bias would give 0.5 * 0.05 * T^2 ~ 1.3 m.


def test_sigma_matches_the_spread_over_seeds() -> None:
    errors = []
    sigma = 0.0
    for seed in range(12):
        imu = ride_imu([(*RIDE_NS, 4.0)], seed=seed)
        ride = ride_height(imu, *RIDE_NS)
        assert ride.height_change_m is not None
        errors.append(ride.height_change_m - 4.0)
        sigma = ride.sigma_m
    rms = float(np.sqrt(np.mean(np.square(errors))))
    assert 0.5 * sigma < rms < 2.0 * sigma
    assert abs(float(np.mean(errors))) < 0.015


def test_skipped_without_imu_or_stand_still() -> None:
    assert ride_height(None, *RIDE_NS).reason == "no IMU"
    imu = ride_imu([(*RIDE_NS, 4.0)], seed=2)
    # The robot turns on the spot right after the cabin stops: no stand-still to trust.
    t_s = (imu.stamp_ns - RIDE_NS[0]) / 1e9
    gyro = imu.gyro_rad_s.copy()
    gyro[(t_s > 11.2) & (t_s < 14.0), 2] = 0.5
    turning = dataclasses.replace(imu, gyro_rad_s=gyro)
    ride = ride_height(turning, *RIDE_NS)
    assert ride.height_change_m is None
    assert ride.reason == "robot not standing still after the ride"
    # A driver that removes gravity: nothing to take up from.
    linear = dataclasses.replace(imu, accel_m_s2=imu.accel_m_s2 - imu.accel_m_s2.mean(axis=0))
    assert ride_height(linear, *RIDE_NS).reason.startswith("IMU reads 0.")
    # An IMU that saw no ride at all (the barometer's transition was a pressure step).
    still = ride_imu([(*RIDE_NS, 0.0)], seed=2)
    assert ride_height(still, *RIDE_NS).reason == "no vertical acceleration found"


def _baro_step(pressure: PressureSeries, after_ns: int, step_pa: float) -> PressureSeries:
    p = pressure.pressure_pa + np.where(pressure.stamp_ns > after_ns, step_pa, 0.0)
    return PressureSeries(pressure.stamp_ns, p, pressure.frame_id)


def test_the_imu_sets_a_rides_height_and_the_barometer_is_weighed_in() -> None:
    """A 1 Pa pressure step at the ride (~ -8.5 cm in the barometer's level change): the IMU's
    height, scale-true, places the floor; the barometer's, whose honest sigma holds its unknown
    scale and the floors' pressure offsets, is weighed in and hardly pulls."""
    floor_height_m = 4.0
    b = make_building((0, 1), seed=4, floor_height_m=floor_height_m, baro_noise_pa=0.5)
    tr = b.segmentation.transitions[0]
    pressure = _baro_step(b.pressure, tr.start_ns, 1.0)
    # The same step in the floors stage's height trace and its transition.
    seg = dataclasses.replace(
        b.segmentation,
        transitions=(dataclasses.replace(tr, height_change_m=floor_height_m - 0.085),),
        height_raw_m=b.segmentation.height_raw_m - np.where(b.segmentation.stamp_ns > tr.start_ns, 0.085, 0.0),
    )
    imu = ride_imu([(tr.start_ns, tr.end_ns, floor_height_m)], seed=5)

    def z_error(config: GraphConfig, imu_series: ImuSeries | None) -> tuple[float, Any]:
        res = optimize_building(b.keyframes, b.edges, seg, pressure, config, temperature_k=295.0, imu=imu_series)
        return res.floor_z_m[1] - res.floor_z_m[0] - floor_height_m, res

    err_off, off = z_error(GraphConfig(ablation=AblationConfig(imu_ride_height=False)), imu)
    err_on, on = z_error(GraphConfig(), imu)
    err_none, none = z_error(GraphConfig(), None)
    assert err_off < -0.05  # the barometer's error
    assert abs(err_on) < 0.015
    assert err_none == pytest.approx(err_off, abs=1e-6)  # no IMU: the barometer alone
    assert on.stats["imu_ride"].count == 1 and "imu_ride" not in off.stats
    ride = on.to_json()["rides"][0]
    assert ride["imu"] == "ok" and ride["imu_legs"] == 1
    assert ride["heights_used"] == ["imu", "barometer"]
    assert ride["heights"].startswith("imu +3.99") and "; barometer +3.9" in ride["heights"]
    assert ride["floors_height_change_m"] == pytest.approx(floor_height_m - 0.085, abs=1e-4)
    assert ride["baro_height_change_m"] == pytest.approx(floor_height_m - 0.085, abs=0.01)
    assert abs(ride["imu_height_change_m"] - floor_height_m) < 0.015
    assert ride["baro_height_change_m"] < ride["graph_height_change_m"] < ride["imu_height_change_m"] + 1e-4
    assert abs(ride["graph_height_change_m"] - ride["imu_height_change_m"]) < 0.005
    assert on.to_json()["heights"]["pairs"] == 1
    assert off.to_json()["rides"][0]["imu"] == "off"
    assert off.to_json()["rides"][0]["heights_used"] == ["barometer"]
    assert none.to_json()["rides"][0]["imu"] == "no IMU"

    # A broken IMU (a bias that changed mid-ride): the cabin is not at rest where the integration
    # ends, so the IMU's own check leaves it out and the barometer is what is left.
    acc = imu.accel_m_s2.copy()
    t_s = (imu.stamp_ns - tr.start_ns) / 1e9
    acc[(t_s > 7.0) & (t_s < 7.5), 2] += 4.0
    err_bad, bad = z_error(GraphConfig(), dataclasses.replace(imu, accel_m_s2=acc))
    assert "imu_ride" not in bad.stats
    assert bad.to_json()["rides"][0]["imu"].startswith("the cabin is not at rest at the end of the integration")
    assert bad.to_json()["rides"][0]["heights_used"] == ["barometer"]
    assert err_bad == pytest.approx(err_off, abs=1e-6)


def test_a_transition_height_moves_the_floor_not_the_keyframes_at_the_ride() -> None:
    """Barometer only (no IMU, no per-keyframe factors): the transition's height change is what
    separates the floors. On the floors' levels, with world-z ties, it moves the whole floor (0.2 mm
    off); on the two keyframes at the ride, as before, the floors' 2 cm ties let it bend them
    instead (2.7 cm off)."""
    b = make_building((0, 1), seed=4, floor_height_m=4.0, baro_noise_pa=0.5)
    config = GraphConfig(ablation=AblationConfig(imu_ride_height=False, barometer_factors=False))
    res = optimize_building(b.keyframes, b.edges, b.segmentation, b.pressure, config, temperature_k=295.0)
    ride = res.to_json()["rides"][0]
    assert abs(res.floor_z_m[1] - res.floor_z_m[0] - ride["baro_height_change_m"]) < 0.005


def _cabin_profile(moves: list[tuple[float, float]], still_s: float = 6.0) -> F64:
    """The cabin's vertical acceleration at 200 Hz for `moves` (height change, then seconds
    standing at the next floor) at 0.5 m/s^2 up to 1 m/s, standing `still_s` before and after."""
    dt_s = 1.0 / 200.0
    parts = [np.zeros(round(still_s / dt_s))]
    for dz_m, stop_s in moves:
        acc_s = min(2.0, math.sqrt(abs(dz_m) / 0.5))
        cruise_s = max(abs(dz_m) / (0.5 * acc_s) - acc_s, 0.0)
        n_acc, n_cruise = round(acc_s / dt_s), round(cruise_s / dt_s)
        a = math.copysign(0.5, dz_m) * (abs(dz_m) / (0.5 * acc_s * (acc_s + cruise_s)))
        parts += [np.full(n_acc, a), np.zeros(n_cruise), np.full(n_acc, -a), np.zeros(round(stop_s / dt_s))]
    parts.append(np.zeros(round(still_s / dt_s)))
    return np.concatenate(parts)


def _profile_imu(a_up: F64, seed: int, still_s: float = 6.0) -> tuple[ImuSeries, int, int]:
    """A 200 Hz IMU feeling `a_up`, with a 0.03 m/s^2 bias and white noise; returns it with
    the first move's start and the last one's end."""
    rng = np.random.default_rng([seed, 31])
    dt_s = 1.0 / 200.0
    n = a_up.shape[0]
    accel = np.column_stack([np.full(n, 0.03), np.full(n, -0.02), 9.80665 + 0.03 + a_up])
    accel += rng.normal(0.0, 0.03, (n, 3))
    stamps = START_NS + (np.arange(n) * dt_s * 1e9).astype(np.int64)
    imu = ImuSeries(stamps, rng.normal(0.0, 0.003, (n, 3)), accel, np.full((n, 4), np.nan), "imu")
    start = START_NS + int(still_s * 1e9)
    end = START_NS + int((n * dt_s - still_s) * 1e9)
    return imu, start, end


def _cabin_imu(moves: list[tuple[float, float]], seed: int, still_s: float = 6.0) -> tuple[ImuSeries, int, int]:
    """A 200 Hz IMU in a cabin that makes `moves` (see _cabin_profile)."""
    return _profile_imu(_cabin_profile(moves, still_s), seed, still_s)


def test_a_ride_that_stops_on_the_way_is_integrated_move_by_move() -> None:
    """Up 4 m, 12 s at a floor with the robot in the cabin, up 5.5 m more: each move between
    stand-stills gets its own zero-velocity ends (one window over all would carry 25 s of noise,
    about 9 cm)."""
    errors = []
    for seed in range(6):
        imu, start, end = _cabin_imu([(4.0, 12.0), (5.5, 0.0)], seed)
        ride = ride_height(imu, start, end)
        assert ride.reason == "ok" and ride.legs == 2
        assert ride.height_change_m is not None
        errors.append(ride.height_change_m - 9.5)
        assert 0.01 < ride.sigma_m < 0.03
    assert float(np.sqrt(np.mean(np.square(errors)))) < 0.025
    # A long ride cruising for 10 s is one move: the accelerometer reads nothing while it
    # cruises, the velocity does not drop.
    imu, start, end = _cabin_imu([(12.0, 0.0)], 0)
    ride = ride_height(imu, start, end)
    assert ride.legs == 1 and ride.height_change_m is not None
    assert abs(ride.height_change_m - 12.0) < 0.06


def test_the_cruise_is_not_integrated_while_the_cabin_holds_its_speed() -> None:
    """12 m in one move: 2 s speeding up, 10 s cruising, 2 s braking. The cruise's noise is left
    out: the error is the speed that the 4 s of speeding up and braking leave uncertain, over the
    10 s (about 2.6 cm; the whole 14 s window's noise would be 3.2 cm), and the sigma says so."""
    errors, sigmas = [], []
    for seed in range(16):
        imu, start, end = _cabin_imu([(12.0, 0.0)], seed)
        ride = ride_height(imu, start, end)
        assert ride.reason == "ok" and ride.legs == 1 and ride.height_change_m is not None
        errors.append(ride.height_change_m - 12.0)
        sigmas.append(math.sqrt(ride.sigma_m**2 - SIGMA_FLOOR_M**2))
    rms = float(np.sqrt(np.mean(np.square(errors))))
    whole_m = 0.03 * math.sqrt(1 / 200) * 14.0**1.5 / math.sqrt(12)
    assert float(np.mean(sigmas)) < 0.85 * whole_m
    assert 0.5 * float(np.mean(sigmas)) < rms < 1.5 * float(np.mean(sigmas))


def test_a_cabin_that_drifts_while_cruising_is_integrated_throughout() -> None:
    """The cabin loses 0.015 m/s^2 of speed for 8 s of its cruise (under the threshold that
    finds its acceleration): leaving the cruise out would miss those 12 cm/s and put the height
    12 cm off; the heights with and without the cruise disagree, so the whole move is integrated."""
    a_up = _cabin_profile([(12.0, 0.0)])
    dt_s = 1.0 / 200.0
    cruise = slice(round((6.0 + 3.0) / dt_s), round((6.0 + 11.0) / dt_s))
    a_up[cruise] -= 0.015
    # The braking ends the move at rest: it brakes less by the 0.12 m/s lost.
    braking = np.flatnonzero(a_up < -0.1)
    a_up[braking] += 0.015 * 8.0 / (braking.shape[0] * dt_s)
    v = np.cumsum(a_up) * dt_s
    true_m = float(np.sum(v) * dt_s)
    assert abs(v[-1]) < 1e-9 and 11.0 < true_m < 12.0
    for seed in range(4):
        imu, start, end = _profile_imu(a_up, seed)
        ride = ride_height(imu, start, end)
        assert ride.reason == "ok" and ride.height_change_m is not None
        assert abs(ride.height_change_m - true_m) < 0.06
