"""mfmap.sim.world: a building's air that the estimator's model does not describe. Each effect
is checked against the physics it claims, on the simulator's barometer without any lidar."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from mfmap.sim.atmosphere import CALM_AIR, KELVIN
from mfmap.sim.building import Building
from mfmap.sim.run import build_trajectory, make_barometer
from mfmap.sim.scenarios import SCENARIOS, building_for
from mfmap.sim.sensors import Barometer
from mfmap.sim.spec import office_block
from mfmap.sim.trajectory import DT_S, Trajectory
from mfmap.sim.world import TemperatureSpec, World, WorldSpec


def _barometer(scenario: str, seed: int, world: WorldSpec) -> tuple[Building, Trajectory, Barometer]:
    spec = dataclasses.replace(SCENARIOS[scenario], world=world)
    building = building_for(spec, seed)
    traj = build_trajectory(spec, building, seed, 1)
    return building, traj, make_barometer(spec, building, traj, seed)


def _still_mean(baro: Barometer, traj: Trajectory, t0: float, t1: float) -> float:
    """Mean noise-free pressure over [t0, t1] relative to the weather at world z = 0."""
    ticks = np.arange(round(t0 / DT_S), round(t1 / DT_S))
    return float(np.mean(baro.clean(ticks) - baro.reference(ticks * DT_S)))


def test_calm_world_is_the_air_column_alone() -> None:
    _, traj, baro = _barometer("two-floor", 0, WorldSpec())
    assert baro.world is not None and baro.world.spec.calm
    ticks = np.arange(0, len(traj.xyz), 7)
    expected = CALM_AIR.pressure_pa(baro.true_height(ticks), baro.reference(ticks * DT_S))
    assert np.array_equal(baro.clean(ticks), expected)
    assert not WorldSpec.harsh().calm


def test_harsh_draws_cover_the_ranges() -> None:
    building = Building(office_block(4, 3.6), 1, 0)
    worlds = [World.draw(WorldSpec.harsh(), building, 101_000.0, seed) for seed in range(200)]
    t_c = np.array([w.air_temperature_k - KELVIN for w in worlds])
    assert t_c.min() >= 0.0 and t_c.max() <= 40.0 and t_c.min() < 3.0 and t_c.max() > 37.0
    g = np.array([w.air.gravity_m_s2 for w in worlds])
    assert 9.780 <= g.min() < 9.785 and 9.815 < g.max() <= 9.823
    # Humid warm air: the virtual temperature is up to a few kelvin above the dry bulb.
    dtv = np.array([w.air.virtual_temperature_k - w.air_temperature_k for w in worlds])
    assert dtv.min() >= 0.0 and dtv.max() > 3.0
    # Stack effect of both signs (winter and summer), a few Pa per storey at most.
    stack = np.array([w.stack_pa_per_m for w in worlds])
    assert stack.min() < -0.1 and stack.max() > 1.0 and np.abs(stack).max() < 2.0
    offsets = np.array([w.floor_offsets_pa for w in worlds])
    assert np.abs(offsets).max() < 15.0 and np.std(offsets) > 1.0
    assert all(w.thermometer is not None for w in worlds)


def test_stack_effect_lowers_upper_floors_in_winter() -> None:
    spec = dataclasses.replace(WorldSpec.harsh(), outdoor_minus_indoor_k=(-25.0, -20.0), floor_hvac_pa=0.0)
    building = Building(office_block(5, 4.0), 0, 0)
    for seed in range(10):
        w = World.draw(spec, building, 101_000.0, seed)
        steps = np.diff(w.floor_offsets_pa)
        # -share * (rho_out - rho_in) * g * 4 m per storey: the outside is colder, so the floors
        # fall behind the shaft's column as they rise.
        np.testing.assert_allclose(steps, -w.floor_stack_share * w.stack_pa_per_m * 4.0, rtol=1e-9)
        assert np.all(steps < 0)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_floor_levels_carry_the_drawn_offsets(seed: int) -> None:
    """Standing on a floor, the pressure is the air column's plus that floor's offset: the
    floor's apparent height is off by the offset over rho * g (tens of centimetres)."""
    _, traj, baro = _barometer("three-floor-revisit", seed, WorldSpec.harsh())
    world = baro.world
    assert world is not None
    for k, t0, t1 in traj.floor_visits:
        # Well inside the visit, away from the doors' mixing and pulses.
        mean = _still_mean(baro, traj, t0 + 15.0, t1 - 15.0)
        ticks = np.arange(round((t0 + 15.0) / DT_S), round((t1 - 15.0) / DT_S))
        col = world.air.pressure_pa(baro.true_height(ticks), baro.reference(ticks * DT_S)) - baro.reference(ticks * DT_S)
        assert mean - float(np.mean(col)) == pytest.approx(world.floor_offsets_pa[k], abs=0.05)


