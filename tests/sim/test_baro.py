"""mfmap.baro: the hypsometric relation, eq. 3 of the LeGO-LOAM elevator paper, and its inverse."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mfmap.baro import height_from_pressure, pressure_from_height


def test_matches_seed_equation_3() -> None:
    # z = T0/L * ((P2/P1)^(-L R / g) - 1), T0 = 295 K, L = 0.0065 K/m, R = 287.053, g = 9.81.
    p1, p2 = 101_325.0, 101_270.0
    z = 295.0 / 0.0065 * ((p2 / p1) ** (-0.0065 * 287.053 / 9.81) - 1.0)
    assert height_from_pressure(p2, p1) == pytest.approx(z, abs=1e-9)
    assert z == pytest.approx(4.6876, abs=1e-3)  # 55 Pa is about one 4.7 m floor (the LeGO-LOAM elevator paper's Fig. 6)


@pytest.mark.parametrize("h_m", [-12.0, -4.0, 0.0, 0.3, 4.7, 20.0, 150.0])
def test_round_trip(h_m: float) -> None:
    p = pressure_from_height(h_m, 99_800.0)
    assert height_from_pressure(p, 99_800.0) == pytest.approx(h_m, abs=1e-9)
    assert (p < 99_800.0) == (h_m > 0)


def test_arrays_and_temperature() -> None:
    h = np.array([0.0, 4.7, 9.4])
    p = pressure_from_height(h, 101_325.0)
    assert isinstance(p, np.ndarray) and p.shape == (3,)
    # Equal height steps give nearly equal pressure steps indoors (~11.7 Pa/m at 295 K).
    steps = -np.diff(p) / 4.7
    assert steps == pytest.approx([11.72, 11.72], abs=0.05)
    warm = pressure_from_height(4.7, 101_325.0, temperature_k=310.0)
    assert 101_325.0 - warm < 101_325.0 - p[1]  # warmer air is thinner: a smaller drop
    assert math.isclose(height_from_pressure(101_325.0, 101_325.0), 0.0)
