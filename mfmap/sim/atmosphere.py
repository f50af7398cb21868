"""The simulator's own air: the pressure a barometer feels at a height in a building.

The estimator converts pressure to height with its own model and constants; the simulator
must not borrow them, or a model error could never show in a test. So this module has its own
physical constants and its own model of the air column: hydrostatic balance of moist air whose
(virtual) temperature may change linearly with height,

    p(z) = p(0) * exp(-g / R_d * integral_0^z dz' / T_v(z')),   T_v(z) = T_v(0) + gamma * z,

under local gravity g (WGS 84 normal gravity at the building's latitude). With gamma = 0 the
column is isothermal. Indoors a column is nearly isothermal; the estimator's hypsometric
formula with an outdoor lapse rate differs from it by millimetres over a building, while the
temperature, humidity and gravity it does not know change the scale by up to ~15 %.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

from mfmap.types import F64

ArrayOrFloat = TypeVar("ArrayOrFloat", float, F64)

# CODATA 2018 molar gas constant; molar masses of dry air (ISO 2533) and water.
R_UNIVERSAL_J_PER_MOL_K = 8.314462618
M_DRY_AIR_KG_PER_MOL = 0.0289644
M_WATER_KG_PER_MOL = 0.01801528
R_DRY_AIR_J_PER_KG_K = R_UNIVERSAL_J_PER_MOL_K / M_DRY_AIR_KG_PER_MOL
EPSILON_WATER = M_WATER_KG_PER_MOL / M_DRY_AIR_KG_PER_MOL
G_STANDARD_M_S2 = 9.80665
KELVIN = 273.15


def normal_gravity_m_s2(latitude_deg: float) -> float:
    """WGS 84 normal gravity on the ellipsoid (Somigliana's formula)."""
    s2 = math.sin(math.radians(latitude_deg)) ** 2
    return 9.7803253359 * (1.0 + 0.00193185265241 * s2) / math.sqrt(1.0 - 0.00669437999013 * s2)


def saturation_vapour_pressure_pa(t_c: float) -> float:
    """Over water, Magnus form with the Alduchov-Eskridge coefficients (0.4 % over 0-40 deg C)."""
    return 610.94 * math.exp(17.625 * t_c / (t_c + 243.04))


def virtual_temperature_k(t_k: float, relative_humidity: float, p_pa: float) -> float:
    """The temperature dry air would need to have moist air's density at the same pressure."""
    e = relative_humidity * saturation_vapour_pressure_pa(t_k - KELVIN)
    return t_k / (1.0 - (e / p_pa) * (1.0 - EPSILON_WATER))


@dataclass(frozen=True)
class AirColumn:
    """Hydrostatic air column: virtual temperature at world z = 0, its vertical gradient and
    local gravity."""

    virtual_temperature_k: float
    gradient_k_per_m: float = 0.0
    gravity_m_s2: float = G_STANDARD_M_S2

    def _integral(self, h: F64) -> F64:
        t0, gam = self.virtual_temperature_k, self.gradient_k_per_m
        if abs(gam) < 1e-12:
            return h / t0
        return np.log1p(gam * h / t0) / gam

    def pressure_pa(self, h_m: ArrayOrFloat, p_ref_pa: float | F64) -> ArrayOrFloat:
        """Pressure at `h_m` above world z = 0, where the pressure is `p_ref_pa`."""
        h = np.asarray(h_m, dtype=np.float64)
        p = p_ref_pa * np.exp(-self.gravity_m_s2 / R_DRY_AIR_J_PER_KG_K * self._integral(h))
        return p if isinstance(h_m, np.ndarray) else float(p)

    def height_m(self, p_pa: ArrayOrFloat, p_ref_pa: float | F64) -> ArrayOrFloat:
        """The inverse of `pressure_pa`: height above world z = 0."""
        p = np.asarray(p_pa, dtype=np.float64)
        integral = -np.log(p / p_ref_pa) * R_DRY_AIR_J_PER_KG_K / self.gravity_m_s2
        t0, gam = self.virtual_temperature_k, self.gradient_k_per_m
        h = integral * t0 if abs(gam) < 1e-12 else np.expm1(gam * integral) * t0 / gam
        return h if isinstance(p_pa, np.ndarray) else float(h)


# The air of the simulator's calm building: 295 K, dry, standard gravity.
CALM_TEMPERATURE_K = 295.0
CALM_AIR = AirColumn(CALM_TEMPERATURE_K)
