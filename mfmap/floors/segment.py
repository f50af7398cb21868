"""Floors from the barometer: height trace -> transitions -> floor levels -> floor ids.

The steps, in order (`segment_pressure`):
1. pressure -> height with the hypsometric relation (mfmap.baro), resampled onto a uniform grid;
2. spike rejection (Hampel), removal of short door/HVAC pressure pulses (grey-scale opening and
   closing, checked for abrupt edges and level flanks), then the offline RTS smoother with
   steady-state gains (or, as the baseline, the LeGO-LOAM elevator paper's 30-sample sliding mean);
3. runs of sustained vertical speed; cancelling up/down pairs (pulses) dropped; partial runs
   split by a pause (a stair landing) joined, closest first; a run is a transition when the
   level changes across it by >= min_floor_height_m at a physically possible speed and
   acceleration; its start and end come from a flat-ramp-flat least-squares fit (soft corners
   for elevators), and for stairs from the odometry's standstills when the robot has them;
4. the level change across each transition is what places floors, so weather drift between
   transitions cannot move a floor: visits are clustered by the chained changes of a drift-aware
   robust line over each neighbouring visit (a revisit is the same floor), and the elevations
   are the least-squares fit of every transition's change from one fit over the raw trace
   either side (mfmap.floors.levels), start floor at 0.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from mfmap.baro import height_from_pressure
from mfmap.errors import MissingDataError
from mfmap.floors.config import FilterMethod, FloorsConfig
from mfmap.floors.filters import (
    LEVEL_MODE_HALF_WIDTH_M,
    Grid,
    fit_ramp,
    hampel,
    remove_transients,
    resample_uniform,
    robust_level,
    robust_noise_sigma,
    rts_smooth,
    running_median_1s,
    sliding_mean,
    step_size,
)
from mfmap.floors.levels import fit_level_change, trace_of_grid
from mfmap.floors.motion import MotionEvidence
from mfmap.types import Floor, FloorSegmentation, PressureSeries, Transition, TransitionKind

logger = logging.getLogger(__name__)

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

MIN_SAMPLES = 10
# Runs of vertical motion smaller than this fraction of a floor are noise, a swinging phone or a
# door/HVAC pressure step: dropped before partial runs are joined.
_NOISE_RUN_FRACTION = 0.3
# A movement the other way at least this big between two runs means they are not one climb.
_BLOCK_RUN_FRACTION = 0.15
# Height changes at least this fraction of a floor, but not a floor, are reported as warnings.
_NEAR_MISS_FRACTION = 0.6
# Pressure pulses up to this fraction of a floor are doors or HVAC; taller ones are visits.
_MAX_PULSE_FRACTION = 0.75
_MOVING_FRACTION_STAIRS = 0.5
# Chi-square gain (in units of the block noise variance) that justifies soft ramp corners.
_SOFT_CORNER_CHI2 = 12.0
# Faster than people or robots climb stairs: an elevator, whose speed ramps up and down.
_ELEVATOR_SPEED_M_S = 0.6


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


@dataclass
class _Run:
    i0: int  # first grid index
    i1: int  # one past the last grid index
    sign: int
    change_m: float = 0.0
    pieces: tuple[tuple[int, int], ...] = ()  # (i0, i1) of the runs joined into this one

    def parts(self) -> tuple[tuple[int, int], ...]:
        return self.pieces or ((self.i0, self.i1),)


def filter_height(grid: Grid, cfg: FloorsConfig) -> FilteredTrace:
    """Spike rejection and smoothing of a uniformly sampled height trace."""
    values = grid.values
    dt_s = grid.dt_s
    if cfg.method is FilterMethod.SLIDING_MEAN:
        filtered = sliding_mean(values, cfg.sliding_window_samples)
        speed = np.gradient(filtered, dt_s) if values.shape[0] > 1 else np.zeros_like(filtered)
        noise = robust_noise_sigma(values)
        return FilteredTrace(grid, values, filtered, speed, filtered, noise, 0)
    half = max(1, round(cfg.spike_window_s / dt_s))
    despiked, spikes = hampel(values, half, cfg.spike_threshold_sigma)
    median = running_median_1s(despiked, dt_s)
    despiked, _pulses = remove_transients(
        despiked, dt_s, cfg.max_transient_s, _MAX_PULSE_FRACTION * cfg.min_floor_height_m, median
    )
    if cfg.noise_m is not None:
        noise = cfg.noise_m
    else:
        one_second = max(1, round(1.0 / dt_s))
        noise = max(robust_noise_sigma(despiked), robust_noise_sigma(despiked, one_second))
    # A quantised, nearly noiseless sensor would give a zero sigma and a filter that smooths
    # nothing; a centimetre floor keeps the smoother sensible.
    noise = max(noise, 0.01)
    filtered, speed = rts_smooth(despiked, dt_s, noise, cfg.accel_noise_m_s2)
    # Steps are judged on the median before pulse removal: a removed pulse no longer matters.
    return FilteredTrace(
        grid, despiked, filtered, speed, despiked, noise, spikes, step_size(median, dt_s), running_median_1s(despiked, dt_s)
    )


def _runs_of(mask: npt.NDArray[np.bool_]) -> list[tuple[int, int]]:
    padded = np.concatenate(([0], mask.astype(np.int8), [0]))
    edges = np.flatnonzero(np.diff(padded))
    return list(zip(edges[0::2].tolist(), edges[1::2].tolist(), strict=True))


def _motion_runs(trace: FilteredTrace, cfg: FloorsConfig) -> list[_Run]:
    """Runs of one-signed vertical speed above the stop speed that reach the minimum speed."""
    v = trace.speed_m_s
    runs: list[_Run] = []
    for sign in (1, -1):
        sv = sign * v
        core = np.concatenate(([0], np.cumsum(sv > cfg.min_vertical_speed_m_s)))
        for i0, i1 in _runs_of(sv > cfg.stop_vertical_speed_m_s):
            if core[i1] - core[i0] > 0:
                runs.append(_Run(i0, i1, sign))
    runs.sort(key=lambda r: r.i0)
    h = trace.filtered_m
    for run in runs:
        run.change_m = float(h[run.i1 - 1] - h[run.i0])
    return runs


def _drop_pulses(runs: list[_Run], trace: FilteredTrace, cfg: FloorsConfig) -> list[_Run]:
    """Drop pairs of opposite runs that cancel within max_transient_s: a pulse, not a climb.

    remove_transients misses pulses whose edges the noise blurs; as runs they are still a
    partial change followed at once by its undoing.
    """
    min_h = cfg.min_floor_height_m
    max_len = round(cfg.max_transient_s / trace.grid.dt_s)
    drop: set[int] = set()
    for k in range(len(runs) - 1):
        a, b = runs[k], runs[k + 1]
        if k in drop or a.sign == b.sign or b.i1 - a.i0 > max_len + (a.i1 - a.i0) + (b.i1 - b.i0):
            continue
        largest = max(abs(a.change_m), abs(b.change_m))
        # Both edges steps: a stairwell's door crossed (a step) just before a climb's first
        # partial flight (a ramp) can cancel it as well as a pulse's edges do.
        if (largest < min_h and abs(a.change_m + b.change_m) < 0.5 * largest
                and _step_like(a, a.change_m, trace, min_h) and _step_like(b, b.change_m, trace, min_h)):
            drop.update((k, k + 1))
    return [r for k, r in enumerate(runs) if k not in drop]


# Is the level held between grid indices i0 and i1 a floor visit? (`_stay_test`)
StayTest = Callable[[int, int], bool]


def _stay_test(motion: MotionEvidence | None, cfg: FloorsConfig, dt_s: float, start_ns: int) -> StayTest:
    """A level held between two height changes is a floor visit when the robot goes somewhere on
    it: with odometry, at least landing_max_path_m of travel (a switch-back's half landing or a
    floor passed through on the stairs is a turn and a step or two across; in an elevator stop the
    robot stays in the cabin); without, at least min_visit_s, and not standing still all along
    by the IMU."""

    def is_visit(i0: int, i1: int) -> bool:
        a, b = start_ns + round(i0 * dt_s * 1e9), start_ns + round(i1 * dt_s * 1e9)
        path = motion.path_m(a, b) if motion is not None else None
        if path is not None:
            return path >= cfg.landing_max_path_m
        if (i1 - i0) * dt_s < cfg.min_visit_s:
            return False
        moving = motion.fraction_moving(a, b) if motion is not None else None
        return moving is None or moving >= 0.1

    return is_visit


def _join_partial_runs(
    runs: list[_Run], trace: FilteredTrace, cfg: FloorsConfig, is_visit: StayTest | None = None
) -> list[_Run]:
    """Join same-direction runs split by a pause (a stair landing) when one is partial: a short
    pause always, a longer one when the level between is no floor visit (`is_visit`).

    Closest pairs are joined first, so a partial climb goes with the neighbour it belongs to
    rather than with whichever came first; a movement the other way in between (a phone lifted
    and lowered on a floor) keeps two runs apart.
    """
    min_h = cfg.min_floor_height_m
    blockers = [r for r in runs if abs(r.change_m) >= _BLOCK_RUN_FRACTION * min_h]
    kept = [r for r in runs if abs(r.change_m) >= _NOISE_RUN_FRACTION * min_h]
    kept = [_Run(r.i0, r.i1, r.sign, r.change_m) for r in _drop_pulses(kept, trace, cfg)]
    max_gap = round(cfg.max_pause_s / trace.grid.dt_s)
    h = trace.filtered_m

    def abrupt(r: _Run) -> bool:
        # Half the change within 0.3 s: a pressure step, not a flight of stairs.
        if trace.jump_m is None or abs(r.change_m) >= min_h:
            return False
        return float(np.max(r.sign * trace.jump_m[r.i0 : r.i1])) >= 0.5 * abs(r.change_m)

    def joinable(a: _Run, b: _Run) -> bool:
        if a.sign != b.sign:
            return False
        if b.i0 - a.i1 > max_gap and (is_visit is None or is_visit(a.i1, b.i0)
                                      or _step_like(a, a.change_m, trace, min_h)
                                      or _step_like(b, b.change_m, trace, min_h)):
            # Across a long stand only climbs: a pressurised stairwell's pressure mixes in
            # over a second as the robot walks out of it, a step the pause-free climb is not.
            return False
        if abs(a.change_m) >= min_h and abs(b.change_m) >= min_h:
            return False
        if abrupt(a) or abrupt(b):
            return False
        return not any(r.sign != a.sign and a.i1 <= r.i0 and r.i1 <= b.i0 for r in blockers)

    while True:
        pairs = [(b.i0 - a.i1, k) for k, (a, b) in enumerate(itertools.pairwise(kept)) if joinable(a, b)]
        if not pairs:
            return kept
        _, k = min(pairs)
        a, b = kept[k], kept[k + 1]
        kept[k] = _Run(a.i0, b.i1, a.sign, float(h[b.i1 - 1] - h[a.i0]), a.parts() + b.parts())
        del kept[k + 1]


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


def _levels_across(runs: list[_Run], trace: FilteredTrace, cfg: FloorsConfig) -> list[tuple[float, float]]:
    """Level just before and just after each run: a robust line over the neighbouring visit
    (at most level_window_s of it), evaluated at the run's edge."""
    level = trace.level_smooth_m if trace.level_smooth_m is not None else trace.level_m
    n = level.shape[0]
    dt_s = trace.grid.dt_s
    w = max(1, round(cfg.level_window_s / dt_s))
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
) -> tuple[list[_Run], list[float], list[tuple[float, float]], list[str]]:
    """Transitions as runs, the level change across each, their (start, end) in grid seconds,
    and warnings about height changes that were not counted."""
    min_h = cfg.min_floor_height_m
    dt_s = trace.grid.dt_s
    is_visit = _stay_test(motion, cfg, dt_s, start_ns)
    travel_known = motion is not None and motion.speed_m_s is not None
    runs = _join_partial_runs(_motion_runs(trace, cfg), trace, cfg, is_visit)
    warnings: list[str] = []
    cache: dict[tuple[int, ...], tuple[float, float]] = {}  # fits of runs whose window is unchanged
    # Dropping a run widens its neighbours' level windows, so repeat until nothing changes.
    while True:
        levels = _levels_across(runs, trace, cfg)
        changes = [after - before for before, after in levels]
        if cfg.method is FilterMethod.RTS:
            hints: list[TransitionKind | None] | None = None
            if motion is not None:
                kinds = [_run_kind(motion, r, dt_s, start_ns) for r in runs]
                hints = [None if h is TransitionKind.UNKNOWN else h for h in kinds]
            times = _refine_joined(runs, trace, hints, cache)
        else:  # the LeGO-LOAM elevator paper's baseline: where the smoothed speed crosses the stop threshold
            times = [(r.i0 * dt_s, (r.i1 - 1) * dt_s) for r in runs]
        speeds = [abs(c) / max(b - a, 1e-3) for c, (a, b) in zip(changes, times, strict=True)]
        # How long each took for the acceleration's bound: the fitted ramp, or the run of
        # vertical speed when that is longer. A closed cabin's pressure leads its height (the
        # moving cabin's piston pressure): the ramp fitted to a 4 m ride of 6 s came out 3 s.
        spans = [max(b - a, sum(i1 - i0 for i0, i1 in r.parts()) * dt_s)
                 for r, (a, b) in zip(runs, times, strict=True)]
        # Rest to rest, a height change d takes at least 2 sqrt(d / a_max) even at full thrust;
        # a pair of pressure steps (door slammed, then the HVAC) is much faster.
        feasible = [
            v <= cfg.max_vertical_speed_m_s
            and d >= 2.0 * np.sqrt(abs(c) / cfg.max_vertical_accel_m_s2)
            and not _step_like(r, c, trace, min_h)
            for r, c, d, v in zip(runs, changes, spans, speeds, strict=True)
        ]
        # First the climbs and rides that are one transition (a level between them no visit),
        # a partial one among them too: a half flight that alone is no floor change belongs to
        # the climb, not to the floor it is dropped onto.
        # Only where odometry measures the travel between: a phone's trace (no motion) has
        # partial wiggles next to real visits, and joining one shortens the visit it sits in.
        climbs = [ok and (abs(c) >= min_h or travel_known) for c, ok in zip(changes, feasible, strict=True)]
        merged = _merge_stays(runs, times, dt_s, is_visit, climbs)
        if merged is not None:
            runs = merged
            continue
        keep = [abs(c) >= min_h and ok for c, ok in zip(changes, feasible, strict=True)]
        if all(keep):
            times = [_after_leading_step(r, t, trace, min_h) for r, t in zip(runs, times, strict=True)]
            return runs, changes, times, warnings
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
        runs = [r for r, ok in zip(runs, keep, strict=True) if ok]


