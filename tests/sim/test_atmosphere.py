"""mfmap.sim.atmosphere: the simulator's own air column, checked against textbook numbers."""

from __future__ import annotations

import numpy as np
import pytest

from mfmap.sim.atmosphere import (
    AirColumn,
    normal_gravity_m_s2,
    saturation_vapour_pressure_pa,
    virtual_temperature_k,
)


def test_isothermal_gradient_and_round_trip() -> None:
    air = AirColumn(295.0)
    # dp/dz = -p g / (R_d T): 101325 * 9.80665 / (287.058 * 295) = 11.734 Pa/m.
    drop = air.pressure_pa(0.0, 101_325.0) - air.pressure_pa(1.0, 101_325.0)
    assert drop == pytest.approx(11.734, abs=0.005)
    h = np.array([-8.0, 0.0, 3.7, 55.0])
    p = air.pressure_pa(h, 99_000.0)
    np.testing.assert_allclose(air.height_m(p, 99_000.0), h, atol=1e-9)


def test_gradient_column_matches_a_numeric_integral() -> None:
    air = AirColumn(290.0, gradient_k_per_m=0.4, gravity_m_s2=9.79)
    z = np.linspace(0.0, 30.0, 300_001)
    t = 290.0 + 0.4 * z
    integral = np.sum((1 / t[1:] + 1 / t[:-1]) / 2 * np.diff(z))
    expected = 100_000.0 * np.exp(-9.79 / 287.0579 * integral)
    assert air.pressure_pa(30.0, 100_000.0) == pytest.approx(expected, abs=2e-3)
    assert air.height_m(air.pressure_pa(30.0, 100_000.0), 100_000.0) == pytest.approx(30.0, abs=1e-9)
    # Warmer air is thinner: the same height change is a smaller pressure change.
    cold, warm = AirColumn(273.15), AirColumn(313.15)
    d_cold = 1e5 - cold.pressure_pa(4.0, 1e5)
    d_warm = 1e5 - warm.pressure_pa(4.0, 1e5)
    assert d_cold / d_warm == pytest.approx(313.15 / 273.15, rel=1e-3)  # 14.6 % over 0-40 deg C


def test_gravity_and_humidity() -> None:
    assert normal_gravity_m_s2(0.0) == pytest.approx(9.7803, abs=1e-4)
    assert normal_gravity_m_s2(90.0) == pytest.approx(9.8322, abs=1e-4)
    assert normal_gravity_m_s2(45.0) == pytest.approx(9.8062, abs=1e-4)
    assert saturation_vapour_pressure_pa(20.0) == pytest.approx(2339.0, rel=0.005)
    assert saturation_vapour_pressure_pa(30.0) == pytest.approx(4246.0, rel=0.005)
    # Saturated air at 30 deg C is as light as dry air nearly 5 K warmer.
    assert virtual_temperature_k(303.15, 1.0, 101_325.0) - 303.15 == pytest.approx(4.9, abs=0.1)
    assert virtual_temperature_k(303.15, 0.0, 101_325.0) == 303.15
