"""The barometer's height change across a transition: one fit over the raw trace either side.

The floors stage places floors with it (their elevations are the least-squares fit of every
transition's change) and the graph stage weighs it with its sigma.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from mfmap.floors.filters import (
    MAD_TO_SIGMA,
    Grid,
    resample_uniform,
    robust_level,
    running_median_1s,
)
from mfmap.types import F64, FloorSegmentation


@dataclass(frozen=True)
class LevelChange:
    """The barometer's height change across one transition, or why there is none (`height_change_m` None)."""

    height_change_m: float | None
    sigma_m: float
    window_s: float  # seconds of floor used on each side
    masked_share: float  # share of those samples left out as door/HVAC steps
    reason: str  # "ok" or why the estimate was skipped


# A side with less floor than this gives no useful level (a transition straight after another).
MIN_SIDE_S = 5.0
# Residual blocks for the coloured-noise check, the noise taken as white within a block: a
# phone's barometer wanders over a second, wind gusts and a floor's air over ten or twenty.
BLOCKS_S = (1.0, 4.0, 16.0)
# Weather moves the barometric height by up to ~120 Pa/h (1 cm per second of apparent height at
# most); its slope's prior sigma, in metres per second.
WEATHER_SLOPE_SIGMA_M_S = 0.002
# The weather's slope is read off the floor visits within this many seconds of a transition (its
# curvature, tens of Pa/h per hour, bends it little over a quarter of an hour) ...
WEATHER_SPAN_S = 900.0
# ... and trusted no better than this (m/s): a floor's own wander over a visit is slope too.
WEATHER_SLOPE_FLOOR_M_S = 0.0005


@dataclass(frozen=True)
class RawTrace:
    """The segmentation's raw heights on a uniform grid, with their 1 s running median."""

    times_s: F64  # from the first sample
    height_m: F64
    median_m: F64
    dt_s: float


def raw_trace(seg: FloorSegmentation) -> RawTrace:
    """Once per segmentation: every transition's fit reads the same grid."""
    t_all = (seg.stamp_ns - seg.stamp_ns[0]).astype(np.float64) / 1e9
    grid = resample_uniform(t_all, np.asarray(seg.height_raw_m, dtype=np.float64))
    return trace_of_grid(grid)


def trace_of_grid(grid: Grid) -> RawTrace:
    """The raw heights resampled on a uniform grid, with their 1 s running median."""
    return RawTrace(grid.times_s, grid.values, running_median_1s(grid.values, grid.dt_s), grid.dt_s)


def level_change(
    seg: FloorSegmentation,
    index: int,
    window_s: float = 120.0,
    gap_s: float = 1.0,
    step_m: float = 0.25,
    trace: RawTrace | None = None,
) -> LevelChange:
    """Height change across transition `index` of a segmentation (see `fit_level_change`).

    `trace`: the segmentation's `raw_trace`, when the caller fits several transitions.
    """
    stamp = seg.stamp_ns
    if stamp.shape[0] < 10:
        return LevelChange(None, 0.0, 0.0, 0.0, "too few barometer samples")
    trace = trace if trace is not None else raw_trace(seg)

    def sec(ns: int) -> float:
        return (ns - int(stamp[0])) / 1e9

    spans = [(sec(t.start_ns), sec(t.end_ns)) for t in seg.transitions]
    visits = visits_between(trace, spans)
    return fit_level_change(trace, spans[index], (visits[index][0], visits[index + 1][1]), window_s,
                            gap_s, step_m, weather_slope(trace, visits, spans[index], gap_s, step_m))