def _step_like(run: _Run, change_m: float, trace: FilteredTrace, min_h: float) -> bool:
    """A partial change with half of it within a second: a pressure step (a door, the zone of
    a pressurised stairwell mixing in over a second or so), not a flight of stairs (a third of a
    metre a second at most)."""
    level = trace.level_smooth_m
    if level is None or abs(change_m) >= min_h or abs(change_m) == 0:
        return False
    half = max(1, round(0.5 / trace.grid.dt_s))
    i0, i1 = max(run.i0 - half, half), min(run.i1 + half, level.shape[0] - half)
    if i1 <= i0:
        return False
    idx = np.arange(i0, i1)
    jump = np.sign(change_m) * (level[idx + half] - level[idx - half])
    return bool(float(np.max(jump)) >= 0.5 * abs(change_m))


def _after_leading_step(run: _Run, times: tuple[float, float], trace: FilteredTrace,
                        min_h: float) -> tuple[float, float]:
    """A joined transition whose first part is a pressure step (the stairwell's door crossed,
    its own pressure, and a stand before the flight) starts where the next part does: the
    height does not change before it."""
    parts = run.parts()
    if len(parts) < 2 or trace.level_smooth_m is None:
        return times
    (i0, i1), (j0, _) = parts[0], parts[1]
    level = trace.level_smooth_m
    change = float(level[min(i1, level.shape[0] - 1)] - level[i0])
    if not _step_like(_Run(i0, i1, run.sign, change), change, trace, min_h):
        return times
    return (max(times[0], j0 * trace.grid.dt_s), times[1])


