"""Runs of vertical speed in the filtered trace: found, pulses dropped, partial ones joined.

A run is a candidate transition: grid indices where the smoothed vertical speed keeps one sign
above the stop speed and reaches the minimum speed somewhere.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from mfmap.floors.config import FloorsConfig
from mfmap.floors.filters import true_runs
from mfmap.floors.motion import MotionEvidence
from mfmap.floors.trace import FilteredTrace
from mfmap.types import TransitionKind

# Runs of vertical motion smaller than this fraction of a floor are noise, a swinging phone or a
# door/HVAC pressure step: dropped before partial runs are joined.
_NOISE_RUN_FRACTION = 0.3
# A movement the other way at least this big between two runs means they are not one climb.
_BLOCK_RUN_FRACTION = 0.15
# The robot moves for at least this share of a transition's time on stairs (run_kind).
_MOVING_FRACTION_STAIRS = 0.5


@dataclass
class Run:
    """Grid indices of one-signed vertical speed: a candidate transition."""

    i0: int  # first grid index
    i1: int  # one past the last grid index
    sign: int
    change_m: float = 0.0
    pieces: tuple[tuple[int, int], ...] = ()  # (i0, i1) of the runs joined into this one

    def parts(self) -> tuple[tuple[int, int], ...]:
        return self.pieces or ((self.i0, self.i1),)


def motion_runs(trace: FilteredTrace, cfg: FloorsConfig) -> list[Run]:
    """Runs of one-signed vertical speed above the stop speed that reach the minimum speed."""
    v = trace.speed_m_s
    runs: list[Run] = []
    for sign in (1, -1):
        sv = sign * v
        core = np.concatenate(([0], np.cumsum(sv > cfg.transitions.min_vertical_speed_m_s)))
        for i0, i1 in true_runs(sv > cfg.transitions.stop_vertical_speed_m_s):
            if core[i1] - core[i0] > 0:
                runs.append(Run(i0, i1, sign))
    runs.sort(key=lambda r: r.i0)
    h = trace.filtered_m
    for run in runs:
        run.change_m = float(h[run.i1 - 1] - h[run.i0])
    return runs


def _drop_pulses(runs: list[Run], trace: FilteredTrace, cfg: FloorsConfig) -> list[Run]:
    """Drop pairs of opposite runs that cancel within max_transient_s: a pulse, not a climb.

    remove_transients misses pulses whose edges the noise blurs; as runs they are still a
    partial change followed at once by its undoing.
    """
    min_h = cfg.min_floor_height_m
    max_len = round(cfg.filter.max_transient_s / trace.grid.dt_s)
    drop: set[int] = set()
    for k in range(len(runs) - 1):
        a, b = runs[k], runs[k + 1]
        if k in drop or a.sign == b.sign or b.i1 - a.i0 > max_len + (a.i1 - a.i0) + (b.i1 - b.i0):
            continue
        largest = max(abs(a.change_m), abs(b.change_m))
        # Both edges steps: a stairwell's door crossed (a step) just before a climb's first
        # partial flight (a ramp) can cancel it as well as a pulse's edges do.
        if (largest < min_h and abs(a.change_m + b.change_m) < 0.5 * largest
                and step_like(a, a.change_m, trace, min_h) and step_like(b, b.change_m, trace, min_h)):
            drop.update((k, k + 1))
    return [r for k, r in enumerate(runs) if k not in drop]


# Is the level held between grid indices i0 and i1 a floor visit? (`stay_test`)
StayTest = Callable[[int, int], bool]


def stay_test(motion: MotionEvidence | None, cfg: FloorsConfig, dt_s: float, start_ns: int) -> StayTest:
    """A level held between two height changes is a floor visit when the robot goes somewhere on
    it: with odometry, at least landing_max_path_m of travel (a switch-back's half landing or a
    floor passed through on the stairs is a turn and a step or two across; in an elevator stop the
    robot stays in the cabin); without, at least min_visit_s, and not standing still all along
    by the IMU."""

    def is_visit(i0: int, i1: int) -> bool:
        a, b = start_ns + round(i0 * dt_s * 1e9), start_ns + round(i1 * dt_s * 1e9)
        path = motion.path_m(a, b) if motion is not None else None
        if path is not None:
            return path >= cfg.transitions.landing_max_path_m
        if (i1 - i0) * dt_s < cfg.transitions.min_visit_s:
            return False
        moving = motion.fraction_moving(a, b) if motion is not None else None
        return moving is None or moving >= 0.1

    return is_visit


def join_partial_runs(
    runs: list[Run], trace: FilteredTrace, cfg: FloorsConfig, is_visit: StayTest | None = None
) -> list[Run]:
    """Join same-direction runs split by a pause (a stair landing) when one is partial: a short
    pause always, a longer one when the level between is no floor visit (`is_visit`).

    Closest pairs are joined first, so a partial climb goes with the neighbour it belongs to
    rather than with whichever came first; a movement the other way in between (a phone lifted
    and lowered on a floor) keeps two runs apart.
    """
    min_h = cfg.min_floor_height_m
    blockers = [r for r in runs if abs(r.change_m) >= _BLOCK_RUN_FRACTION * min_h]
    kept = [r for r in runs if abs(r.change_m) >= _NOISE_RUN_FRACTION * min_h]
    kept = [Run(r.i0, r.i1, r.sign, r.change_m) for r in _drop_pulses(kept, trace, cfg)]
    max_gap = round(cfg.transitions.max_pause_s / trace.grid.dt_s)
    h = trace.filtered_m

    def abrupt(r: Run) -> bool:
        # Half the change within 0.3 s: a pressure step, not a flight of stairs.
        if trace.jump_m is None or abs(r.change_m) >= min_h:
            return False
        return float(np.max(r.sign * trace.jump_m[r.i0 : r.i1])) >= 0.5 * abs(r.change_m)

    def joinable(a: Run, b: Run) -> bool:
        if a.sign != b.sign:
            return False
        if b.i0 - a.i1 > max_gap and (is_visit is None or is_visit(a.i1, b.i0)
                                      or step_like(a, a.change_m, trace, min_h)
                                      or step_like(b, b.change_m, trace, min_h)):
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
        kept[k] = Run(a.i0, b.i1, a.sign, float(h[b.i1 - 1] - h[a.i0]), a.parts() + b.parts())
        del kept[k + 1]


def step_like(run: Run, change_m: float, trace: FilteredTrace, min_h: float) -> bool:
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


def after_leading_step(run: Run, times: tuple[float, float], trace: FilteredTrace,
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
    if not step_like(Run(i0, i1, run.sign, change), change, trace, min_h):
        return times
    return (max(times[0], j0 * trace.grid.dt_s), times[1])


def merge_stays(runs: list[Run], times: list[tuple[float, float]], dt_s: float,
                 is_visit: StayTest, climbs: list[bool]) -> list[Run] | None:
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
            joined = Run(a.i0, b.i1, a.sign, a.change_m + b.change_m, a.parts() + b.parts())
            return [*runs[:k], joined, *runs[k + 2:]]
    return None


def run_kind(motion: MotionEvidence, run: Run, dt_s: float, start_ns: int) -> TransitionKind:
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