def visits_between(trace: RawTrace, transitions_s: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The floor visits (start, end) around transitions given as (start, end) in the trace's
    seconds: one more than the transitions."""
    edges = [float(trace.times_s[0])] + [x for pair in transitions_s for x in pair] + [float(trace.times_s[-1])]
    return [(edges[2 * k], edges[2 * k + 1]) for k in range(len(transitions_s) + 1)]


def weather_slope(
    trace: RawTrace,
    visits_s: list[tuple[float, float]],
    transition_s: tuple[float, float],
    gap_s: float = 1.0,
    step_m: float = 0.25,
) -> tuple[float, float]:
    """The weather's slope of the barometric height around a transition (m/s) and its sigma:
    one fit over every floor visit within WEATHER_SPAN_S of it, a level per visit and a shared
    slope, door and HVAC steps left out as in the transition's own fit.

    The transition's own fit sees only the floor either side, trimmed to the same length: after
    a long stair walk half a minute on the floor reached can be all it has, and the stairwell's
    air leaving the robot over those seconds looks like weather. Extrapolated across two minutes
    of stairs, 3 cm/s of such slope moved a 6.6 m descent by 2.1 m (a simulated building, a
    return to the start floor taken for a new floor). The visits around it, minutes of floor,
    know the weather better; the prior of WEATHER_SLOPE_SIGMA_M_S is kept when they are short.
    """
    mid = 0.5 * (transition_s[0] + transition_s[1])
    t, med, dt = trace.times_s, trace.median_m, trace.dt_s
    cols: list[npt.NDArray[np.bool_]] = []
    for lo, hi in visits_s:
        lo, hi = max(lo + gap_s, mid - WEATHER_SPAN_S), min(hi - gap_s, mid + WEATHER_SPAN_S)
        if hi - lo >= 2 * MIN_SIDE_S:
            cols.append((t >= lo) & (t <= hi))
    if not cols:
        return 0.0, WEATHER_SLOPE_SIGMA_M_S
    used = np.logical_or.reduce(cols)
    levels = np.stack([c[used] for c in cols], axis=1).astype(np.float64)
    design = np.concatenate([levels, (t[used] - mid)[:, None]], axis=1)
    y = med[used]
    start = np.array([robust_level(y[levels[:, k] > 0]) for k in range(len(cols))] + [0.0])
    keep = ~_robust_outliers(design, y, start, dt, step_m)
    if np.count_nonzero(keep) < 20:
        return 0.0, WEATHER_SLOPE_SIGMA_M_S
    a, z = design[keep], trace.height_m[used][keep]
    var = _noise_variance(z - a @ _weighted_lstsq(a, z, np.ones(z.shape[0])), dt)
    info = a.T @ a / max(var, 1e-12)
    info[-1, -1] += WEATHER_SLOPE_SIGMA_M_S**-2
    cov = np.linalg.inv(info)
    slope = float((cov @ (a.T @ z) / max(var, 1e-12))[-1])
    return slope, max(math.sqrt(float(cov[-1, -1])), WEATHER_SLOPE_FLOOR_M_S)


def fit_level_change(
    trace: RawTrace,
    transition_s: tuple[float, float],
    floor_s: tuple[float, float],
    window_s: float = 120.0,
    gap_s: float = 1.0,
    step_m: float = 0.25,
    weather: tuple[float, float] = (0.0, WEATHER_SLOPE_SIGMA_M_S),
) -> LevelChange:
    """Height change across a transition (its start and end, `transition_s`, in the trace's
    seconds) from the raw barometer samples on both sides, which lie within `floor_s` (the end
    of the transition before and the start of the one after).

    One least-squares fit over up to `window_s` of floor on each side (trimmed to the same
    length, ending `gap_s` from the transition): a level before, a level after, and one shared
    slope for the weather drift. Shared, because the weather does not change across a ride;
    symmetric, because then a curving drift (its quadratic part) cancels in the difference.
    Door and HVAC steps are found on the 1 s running median (a robust fit of the same model,
    residuals over `step_m`) and left out, with a second either side. The fit runs on the raw
    samples, not the floors stage's smoothed trace: its pulse removal leaves centimetres of step
    behind, which a level over a minute still sees. The sigma is the fit's, scaled up when the
    residuals are correlated over a second (a phone's barometer wanders). `weather`: the slope's
    prior, mean and sigma (m/s; `weather_slope` reads it off the visits around).
    """
    t, raw, med, dt = trace.times_s, trace.height_m, trace.median_m, trace.dt_s
    lo, hi = floor_s
    ta, tb = transition_s[0] - gap_s, transition_s[1] + gap_s
    side = float(min(ta - max(lo, ta - window_s), min(hi, tb + window_s) - tb))
    if side < MIN_SIDE_S:
        return LevelChange(None, 0.0, max(side, 0.0), 0.0, f"less than {MIN_SIDE_S:.0f} s of floor on one side")
    before = (t >= ta - side) & (t <= ta)
    after = (t >= tb) & (t <= tb + side)
    used = before | after
    is_after = after[used].astype(np.float64)
    design = np.stack([1.0 - is_after, is_after, t[used] - 0.5 * (ta + tb)], axis=1)

    step = _steps(design, med[used], (med[before], med[after]), dt, step_m)
    keep = ~step
    if np.count_nonzero(keep & (is_after == 0)) < 10 or np.count_nonzero(keep & (is_after == 1)) < 10:
        return LevelChange(None, 0.0, side, float(step.mean()), "door/HVAC steps cover one side")

    a, z = design[keep], raw[used][keep]
    x = _weighted_lstsq(a, z, np.ones(z.shape[0]))
    var = _noise_variance(z - a @ x, dt)
    # The shared slope, with the weather's prior: over a long transition (a stair walk with
    # stands on its landings, minutes) the slope is extrapolated across it, and a floor's own
    # wander on one side (gusts correlated over tens of seconds, a zone near a pressurised
    # stairwell) taken for weather moved a 9 m climb by 1.9 m.
    info = a.T @ a / max(var, 1e-12)
    info[2, 2] += weather[1] ** -2
    cov = np.linalg.inv(info)
    x = cov @ (a.T @ z / max(var, 1e-12) + np.array([0.0, 0.0, weather[0] / weather[1] ** 2]))
    sigma = math.sqrt(max(float(cov[0, 0] + cov[1, 1] - 2 * cov[0, 1]), 0.0))
    return LevelChange(float(x[1] - x[0]), sigma, side, float(step.mean()), "ok")


def _steps(design: F64, y: F64, sides: tuple[F64, F64], dt: float, step_m: float) -> npt.NDArray[np.bool_]:
    """Door and HVAC steps in the running median `y`: a robust (Tukey) fit of the model, then
    every sample further than `step_m` from it, with a second either side. `sides`: the running
    median before and after, for the fit's start."""
    return _robust_outliers(design, y, np.array([robust_level(sides[0]), robust_level(sides[1]), 0.0]), dt,
                            step_m)


def _robust_outliers(design: F64, y: F64, x: F64, dt: float, step_m: float) -> npt.NDArray[np.bool_]:
    """Samples of `y` further than `step_m` from a robust (Tukey) fit of `design` started at `x`,
    with a second either side."""
    for _ in range(20):
        r = y - design @ x
        c = 4.685 * max(MAD_TO_SIGMA * float(np.median(np.abs(r))), 0.02)
        x = _weighted_lstsq(design, y, np.clip(1.0 - (r / c) ** 2, 0.0, None) ** 2)
    pad = max(1, round(1.0 / dt))
    return np.asarray(ndimage.binary_dilation(np.abs(y - design @ x) > step_m, np.ones(2 * pad + 1, dtype=bool)))


def _noise_variance(resid: F64, dt: float) -> float:
    """The residuals' variance, raised where they are correlated over one of BLOCKS_S."""
    var = float(resid.var())
    white = var
    for block_s in BLOCKS_S:
        # Correlated over the block: its means vary more than white noise's would.
        per_block = max(1, round(block_s / dt))
        n_blocks = resid.shape[0] // per_block
        if n_blocks >= 8 and white > 0:
            blocks = resid[: n_blocks * per_block].reshape(n_blocks, per_block).mean(axis=1)
            var = max(var, float(blocks.var()) * per_block)
    return var


def _weighted_lstsq(a: F64, y: F64, w: F64) -> F64:
    """Weighted least squares; lstsq, so all-zero weights on one side do not raise."""
    sw = np.sqrt(w)
    return np.asarray(np.linalg.lstsq(a * sw[:, None], y * sw, rcond=None)[0], dtype=np.float64)