def _merge_stays(runs: list[_Run], times: list[tuple[float, float]], dt_s: float,
                 is_visit: StayTest, climbs: list[bool]) -> list[_Run] | None:
    """Two climbs or rides in one direction whose level between is no floor visit (a floor
    passed through on the stairs, an elevator stop with the robot in the cabin, a half landing)
    as one, from the floor left to the floor reached; None when there are none. Only runs that
    are `climbs` (a physically possible speed: a pressure step is not part of a climb).
    The first such pair only: the levels and times are fitted again before the next. Up and
    straight back down stays two transitions: taken for one, a floor the robot did reach
    would vanish."""
    for k in range(len(runs) - 1):
        a, b = runs[k], runs[k + 1]
        if a.sign != b.sign or not (climbs[k] and climbs[k + 1]):
            continue
        i0 = max(a.i1, round(times[k][1] / dt_s))
        i1 = max(i0, min(b.i0, round(times[k + 1][0] / dt_s)))
        if not is_visit(i0, i1):
            joined = _Run(a.i0, b.i1, a.sign, a.change_m + b.change_m, a.parts() + b.parts())
            return [*runs[:k], joined, *runs[k + 2:]]
    return None


def _run_kind(motion: MotionEvidence, run: _Run, dt_s: float, start_ns: int) -> TransitionKind:
    """Stairs or elevator by the motion while the height changes: a joined transition's stands on
    landings and stops in between are left out (on stairs they would make it look like a ride)."""
    moving = total = 0.0
    for i0, i1 in run.parts():
        a, b = start_ns + round(i0 * dt_s * 1e9), start_ns + round(i1 * dt_s * 1e9)
        share = motion.fraction_moving(a, b)
        if share is not None:
            moving += share * (i1 - i0)
            total += i1 - i0
    if total == 0:
        return TransitionKind.UNKNOWN
    return TransitionKind.STAIRS if moving / total >= _MOVING_FRACTION_STAIRS else TransitionKind.ELEVATOR


