"""When each transition starts and ends: a flat-ramp-flat least-squares fit to the trace, and for
stairs the odometry's standstills."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mfmap.floors.config import FloorsConfig
from mfmap.floors.filters import fit_ramp
from mfmap.floors.motion import MotionEvidence
from mfmap.floors.runs import Run
from mfmap.floors.trace import FilteredTrace
from mfmap.types import F64, TransitionKind

# Chi-square gain (in units of the block noise variance) that justifies soft ramp corners.
_SOFT_CORNER_CHI2 = 12.0
# Faster than people or robots climb stairs: an elevator, whose speed ramps up and down.
_ELEVATOR_SPEED_M_S = 0.6


def refine_joined(
    runs: list[Run],
    trace: FilteredTrace,
    hints: list[TransitionKind | None] | None,
    cache: dict[tuple[int, ...], tuple[float, float]] | None = None,
) -> list[tuple[float, float]]:
    """Fit times of transitions; one joined over a landing starts where its first flight
    starts and ends where its last flight ends, each fitted on its own."""
    h = trace.filtered_m
    units: list[Run] = []
    unit_hints: list[TransitionKind | None] = []
    span: list[tuple[int, int]] = []
    for k, run in enumerate(runs):
        parts = run.parts()
        chosen = [parts[0]] if len(parts) == 1 else [parts[0], parts[-1]]
        span.append((len(units), len(units) + len(chosen) - 1))
        for i0, i1 in chosen:
            units.append(Run(i0, i1, run.sign, float(h[i1 - 1] - h[i0])))
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
    runs: list[Run],
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


def stairs_from_standstill(
    motion: MotionEvidence, start_ns: int, end_ns: int, cfg: FloorsConfig
) -> tuple[int, int]:
    """A climb runs from standstill to standstill: the height only starts to change a step or
    two into it, so odometry places its ends better than the barometer (within 3 s of them)."""
    within_ns = 3_000_000_000
    before = motion.standstill_near(start_ns, within_ns, cfg.moving.speed_m_s, before=True)
    after = motion.standstill_near(end_ns, within_ns, cfg.moving.speed_m_s, before=False)
    return (before if before is not None else start_ns, after if after is not None else end_ns)
