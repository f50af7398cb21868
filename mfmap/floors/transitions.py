"""Transitions from the filtered trace: runs of vertical speed, the level change across each, and
the checks that make a run a floor change (height, speed, acceleration, not a pressure step)."""

from __future__ import annotations

import numpy as np

from mfmap.floors.config import FilterMethod, FloorsConfig
from mfmap.floors.filters import LEVEL_MODE_HALF_WIDTH_M, robust_level
from mfmap.floors.motion import MotionEvidence
from mfmap.floors.runs import (
    Run,
    after_leading_step,
    join_partial_runs,
    merge_stays,
    motion_runs,
    run_kind,
    stay_test,
    step_like,
)
from mfmap.floors.timing import refine_joined
from mfmap.floors.trace import FilteredTrace
from mfmap.types import F64, TransitionKind

# Height changes at least this fraction of a floor, but not a floor, are reported as warnings.
_NEAR_MISS_FRACTION = 0.6


def robust_line_at(times_s: F64, values: F64, at_s: float, scale_m: float = LEVEL_MODE_HALF_WIDTH_M) -> float:
    """Height at `at_s` of a line fitted to a floor visit, door/HVAC steps weighted out.

    A line, because weather drift (up to 200 Pa/h, 5 mm/s apparent) moves a long visit's level;
    Tukey-biweight reweighting from the densest level, because steps cover part of the visit.
    """
    if values.shape[0] < 10:
        return float(np.median(values))
    t = times_s - at_s
    intercept, slope = robust_level(values, scale_m), 0.0
    c = 3.0 * scale_m
    for _ in range(10):
        r = values - (intercept + slope * t)
        w = np.clip(1.0 - (r / c) ** 2, 0.0, None) ** 2
        sw = float(w.sum())
        if sw < 3.0:
            break
        tm = float((w * t).sum()) / sw
        vm = float((w * values).sum()) / sw
        var_t = float((w * (t - tm) ** 2).sum())
        slope = float((w * (t - tm) * (values - vm)).sum()) / var_t if var_t > 1e-9 else 0.0
        intercept = vm - slope * tm
    return float(intercept)


def _levels_across(runs: list[Run], trace: FilteredTrace, cfg: FloorsConfig) -> list[tuple[float, float]]:
    """Level just before and just after each run: a robust line over the neighbouring visit
    (at most level_window_s of it), evaluated at the run's edge."""
    level = trace.level_smooth_m if trace.level_smooth_m is not None else trace.level_m
    n = level.shape[0]
    dt_s = trace.grid.dt_s
    w = max(1, round(cfg.transitions.level_window_s / dt_s))
    sub = max(1, round(0.5 / dt_s))  # the smoothed level is correlated over ~1 s anyway
    times_s = np.arange(n, dtype=np.float64) * dt_s
    out = []
    for k, run in enumerate(runs):
        lo = max(runs[k - 1].i1 if k > 0 else 0, run.i0 - w)
        hi = min(runs[k + 1].i0 if k + 1 < len(runs) else n, run.i1 + w)
        if run.i0 > lo:
            sl = slice(lo, run.i0, sub)
            before = robust_line_at(times_s[sl], level[sl], run.i0 * dt_s)
        else:
            before = float(trace.filtered_m[run.i0])
        if hi > run.i1:
            sl = slice(run.i1, hi, sub)
            after = robust_line_at(times_s[sl], level[sl], (run.i1 - 1) * dt_s)
        else:
            after = float(trace.filtered_m[run.i1 - 1])
        out.append((before, after))
    return out