def _refine_joined(
    runs: list[_Run],
    trace: FilteredTrace,
    hints: list[TransitionKind | None] | None,
    cache: dict[tuple[int, ...], tuple[float, float]] | None = None,
) -> list[tuple[float, float]]:
    """Fit times of transitions; one joined over a landing starts where its first flight
    starts and ends where its last flight ends, each fitted on its own."""
    h = trace.filtered_m
    units: list[_Run] = []
    unit_hints: list[TransitionKind | None] = []
    span: list[tuple[int, int]] = []
    for k, run in enumerate(runs):
        parts = run.parts()
        chosen = [parts[0]] if len(parts) == 1 else [parts[0], parts[-1]]
        span.append((len(units), len(units) + len(chosen) - 1))
        for i0, i1 in chosen:
            units.append(_Run(i0, i1, run.sign, float(h[i1 - 1] - h[i0])))
            unit_hints.append(hints[k] if hints is not None else None)
    times = refine_timing(units, trace, unit_hints if hints is not None else None, cache=cache)
    return [(times[a][0], times[b][1]) for a, b in span]


@dataclass(frozen=True)
class _RampFit:
    """Least-squares ramp search over one transition's window (block means at ~10 Hz)."""

    times: F64
    values: F64
    s0: float  # the speed threshold's start and end: the search centres
    e0: float

    def best_of(self, starts: F64, ends: F64, corners: F64) -> tuple[float, float, float, float]:
        S, E, C = (g.ravel() for g in np.meshgrid(starts, ends, corners, indexing="ij"))
        ok = (E - S >= 0.5) & (self.times[0] <= S) & (self.times[-1] >= E)
        if not np.any(ok):
            return self.s0, self.e0, 0.0, np.inf
        S, E, C = S[ok], E[ok], C[ok]
        i, _, _, sse = fit_ramp(self.times, self.values, S, E, C)
        return float(S[i]), float(E[i]), float(C[i]), sse

    def search(self, corners: F64, search_s: float) -> tuple[float, float, float]:
        """Coarse to fine: 1 s steps over +-search_s, then 0.25 s, then 0.1 s."""
        t1, t2, c, _ = self.best_of(
            np.arange(self.s0 - search_s, self.s0 + search_s + 1e-9, 1.0),
            np.arange(self.e0 - search_s, self.e0 + search_s + 1e-9, 1.0),
            corners,
        )
        lo_c, hi_c = float(corners.min()), float(corners.max())
        sse = np.inf
        for half, step_s in ((1.0, 0.25), (0.2, 0.1)):
            near = np.unique(np.clip(np.arange(c - 0.1, c + 0.1 + 1e-9, 0.05), lo_c, hi_c))
            t1, t2, c, sse = self.best_of(
                np.arange(t1 - half, t1 + half + 1e-9, step_s),
                np.arange(t2 - half, t2 + half + 1e-9, step_s),
                near if corners.shape[0] > 1 else corners,
            )
        return t1, t2, sse


