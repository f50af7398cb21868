"""The height trace on its uniform grid, despiked and smoothed, with its vertical speed."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mfmap.floors.config import FilterMethod, FloorsConfig
from mfmap.floors.filters import (
    Grid,
    hampel,
    remove_transients,
    robust_noise_sigma,
    rts_smooth,
    running_median_1s,
    sliding_mean,
    step_size,
)
from mfmap.types import F64

# Pressure pulses up to this fraction of a floor are doors or HVAC; taller ones are visits.
_MAX_PULSE_FRACTION = 0.75


@dataclass(frozen=True)
class FilteredTrace:
    """The height trace on its uniform grid: despiked, smoothed, and vertical speed."""

    grid: Grid  # raw heights on the grid
    despiked_m: F64
    filtered_m: F64
    speed_m_s: F64
    level_m: F64  # what floor levels are measured on (despiked for rts, the mean for baseline)
    noise_m: float
    spikes: int
    jump_m: F64 | None = None  # change of the 1 s running median over +-0.15 s (abrupt steps)
    level_smooth_m: F64 | None = None  # 1 s running median of level_m


def filter_height(grid: Grid, cfg: FloorsConfig) -> FilteredTrace:
    """Spike rejection and smoothing of a uniformly sampled height trace."""
    values = grid.values
    dt_s = grid.dt_s
    if cfg.filter.method is FilterMethod.SLIDING_MEAN:
        filtered = sliding_mean(values, cfg.filter.sliding_window_samples)
        speed = np.gradient(filtered, dt_s) if values.shape[0] > 1 else np.zeros_like(filtered)
        noise = robust_noise_sigma(values)
        return FilteredTrace(grid, values, filtered, speed, filtered, noise, 0)
    half = max(1, round(cfg.filter.spike_window_s / dt_s))
    despiked, spikes = hampel(values, half, cfg.filter.spike_threshold_sigma)
    median = running_median_1s(despiked, dt_s)
    despiked, _pulses = remove_transients(
        despiked, dt_s, cfg.filter.max_transient_s, _MAX_PULSE_FRACTION * cfg.min_floor_height_m, median
    )
    if cfg.filter.noise_m is not None:
        noise = cfg.filter.noise_m
    else:
        one_second = max(1, round(1.0 / dt_s))
        noise = max(robust_noise_sigma(despiked), robust_noise_sigma(despiked, one_second))
    # A quantised, nearly noiseless sensor would give a zero sigma and a filter that smooths
    # nothing; a centimetre floor keeps the smoother sensible.
    noise = max(noise, 0.01)
    filtered, speed = rts_smooth(despiked, dt_s, noise, cfg.filter.accel_noise_m_s2)
    # Steps are judged on the median before pulse removal: a removed pulse no longer matters.
    return FilteredTrace(
        grid, despiked, filtered, speed, despiked, noise, spikes, step_size(median, dt_s), running_median_1s(despiked, dt_s)
    )
