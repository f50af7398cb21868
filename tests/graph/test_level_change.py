"""The barometer's height change across a transition (mfmap.graph.barometer.level_change)."""

from __future__ import annotations

import dataclasses

import numpy as np

from mfmap.config import MfmapConfig
from mfmap.floors.segment import segment_pressure
from mfmap.floors.synthetic import sim_barometer
from mfmap.graph.barometer import level_change
from mfmap.types import FloorSegmentation


def _simulated(scenario: str, seed: int) -> tuple[FloorSegmentation, list[float]]:
    """The simulator's barometer alone (weather drift, wander, door/HVAC steps, noise) for one
    route, segmented by the floors stage; with the true height change of every transition."""
    sim = sim_barometer(scenario, seed)
    seg = segment_pressure(sim.pressure, None, MfmapConfig().floors)
    elevation = {f["id"]: f["elevation_m"] for f in sim.gt_floors["floors"]}
    truth = [elevation[t["to"]] - elevation[t["from"]] for t in sim.gt_floors["transitions"]]
    assert len(seg.transitions) == len(truth)
    return seg, truth


def test_within_2_5_cm_over_seeds_and_twice_as_close_as_the_floors_stage() -> None:
    fit_err, floors_err, z = [], [], []
    for scenario in ("two-floor", "three-floor-revisit", "stairs"):
        for seed in range(8):
            seg, truth = _simulated(scenario, seed)
            for k, true_m in enumerate(truth):
                fit = level_change(seg, k)
                assert fit.reason == "ok" and fit.height_change_m is not None
                fit_err.append(fit.height_change_m - true_m)
                floors_err.append(seg.transitions[k].height_change_m - true_m)
                z.append(fit_err[-1] / fit.sigma_m)
    assert len(fit_err) == 8 * (1 + 3 + 2)
    rms = float(np.sqrt(np.mean(np.square(fit_err))))
    rms_floors = float(np.sqrt(np.mean(np.square(floors_err))))
    # Measured: 1.7 cm against the floors stage's 3.4 cm; the sigma is honest (chi2 / n 0.8).
    assert rms < 0.025
    assert rms < 0.6 * rms_floors
    assert 0.5 < float(np.mean(np.square(z))) < 2.0


def test_a_door_step_after_the_ride_is_left_out() -> None:
    seg, truth = _simulated("two-floor", 0)
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
    seg, _ = _simulated("two-floor", 0)
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