def refine_timing(
    runs: list[_Run],
    trace: FilteredTrace,
    hints: list[TransitionKind | None] | None = None,
    search_s: float = 4.0,
    cache: dict[tuple[int, ...], tuple[float, float]] | None = None,
) -> list[tuple[float, float]]:
    """Start and end (s on the grid) of each transition from a flat-ramp-flat fit.

    The smoother spreads a ride over its kernel, so the speed threshold starts it early and
    ends it late; the fit puts the ends where the height really starts and stops changing.
    Trapezoid speed profiles from straight stairs to a short elevator ride.
    """
    dt_s = trace.grid.dt_s
    step = max(1, round(0.1 / dt_s))
    out: list[tuple[float, float]] = []
    for k, run in enumerate(runs):
        s0, e0 = run.i0 * dt_s, (run.i1 - 1) * dt_s
        lo_s = max(runs[k - 1].i1 * dt_s if k > 0 else 0.0, s0 - 2 * search_s)
        lo_s = max(lo_s, out[-1][1] if out else 0.0)
        hi_s = min(runs[k + 1].i0 * dt_s if k + 1 < len(runs) else np.inf, e0 + 2 * search_s)
        i_lo, i_hi = int(np.ceil(lo_s / dt_s)), min(int(hi_s / dt_s) + 1, trace.level_m.shape[0])
        m = (i_hi - i_lo) // step
        if m < 4:
            out.append((s0, e0))
            continue
        hint = hints[k] if hints is not None else None
        key = (run.i0, run.i1, i_lo, i_hi, -1 if hint is None else list(TransitionKind).index(hint))
        if cache is not None and key in cache:
            out.append(cache[key])
            continue
        # Block means at ~10 Hz: the fit needs the shape, not every 50 Hz sample.
        values = trace.level_m[i_lo : i_lo + m * step].reshape(m, step).mean(axis=1)
        times = (i_lo + step * np.arange(m) + (step - 1) / 2.0) * dt_s
        fit = _RampFit(times, values, s0, e0)
        # An elevator speeds up and slows down gently (soft corners, a jerk-limited profile); a
        # climb keeps a steady pace (a straight ramp). Soft corners trade against a wider ramp,
        # so on noise they would widen a straight climb: the robot's motion decides when it is
        # known, else the speed (no one climbs stairs at elevator speed), else the fit itself.
        t1, t2, sse_straight = fit.search(np.zeros(1), search_s)
        fast = abs(run.change_m) / max(t2 - t1, 1e-6) > _ELEVATOR_SPEED_M_S
        if hint is TransitionKind.ELEVATOR or (hint is None and fast):
            t1, t2, _ = fit.search(np.linspace(0.1, 0.5, 5), search_s)
        elif hint is None:
            c1, c2, sse_soft = fit.search(np.linspace(0.0, 0.5, 6), search_s)
            block_var = max(trace.noise_m**2 / step, 1e-6)
            if (sse_straight - sse_soft) / block_var > _SOFT_CORNER_CHI2:
                t1, t2 = c1, c2
        out.append((t1, t2))
        if cache is not None:
            cache[key] = (t1, t2)
    return out


