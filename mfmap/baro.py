"""Barometric height: the hypsometric relation (eq. 3 of the LeGO-LOAM elevator paper) and its inverse.

    z = T0 / L * ((P2 / P1) ** (-L * R / g) - 1)

One place for the formula: the floors stage and the graph's barometric factors both make height
from pressure with it. The simulator keeps its own atmosphere (mfmap.sim.atmosphere), so that the
estimator is tested against a world it does not share a model with.
"""

from __future__ import annotations

from typing import TypeVar

import numpy as np

from mfmap.types import F64

T0_K = 295.0  # room temperature, as in the LeGO-LOAM elevator paper
LAPSE_K_PER_M = 0.0065
R_J_PER_KG_K = 287.053
G_M_PER_S2 = 9.81

_EXP = LAPSE_K_PER_M * R_J_PER_KG_K / G_M_PER_S2

ArrayOrFloat = TypeVar("ArrayOrFloat", float, F64)


def height_from_pressure(
    p_pa: ArrayOrFloat, p_ref_pa: float | F64, temperature_k: float = T0_K
) -> ArrayOrFloat:
    """Height in metres above the level where the pressure is `p_ref_pa`."""
    ratio = np.asarray(p_pa, dtype=np.float64) / p_ref_pa
    height = temperature_k / LAPSE_K_PER_M * (ratio ** (-_EXP) - 1.0)
    return height if isinstance(p_pa, np.ndarray) else float(height)


def pressure_from_height(
    h_m: ArrayOrFloat, p_ref_pa: float | F64, temperature_k: float = T0_K
) -> ArrayOrFloat:
    """Pressure in Pa at `h_m` metres above the level where the pressure is `p_ref_pa`."""
    h = np.asarray(h_m, dtype=np.float64)
    pressure = p_ref_pa * (1.0 + LAPSE_K_PER_M * h / temperature_k) ** (-1.0 / _EXP)
    return pressure if isinstance(h_m, np.ndarray) else float(pressure)