def find_transitions(
    trace: FilteredTrace, cfg: FloorsConfig, motion: MotionEvidence | None = None, start_ns: int = 0
) -> tuple[list[Run], list[float], list[tuple[float, float]], list[str]]:
    """Transitions as runs, the level change across each, their (start, end) in grid seconds,
    and warnings about height changes that were not counted."""
    min_h = cfg.min_floor_height_m
    dt_s = trace.grid.dt_s
    is_visit = stay_test(motion, cfg, dt_s, start_ns)
    travel_known = motion is not None and motion.speed_m_s is not None
    runs = join_partial_runs(motion_runs(trace, cfg), trace, cfg, is_visit)
    warnings: list[str] = []
    cache: dict[tuple[int, ...], tuple[float, float]] = {}  # fits of runs whose window is unchanged
    # Dropping a run widens its neighbours' level windows, so repeat until nothing changes.
    while True:
        levels = _levels_across(runs, trace, cfg)
        changes = [after - before for before, after in levels]
        times = _times(runs, trace, cfg, motion, start_ns, cache)
        speeds, feasible = _feasible(runs, changes, times, trace, cfg)
        # First the climbs and rides that are one transition (a level between them no visit),
        # a partial one among them too: a half flight that alone is no floor change belongs to
        # the climb, not to the floor it is dropped onto.
        # Only where odometry measures the travel between: a phone's trace (no motion) has
        # partial wiggles next to real visits, and joining one shortens the visit it sits in.
        climbs = [ok and (abs(c) >= min_h or travel_known) for c, ok in zip(changes, feasible, strict=True)]
        merged = merge_stays(runs, times, dt_s, is_visit, climbs)
        if merged is not None:
            runs = merged
            continue
        keep = [abs(c) >= min_h and ok for c, ok in zip(changes, feasible, strict=True)]
        if all(keep):
            times = [after_leading_step(r, t, trace, min_h) for r, t in zip(runs, times, strict=True)]
            return runs, changes, times, warnings
        warnings += _not_counted(changes, times, speeds, keep, min_h)
        runs = [r for r, ok in zip(runs, keep, strict=True) if ok]


def _times(
    runs: list[Run],
    trace: FilteredTrace,
    cfg: FloorsConfig,
    motion: MotionEvidence | None,
    start_ns: int,
    cache: dict[tuple[int, ...], tuple[float, float]],
) -> list[tuple[float, float]]:
    """Each run's (start, end) in grid seconds: the ramp fit, its kind hinted by the motion."""
    dt_s = trace.grid.dt_s
    if cfg.filter.method is FilterMethod.RTS:
        hints: list[TransitionKind | None] | None = None
        if motion is not None:
            kinds = [run_kind(motion, r, dt_s, start_ns) for r in runs]
            hints = [None if h is TransitionKind.UNKNOWN else h for h in kinds]
        return refine_joined(runs, trace, hints, cache)
    # The LeGO-LOAM elevator paper's baseline: where the smoothed speed crosses the stop threshold.
    return [(r.i0 * dt_s, (r.i1 - 1) * dt_s) for r in runs]


def _feasible(
    runs: list[Run],
    changes: list[float],
    times: list[tuple[float, float]],
    trace: FilteredTrace,
    cfg: FloorsConfig,
) -> tuple[list[float], list[bool]]:
    """Each run's mean vertical speed, and whether a ride or a climb could make its change."""
    min_h = cfg.min_floor_height_m
    dt_s = trace.grid.dt_s
    speeds = [abs(c) / max(b - a, 1e-3) for c, (a, b) in zip(changes, times, strict=True)]
    # How long each took for the acceleration's bound: the fitted ramp, or the run of
    # vertical speed when that is longer. A closed cabin's pressure leads its height (the
    # moving cabin's piston pressure): the ramp fitted to a 4 m ride of 6 s can come out 3 s.
    spans = [max(b - a, sum(i1 - i0 for i0, i1 in r.parts()) * dt_s)
             for r, (a, b) in zip(runs, times, strict=True)]
    # Rest to rest, a height change d takes at least 2 sqrt(d / a_max) even at full thrust;
    # a pair of pressure steps (door slammed, then the HVAC) is much faster.
    feasible = [
        v <= cfg.transitions.max_vertical_speed_m_s
        and d >= 2.0 * np.sqrt(abs(c) / cfg.transitions.max_vertical_accel_m_s2)
        and not step_like(r, c, trace, min_h)
        for r, c, d, v in zip(runs, changes, spans, speeds, strict=True)
    ]
    return speeds, feasible


def _not_counted(
    changes: list[float], times: list[tuple[float, float]], speeds: list[float], keep: list[bool],
    min_h: float,
) -> list[str]:
    """Warnings for the runs dropped that changed the height by a floor or nearly."""
    warnings: list[str] = []
    for change, (a, _), v, ok in zip(changes, times, speeds, keep, strict=True):
        if ok:
            continue
        if abs(change) >= min_h:
            warnings.append(
                f"an abrupt pressure step ({change:+.2f} m at {v:.1f} m/s) at {a:.1f} s into the "
                f"trace is faster than a ride or a climb: not counted as a floor change"
            )
        elif abs(change) >= _NEAR_MISS_FRACTION * min_h:
            warnings.append(
                f"a height change of {change:+.2f} m at {a:.1f} s into the trace is below "
                f"min_floor_height_m ({min_h:g} m): not counted as a floor change"
            )
    return warnings