def _cluster_visits(changes: list[float], tolerance_m: float) -> list[int]:
    """Cluster label per visit: chain each transition's change from the current floor's estimate.

    Chaining from the floor's running estimate (not from the previous chained value) keeps
    errors from accumulating over many transitions.
    """
    labels = [0]
    sums = [0.0]
    counts = [1]
    for change in changes:
        cur = labels[-1]
        estimate = sums[cur] / counts[cur] + change
        means = np.array(sums) / np.array(counts)
        dist = np.abs(means - estimate)
        dist[cur] = np.inf  # a floor change never ends on the floor it left
        best = int(np.argmin(dist))
        if dist[best] < tolerance_m:
            labels.append(best)
            sums[best] += estimate
            counts[best] += 1
        else:
            labels.append(len(sums))
            sums.append(estimate)
            counts.append(1)
    return _merge_clusters(labels, changes, tolerance_m)


def _merge_clusters(labels: list[int], changes: list[float], tolerance_m: float) -> list[int]:
    """Floors the chain made twice: two labels whose least-squares elevations (every transition
    weighed) are within the tolerance, and that no transition joins (a floor change is at
    least a floor), are one floor. The chain decides each revisit from the floor it left alone,
    so a few decimetres of error per transition (a phone's barometer) can carry a revisit just
    past the tolerance; the elevations of all transitions together place it again."""
    labels = list(labels)
    while max(labels) > 0:
        elevations = _solve_elevations(labels, changes)
        joined = {frozenset(p) for p in itertools.pairwise(labels)}
        pairs = [
            (abs(float(elevations[a] - elevations[b])), a, b)
            for a, b in itertools.combinations(range(elevations.shape[0]), 2)
            if frozenset((a, b)) not in joined
        ]
        close = [p for p in pairs if p[0] < tolerance_m]
        if not close:
            return labels
        _, a, b = min(close)
        # Labels stay 0..n-1 in order of first visit.
        merged = [a if lab == b else lab for lab in labels]
        order = {lab: k for k, lab in enumerate(dict.fromkeys(merged))}
        labels = [order[lab] for lab in merged]
    return labels


