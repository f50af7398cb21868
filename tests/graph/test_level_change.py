"""The barometer's height change across a transition (mfmap.floors.levels.level_change)."""

from __future__ import annotations

import dataclasses

import numpy as np

from mfmap.config import MfmapConfig
from mfmap.floors.levels import level_change
from mfmap.floors.segment import segment_pressure
from mfmap.sim.traces import sim_barometer
from mfmap.types import FloorSegmentation


def _simulated(scenario: str, seed: int, window_s: float = 120.0) -> tuple[FloorSegmentation, list[float], dict[int, float]]:
    """The simulator's barometer alone (weather drift, wander, door/HVAC steps, noise) for one
    route, segmented by the floors stage (with its fit over `window_s` either side of each
    transition, or its robust lines for 0); with the true height change of every transition and
    the true elevations."""
    sim = sim_barometer(scenario, seed)
    cfg = MfmapConfig().floors.model_copy(update={"transitions": MfmapConfig().floors.transitions.model_copy(update={"window_s": window_s})})
    seg = segment_pressure(sim.pressure, None, cfg)
    elevation = {f["id"]: f["elevation_m"] for f in sim.gt_floors["floors"]}
    truth = [elevation[t["to"]] - elevation[t["from"]] for t in sim.gt_floors["transitions"]]
    assert len(seg.transitions) == len(truth)
    return seg, truth, elevation


def test_within_2_5_cm_over_seeds_and_twice_as_close_as_the_robust_lines() -> None:
    fit_err, lines_err, z, elev_err, elev_lines_err = [], [], [], [], []
    for scenario in ("two-floor", "three-floor-revisit", "stairs"):
        for seed in range(8):
            seg, truth, elevation = _simulated(scenario, seed)
            lines, _, _ = _simulated(scenario, seed, window_s=0.0)
            for k, true_m in enumerate(truth):
                fit = level_change(seg, k)
                assert fit.reason == "ok" and fit.height_change_m is not None
                # The floors stage carries the fit.
                assert seg.transitions[k].height_change_m == fit.height_change_m
                fit_err.append(fit.height_change_m - true_m)
                lines_err.append(lines.transitions[k].height_change_m - true_m)
                z.append(fit_err[-1] / fit.sigma_m)
            for ours, err in ((seg, elev_err), (lines, elev_lines_err)):
                assert [f.id for f in ours.floors] == sorted(elevation)
                base = elevation[ours.floor_of_sample[0]]
                err.extend(f.elevation_m - (elevation[f.id] - base) for f in ours.floors)
    assert len(fit_err) == 8 * (1 + 3 + 2)
    rms = float(np.sqrt(np.mean(np.square(fit_err))))
    rms_lines = float(np.sqrt(np.mean(np.square(lines_err))))
    # Measured: 1.7 cm against the robust lines' 3.4 cm; the sigma is honest (chi2 / n 0.8).
    assert rms < 0.025
    assert rms < 0.6 * rms_lines
    assert 0.5 < float(np.mean(np.square(z))) < 2.0
    # The floors' elevations (start floor at 0) follow.
    elev_rms = float(np.sqrt(np.mean(np.square(elev_err))))
    elev_rms_lines = float(np.sqrt(np.mean(np.square(elev_lines_err))))
    print(f"elevations: fit {elev_rms:.4f} m, lines {elev_rms_lines:.4f} m")
    assert elev_rms < 0.6 * elev_rms_lines


def test_a_door_step_after_the_ride_is_left_out() -> None:
    seg, truth, _ = _simulated("two-floor", 0)
    tr = seg.transitions[0]
    # A 12 Pa (about 1 m) step for 6 s, 40 s after the ride (clear of the simulator's own steps):
    # the fit leaves it out.
    t = seg.stamp_ns
    inside = (t > tr.end_ns + 40_000_000_000) & (t < tr.end_ns + 46_000_000_000)
    stepped = dataclasses.replace(seg, height_raw_m=np.where(inside, seg.height_raw_m - 1.0, seg.height_raw_m))
    clean, with_step = level_change(seg, 0), level_change(stepped, 0)
    assert clean.height_change_m is not None and with_step.height_change_m is not None
    assert with_step.masked_share > clean.masked_share + 0.025  # 8 s of 226 s
    assert abs(with_step.height_change_m - clean.height_change_m) < 0.005
    assert abs(with_step.height_change_m - truth[0]) < 0.05


def test_skipped_when_one_side_has_no_floor() -> None:
    seg, _, _ = _simulated("two-floor", 0)
    tr = seg.transitions[0]
    # The log ends 3 s after the ride.
    keep = seg.stamp_ns <= tr.end_ns + 3_000_000_000
    cut = dataclasses.replace(
        seg,
        stamp_ns=seg.stamp_ns[keep],
        height_raw_m=seg.height_raw_m[keep],
        height_filtered_m=seg.height_filtered_m[keep],
        floor_of_sample=seg.floor_of_sample[keep],
    )
    fit = level_change(cut, 0)
    assert fit.height_change_m is None
    assert fit.reason == "less than 5 s of floor on one side"


def test_the_weather_comes_from_the_visits_around_not_a_transient_after_a_long_walk() -> None:
    """A two-minute stair walk down 6.6 m followed by half a minute of floor whose first seconds
    still hold the stairwell's air: the weather's slope is read off the visits around (minutes of
    floor), within its sigma, and the walk's change is right with it as the prior."""
    from mfmap.floors.filters import Grid
    from mfmap.floors.levels import fit_level_change, trace_of_grid, visits_between, weather_slope

    dt = 0.04
    t = np.arange(0.0, 373.0, dt)
    rng = np.random.default_rng(0)
    drift = 0.0025 * t  # weather: falling pressure, 2.5 mm/s of apparent height
    truth = np.where(t < 93.0, 0.0, np.where(t < 112.0, 6.6 * (t - 93.0) / 19.0, 6.6))
    truth = np.where(t < 228.0, truth, np.where(t < 342.0, 6.6 - 6.6 * (t - 228.0) / 114.0, 0.0))
    # The stairwell's air leaves the robot over eight seconds after the walk: 0.6 m of offset.
    after = t - 342.0
    transient = np.where((after > 0) & (after < 8.0), -0.6 * (1.0 - after / 8.0), 0.0)
    height = truth + drift + transient + rng.normal(0.0, 0.15, t.shape)
    trace = trace_of_grid(Grid(0.0, dt, height))
    spans = [(93.0, 112.0), (228.0, 342.0)]
    visits = visits_between(trace, spans)
    slope, sigma = weather_slope(trace, visits, spans[1])
    assert abs(slope - 0.0025) < 3 * sigma and sigma < 0.001
    fit = fit_level_change(trace, spans[1], (visits[1][0], visits[2][1]), weather=(slope, sigma))
    assert fit.height_change_m is not None
    assert abs(fit.height_change_m - -6.6) < 0.3
