"""Pressure -> height for the barometric factors (the height change across a transition is
mfmap.floors.levels.level_change)."""

from __future__ import annotations

import numpy as np

from mfmap.baro import height_from_pressure
from mfmap.types import F64, PressureSeries


def pressure_to_height_m(pressure_pa: F64, reference_pa: float, temperature_k: float) -> F64:
    """Hypsometric height above the reference pressure (eq. 3 of the LeGO-LOAM elevator paper)."""
    return np.asarray(height_from_pressure(np.asarray(pressure_pa, dtype=np.float64), reference_pa, temperature_k))


def pressure_at(series: PressureSeries, stamps_ns: np.ndarray, window_s: float) -> F64:
    """Mean pressure within +-window_s of each stamp (linear interpolation where none)."""
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    t = series.stamp_ns
    p = series.pressure_pa
    csum = np.concatenate([[0.0], np.cumsum(p)])
    half_ns = int(window_s * 1e9)
    lo = np.searchsorted(t, stamps - half_ns, side="left")
    hi = np.searchsorted(t, stamps + half_ns, side="right")
    count = hi - lo
    mean = (csum[hi] - csum[lo]) / np.maximum(count, 1)
    interp = np.interp(stamps.astype(np.float64), t.astype(np.float64), p)
    return np.where(count > 0, mean, interp)