def _solve_elevations(labels: list[int], changes: list[float]) -> F64:
    """Least-squares floor elevations from every transition's change, start floor fixed at 0."""
    n_floors = max(labels) + 1
    if n_floors == 1:
        return np.zeros(1)
    rows = []
    for k, change in enumerate(changes):
        row = np.zeros(n_floors)
        row[labels[k + 1]] += 1.0
        row[labels[k]] -= 1.0
        rows.append((row, change))
    A = np.array([r for r, _ in rows])[:, 1:]  # floor of the first visit is label 0, fixed at 0
    b = np.array([c for _, c in rows])
    solution, *_ = np.linalg.lstsq(A, b, rcond=None)
    return np.concatenate(([0.0], solution))


def _fitted_changes(grid: Grid, bounds: list[tuple[int, int]], changes: list[float], start_ns: int,
                    window_s: float) -> list[float]:
    """Each transition's height change from one fit over the raw trace either side
    (`mfmap.floors.levels`); the robust lines' change where the fit does not run.

    The lines fit each side on its own over the pulse-cleaned trace, whose pulse removal leaves
    centimetres of step behind: over 420 simulated transitions they were 4.9 cm RMS off (worst
    31 cm), the fit 1.9 cm (worst 6.5 cm).
    """
    trace = trace_of_grid(grid)
    secs = [((a - start_ns) / 1e9, (b - start_ns) / 1e9) for a, b in bounds]
    ends = [float(grid.times_s[0])] + [b for _, b in secs]
    starts = [a for a, _ in secs] + [float(grid.times_s[-1])]
    out = []
    for k, change in enumerate(changes):
        fit = fit_level_change(trace, secs[k], (ends[k], starts[k + 1]), window_s)
        out.append(change if fit.height_change_m is None else fit.height_change_m)
    return out


def _stairs_from_standstill(
    motion: MotionEvidence, start_ns: int, end_ns: int, cfg: FloorsConfig
) -> tuple[int, int]:
    """A climb runs from standstill to standstill: the height only starts to change a step or
    two into it, so odometry places its ends better than the barometer (within 3 s of them)."""
    within_ns = 3_000_000_000
    before = motion.standstill_near(start_ns, within_ns, cfg.moving_speed_m_s, before=True)
    after = motion.standstill_near(end_ns, within_ns, cfg.moving_speed_m_s, before=False)
    return (before if before is not None else start_ns, after if after is not None else end_ns)


def _clean_series(pressure: PressureSeries) -> tuple[I64, F64]:
    stamp_ns = np.asarray(pressure.stamp_ns, dtype=np.int64)
    pressure_pa = np.asarray(pressure.pressure_pa, dtype=np.float64)
    ok = np.isfinite(pressure_pa) & (pressure_pa > 0)
    stamp_ns, pressure_pa = stamp_ns[ok], pressure_pa[ok]
    order = np.argsort(stamp_ns, kind="stable")
    stamp_ns, pressure_pa = stamp_ns[order], pressure_pa[order]
    # Duplicate stamps (re-published messages) would make a zero time step.
    keep = np.concatenate((np.ones(min(1, stamp_ns.shape[0]), dtype=bool), np.diff(stamp_ns) > 0))
    stamp_ns, pressure_pa = stamp_ns[keep], pressure_pa[keep]
    if stamp_ns.shape[0] < MIN_SAMPLES:
        raise MissingDataError(
            f"the barometer trace has {stamp_ns.shape[0]} usable samples, at least {MIN_SAMPLES} needed"
        )
    return stamp_ns, pressure_pa