def test_the_ride_reads_a_wrong_height_with_the_calm_model() -> None:
    """Across buildings, the barometer's height change of one 4.7 m ride (converted with the
    calm 295 K model) scatters by percent: temperature, humidity, gravity, floor offsets."""
    errors = []
    for seed in range(12):
        _, traj, baro = _barometer("two-floor", seed, WorldSpec.harsh())
        tr = traj.transitions[0]
        (v0,), (v1,) = ([v for v in traj.floor_visits if v[0] == f][:1] for f in (0, 1))
        p0 = _still_mean(baro, traj, v0[2] - 25.0, v0[2] - 15.0)
        p1 = _still_mean(baro, traj, v1[1] + 15.0, v1[1] + 25.0)
        dz = CALM_AIR.height_m(101_325.0 + p1, 101_325.0 + p0)
        errors.append(dz / tr.height_change_m - 1.0)
    err = np.array(errors)
    assert np.abs(err).max() > 0.05 and np.std(err) > 0.02
    assert np.abs(err).max() < 0.3


def test_closed_cabin_lags_and_doors_pulse() -> None:
    spec = dataclasses.replace(WorldSpec.harsh(), cabin_lag_s=(1.0, 1.0), piston_pa_s2_per_m2=(0.0, 0.0), gust_pa=(0.0, 0.0))
    _, traj, baro = _barometer("tiny", 3, spec)
    world = baro.world
    assert world is not None
    tr = traj.transitions[0]
    mid = (tr.t_start_s + tr.t_end_s) / 2
    i = np.array([round(mid / DT_S)])
    apparent = world.air.height_m(baro.clean(i), baro.reference(i * DT_S))[0]
    # A 1 s lag at ~1 m/s: the cabin's pressure reads about a metre below the cabin.
    lag_m = float(baro.true_height(i)[0] - apparent)
    assert 0.6 < lag_m < 1.4
    # Every door opening and closing pushes a pulse: the same world without them differs by
    # exactly the pulses, which decay within a few pulse times.
    quiet = dataclasses.replace(spec, door_pulse_pa=(0.0, 0.0))
    _, _, baro_q = _barometer("tiny", 3, quiet)
    doors = [t for t0, t1, _ in traj.door_open for t in (t0, t1)]
    assert [t for t, _ in world.door_pulses] == doors
    tau = world.door_pulse_s

    def pulses_at(t: float) -> float:
        return sum(a * np.exp(-(t - tp) / tau) for tp, a in world.door_pulses if 0 <= t - tp < 10 * tau)

    for t0, amp in world.door_pulses:
        assert 1.0 <= abs(amp) <= 6.0
        for t in (t0, t0 + tau, t0 + 3 * tau):
            i = np.array([round(t / DT_S)])
            diff = float((baro.clean(i) - baro_q.clean(i))[0])
            assert diff == pytest.approx(pulses_at(i[0] * DT_S), abs=1e-6)
        assert abs(pulses_at(t0)) > 0.5


def test_chip_temperature_runs_warm_and_lags() -> None:
    sensor = TemperatureSpec(warmup_s=(30.0, 30.0))
    # Air of one temperature at every height here, so the chip's lag does not show.
    spec = dataclasses.replace(WorldSpec.harsh(), temperature_sensor=sensor, temperature_gradient_k_per_m=(0.0, 0.0))
    _, traj, baro = _barometer("stairs", 5, spec)
    world = baro.world
    assert world is not None and world.thermometer is not None
    th = world.thermometer
    t = np.arange(0.0, traj.duration_s, 0.2)
    h = baro.true_height(np.round(t / DT_S).astype(np.int64))
    reading = world.chip_temperature_c(t, h, np.random.default_rng(0))
    air_c = world.air_temperature_k - KELVIN + world.air.gradient_k_per_m * h
    late = t > 5 * th.warmup_s
    offset = float(np.median((reading - air_c)[late]))
    assert offset == pytest.approx(th.self_heating_k + th.bias_k, abs=0.15)
    # Shortly after power-up it reads the air plus the bias (not yet warmed up).
    assert float(np.median((reading - air_c)[t < 1.0])) == pytest.approx(th.bias_k, abs=0.1)
    assert np.all(np.abs(np.diff(reading)) < 0.2)  # a chip's temperature moves slowly


def test_harsh_log_has_the_temperature_topic(sim_run: Callable[..., Path]) -> None:
    from simtest_helpers import iter_messages, load_floors, stamp_ns

    folder = sim_run("tiny-harsh")
    sim = load_floors(folder)["sim"]
    world = sim["world"]
    assert 0.0 <= world["air_temperature_c"] <= 40.0
    t, c = [], []
    for _, msgtype, _, msg in iter_messages(folder, "mcap", {"/baro/temperature"}):
        assert msgtype == "sensor_msgs/msg/Temperature" and msg.header.frame_id == "baro"
        t.append(stamp_ns(msg) / 1e9)
        c.append(msg.temperature)
    assert len(t) > 0
    assert np.median(np.diff(t)) == pytest.approx(0.2, abs=1e-6)
    ts = world["temperature_sensor"]
    assert abs(np.median(c) - world["air_temperature_c"]) < ts["self_heating_k"] + abs(ts["bias_k"]) + 0.5