def segment_pressure(
    pressure: PressureSeries, motion: MotionEvidence | None, cfg: FloorsConfig
) -> FloorSegmentation:
    """Floors, transitions and the filtered height trace of one barometer series."""
    stamp_ns, pressure_pa = _clean_series(pressure)
    warnings: list[str] = []
    t_s = (stamp_ns - stamp_ns[0]).astype(np.float64) / 1e9
    ref_pa = float(np.median(pressure_pa[t_s <= min(1.0, t_s[-1])]))
    height_raw = height_from_pressure(pressure_pa, ref_pa, cfg.temperature_k)
    grid = resample_uniform(t_s, height_raw)
    gaps = np.diff(t_s) > max(2.0, 20 * grid.dt_s)
    if np.any(gaps):
        warnings.append(
            f"{int(np.count_nonzero(gaps))} gaps in the barometer trace (longest "
            f"{float(np.max(np.diff(t_s))):.1f} s): heights interpolated across them"
        )
    trace = filter_height(grid, cfg)
    if trace.spikes > 0.01 * grid.values.shape[0]:
        warnings.append(f"{trace.spikes} barometer spikes rejected ({trace.spikes / len(grid.values):.1%})")
    runs, changes, times, near_misses = find_transitions(trace, cfg, motion, int(stamp_ns[0]))
    warnings.extend(near_misses)

    def to_ns(seconds: float) -> int:
        return int(stamp_ns[0] + round(seconds * 1e9))

    end_s = float(t_s[-1])
    bounds = [(to_ns(max(0.0, a)), to_ns(min(b, end_s))) for a, b in times]
    dt_s = trace.grid.dt_s
    kinds = [TransitionKind.UNKNOWN if motion is None else _run_kind(motion, r, dt_s, int(stamp_ns[0]))
             for r in runs]
    if motion is not None:
        bounds = [
            _stairs_from_standstill(motion, a, b, cfg) if kind is TransitionKind.STAIRS else (a, b)
            for kind, (a, b) in zip(kinds, bounds, strict=True)
        ]
        # Never past the neighbouring transitions or the trace.
        edges = [int(stamp_ns[0])] + [x for pair in bounds for x in pair] + [int(stamp_ns[-1])]
        edges = np.maximum.accumulate(np.array(edges, dtype=np.int64)).tolist()
        bounds = [(edges[2 * k + 1], edges[2 * k + 2]) for k in range(len(bounds))]
    if cfg.transition_window_s > 0:
        changes = _fitted_changes(grid, bounds, changes, int(stamp_ns[0]), cfg.transition_window_s)
    # Revisits are recognised on the fitted changes: the robust lines' are good enough to find
    # the transitions, but a stairwell's own pressure held over the approach to the flight
    # left one 0.6 m off where the fit was 0.35 m off (a harsh building's 0 -> 2 -> 0, one floor
    # of 1 m tolerance apart).
    labels = _cluster_visits(changes, cfg.cluster_tolerance_m)
    elevations = _solve_elevations(labels, changes)
    # Ids from 0 = lowest; elevations relative to the start floor (label 0, solved as 0).
    order = np.argsort(elevations, kind="stable")
    id_of_label = np.empty_like(order)
    id_of_label[order] = np.arange(order.shape[0])
    visit_edges = [int(stamp_ns[0])] + [b for pair in bounds for b in pair] + [int(stamp_ns[-1])]
    visits = [(visit_edges[2 * k], visit_edges[2 * k + 1]) for k in range(len(runs) + 1)]

    transitions = []
    for k, (start_ns, end_ns) in enumerate(bounds):
        transitions.append(
            Transition(
                kind=kinds[k],
                from_floor=int(id_of_label[labels[k]]),
                to_floor=int(id_of_label[labels[k + 1]]),
                start_ns=start_ns,
                end_ns=end_ns,
                height_change_m=float(changes[k]),
            )
        )

    floor_of_sample = np.full(stamp_ns.shape[0], -1, dtype=np.int32)
    floor_pressures: dict[int, list[F64]] = {}
    for label, (start_ns, end_ns) in zip(labels, visits, strict=True):
        # Transitions own their edge samples; the trace's first and last samples are on floors.
        lo = 0 if start_ns == stamp_ns[0] else int(np.searchsorted(stamp_ns, start_ns, side="right"))
        n = stamp_ns.shape[0]
        hi = n if end_ns == stamp_ns[-1] else int(np.searchsorted(stamp_ns, end_ns, side="left"))
        floor_of_sample[lo:hi] = id_of_label[label]
        # A visit squeezed to nothing (a trace ending on a transition) keeps its edge sample.
        lo, hi = (lo, hi) if hi > lo else (min(lo, n - 1), min(lo, n - 1) + 1)
        floor_pressures.setdefault(label, []).append(pressure_pa[lo:hi])

    floors = []
    for label in range(elevations.shape[0]):
        samples = np.concatenate(floor_pressures[label])
        floors.append(
            Floor(
                id=int(id_of_label[label]),
                elevation_m=float(elevations[label]),
                pressure_pa=float(np.median(samples)),
                visits=tuple(v for lab, v in zip(labels, visits, strict=True) if lab == label),
            )
        )
    floors.sort(key=lambda f: f.id)
    filtered_at_samples = np.interp(t_s, grid.times_s, trace.filtered_m)
    logger.debug("%d floors, %d transitions, noise %.3f m", len(floors), len(transitions), trace.noise_m)
    return FloorSegmentation(
        floors=tuple(floors),
        transitions=tuple(transitions),
        stamp_ns=stamp_ns,
        height_raw_m=height_raw,
        height_filtered_m=np.asarray(filtered_at_samples, dtype=np.float64),
        floor_of_sample=floor_of_sample,
        warnings=tuple(warnings),
    )
