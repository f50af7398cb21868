"""segment_pressure on synthetic traces (known truth): counts, ids, timing, elevations."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest

from mfmap.errors import MissingDataError
from mfmap.floors.config import FilterConfig, FloorsConfig
from mfmap.floors.motion import MotionEvidence
from mfmap.floors.segment import cluster_visits, segment_pressure
from mfmap.sim.traces import Leg, SyntheticTrace, building_walk, synthetic_trace
from mfmap.types import FloorSegmentation, PressureSeries, TransitionKind


def _truth_ids(trace: SyntheticTrace) -> npt.NDArray[np.int64]:
    """Truth floor id per sample (0 = lowest), -1 while moving."""
    rank = np.argsort(np.argsort(trace.elevations))
    return np.asarray(np.where(trace.level_of_sample >= 0, rank[np.maximum(trace.level_of_sample, 0)], -1), dtype=np.int64)


def _check(seg: FloorSegmentation, trace: SyntheticTrace, timing_s: float | None) -> None:
    assert len(seg.floors) == len(trace.elevations)
    assert len(seg.transitions) == len(trace.transitions)
    start = int(seg.stamp_ns[0])
    # Elevations relative to the start floor, within 0.3 m.
    for floor, elevation in zip(seg.floors, sorted(trace.elevations), strict=True):
        assert abs(floor.elevation_m - elevation) < 0.3
    if timing_s is not None:
        for got, want in zip(seg.transitions, trace.transitions, strict=True):
            assert abs((got.start_ns - start) / 1e9 - want.start_s) < timing_s
            assert abs((got.end_ns - start) / 1e9 - want.end_s) < timing_s
    # Every sample away from the true transitions (by more than the timing tolerance) carries
    # exactly its floor's id.
    truth = _truth_ids(trace)
    if timing_s is None:
        # No sample on a wrong floor, and nearly all samples on a floor (a transition pulled
        # long by a door step next to it may swallow a few seconds).
        on_floor = (truth >= 0) & (seg.floor_of_sample >= 0)
        assert np.array_equal(seg.floor_of_sample[on_floor], truth[on_floor])
        assert np.count_nonzero(on_floor) > 0.95 * np.count_nonzero(truth >= 0)
        return
    near = np.zeros(truth.shape[0], dtype=bool)
    for tr in trace.transitions:
        near |= (trace.times_s > tr.start_s - timing_s) & (trace.times_s < tr.end_s + timing_s)
    away = (truth >= 0) & ~near
    assert np.array_equal(seg.floor_of_sample[away], truth[away])


@pytest.mark.parametrize("kind", ["elevator", "stairs"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_clean_building_walk(kind: str, seed: int, cfg: FloorsConfig) -> None:
    """0 -> +1 -> +2 -> +1 -> 0 -> -1 -> 0 with 3 Pa noise, 0.5 Pa quantisation, spikes."""
    trace = synthetic_trace(building_walk(4.0 if kind == "elevator" else 3.0, kind), spikes=20, seed=seed)
    seg = segment_pressure(trace.pressure, None, cfg)
    _check(seg, trace, timing_s=1.0)
    assert [t.kind for t in seg.transitions] == [TransitionKind.UNKNOWN] * 6


@pytest.mark.parametrize("kind", ["elevator", "stairs"])
@pytest.mark.parametrize("drift", [200.0, -200.0])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_drift_and_door_transients_never_add_or_split_a_floor(
    kind: str, drift: float, seed: int, cfg: FloorsConfig
) -> None:
    """200 Pa/h drift (17 m/h apparent) and eight 5-15 Pa steps of 1-6 s on the floors."""
    trace = synthetic_trace(
        building_walk(4.0 if kind == "elevator" else 3.0, kind),
        drift_pa_per_h=drift,
        transients=8,
        spikes=20,
        seed=seed,
    )
    seg = segment_pressure(trace.pressure, None, cfg)
    # Timing is not asserted here: a step a few seconds before a ride can still pull its start
    # (the sim scenarios below assert 1 s with the simulator's own transients).
    _check(seg, trace, timing_s=None)


def test_long_stay_under_strong_drift_is_one_floor(cfg: FloorsConfig) -> None:
    """An hour on one floor at 200 Pa/h: 17 m of apparent height, still one floor."""
    trace = synthetic_trace([Leg("stay", 3600.0)], rate_hz=10.0, drift_pa_per_h=200.0, transients=20, seed=5)
    seg = segment_pressure(trace.pressure, None, cfg)
    assert len(seg.floors) == 1 and len(seg.transitions) == 0
    assert np.all(seg.floor_of_sample == 0)


def test_revisit_gets_the_same_id_after_many_transitions(cfg: FloorsConfig) -> None:
    stay = Leg("stay", 30.0)
    legs = [stay]
    for _ in range(5):  # up two floors and back, five times
        legs += [Leg("elevator", height_change_m=3.5), stay, Leg("elevator", height_change_m=3.5), stay]
        legs += [Leg("elevator", height_change_m=-7.0), stay]
    trace = synthetic_trace(legs, drift_pa_per_h=100.0, seed=6)
    seg = segment_pressure(trace.pressure, None, cfg)
    assert len(seg.floors) == 3 and len(seg.transitions) == 15
    assert [v[0] for v in seg.visits()] == [0, 1, 2] * 5 + [0]
    _check(seg, trace, timing_s=1.0)


def test_a_short_change_below_min_floor_height_is_not_a_floor(cfg: FloorsConfig) -> None:
    """A 1.5 m ramp (a mezzanine half-flight) with min_floor_height_m 2.0: one floor, a warning."""
    legs = [Leg("stay", 40.0), Leg("stairs", height_change_m=1.5, speed_m_s=0.3), Leg("stay", 40.0)]
    seg = segment_pressure(synthetic_trace(legs, seed=7).pressure, None, cfg)
    assert len(seg.floors) == 1 and len(seg.transitions) == 0
    assert any("below min_floor_height_m" in w for w in seg.warnings)


def test_stair_landing_pause_is_one_transition(cfg: FloorsConfig) -> None:
    """Two half-flights of 1.6 m with a 6 s pause on the landing: one floor change of 3.2 m."""
    half = Leg("stairs", height_change_m=1.6, speed_m_s=0.3)
    legs = [Leg("stay", 40.0), half, Leg("stay", 6.0), half, Leg("stay", 40.0)]
    trace = synthetic_trace(legs, seed=8)
    seg = segment_pressure(trace.pressure, None, cfg)
    assert len(seg.floors) == 2 and len(seg.transitions) == 1
    assert abs(seg.transitions[0].height_change_m - 3.2) < 0.3
    start = seg.stamp_ns[0]
    assert abs((seg.transitions[0].start_ns - start) / 1e9 - 40.0) < 1.0
    assert abs((seg.transitions[0].end_ns - start) / 1e9 - (40.0 + 2 * 1.6 / 0.3 + 6.0)) < 1.0


def _odometry(trace: SyntheticTrace, legs: list[Leg], walk_m_s: list[float]) -> MotionEvidence:
    """Odometry speed per leg (one value per leg), sampled at the trace's stamps."""
    bounds = np.cumsum([leg.duration_s if leg.kind == "stay" else abs(leg.height_change_m) / leg.speed_m_s
                        for leg in legs])
    speed = np.asarray(walk_m_s)[np.minimum(np.searchsorted(bounds, trace.times_s), len(legs) - 1)]
    return MotionEvidence(trace.pressure.stamp_ns, speed > 0.1, "odometry", speed.astype(np.float64))


def test_switch_back_landing_of_half_a_minute_is_one_transition(cfg: FloorsConfig) -> None:
    """Two half flights of 1.8 m, 30 s standing on the landing between (each half is below
    min_floor_height_m, the stand longer than any pause): one floor change of 3.6 m, because
    the odometry says the robot went nowhere on the landing."""
    half = Leg("stairs", height_change_m=1.8, speed_m_s=0.3)
    legs = [Leg("stay", 60.0), half, Leg("stay", 30.0), half, Leg("stay", 60.0)]
    trace = synthetic_trace(legs, seed=3)
    motion = _odometry(trace, legs, [0.5, 0.4, 0.0, 0.4, 0.5])
    seg = segment_pressure(trace.pressure, motion, cfg)
    assert len(seg.floors) == 2 and len(seg.transitions) == 1
    assert abs(seg.transitions[0].height_change_m - 3.6) < 0.3
    assert seg.transitions[0].kind is TransitionKind.STAIRS
    start = seg.stamp_ns[0]
    assert abs((seg.transitions[0].start_ns - start) / 1e9 - 60.0) < 2.0
    assert abs((seg.transitions[0].end_ns - start) / 1e9 - (60.0 + 12.0 + 30.0)) < 2.0


def test_floor_passed_through_on_the_stairs_is_not_a_floor_visit(cfg: FloorsConfig) -> None:
    """Up two storeys of unequal height (3.0 m, then 4.2 m) by the stairs, crossing the middle
    floor's landing in 12 s and 3 m of travel: one transition to the top floor, two floors."""
    legs = [Leg("stay", 60.0), Leg("stairs", height_change_m=3.0, speed_m_s=0.3), Leg("stay", 12.0),
            Leg("stairs", height_change_m=4.2, speed_m_s=0.3), Leg("stay", 60.0)]
    trace = synthetic_trace(legs, seed=5)
    motion = _odometry(trace, legs, [0.5, 0.4, 0.25, 0.4, 0.5])
    seg = segment_pressure(trace.pressure, motion, cfg)
    assert len(seg.floors) == 2 and len(seg.transitions) == 1
    assert abs(seg.transitions[0].height_change_m - 7.2) < 0.3
    # Walking across it (12 m) makes it a visit: three floors.
    motion = _odometry(trace, legs, [0.5, 0.4, 1.0, 0.4, 0.5])
    assert len(segment_pressure(trace.pressure, motion, cfg).floors) == 3


def test_a_stand_after_the_stairwell_door_is_not_part_of_the_walk(cfg: FloorsConfig) -> None:
    """Through the stairwell's door (its own pressure, 7 Pa above the floor's, mixes in within a
    second), 12 s standing, then 3.2 m down the stairs: the walk starts with the flight, not
    at the door."""
    legs = [Leg("stay", 60.0), Leg("stay", 12.0), Leg("stairs", height_change_m=-3.2, speed_m_s=0.3),
            Leg("stay", 60.0)]
    trace = synthetic_trace(legs, seed=4)
    t = trace.times_s
    door = np.clip((t - 60.0) / 0.8, 0.0, 1.0) * 7.0
    pressure = PressureSeries(trace.pressure.stamp_ns, trace.pressure.pressure_pa + door)
    motion = _odometry(trace, legs, [0.5, 0.0, 0.4, 0.5])
    seg = segment_pressure(pressure, motion, cfg)
    assert len(seg.floors) == 2 and len(seg.transitions) == 1
    start = seg.stamp_ns[0]
    assert abs((seg.transitions[0].start_ns - start) / 1e9 - 72.0) < 2.0


def test_a_revisit_the_chain_misses_is_placed_by_all_transitions() -> None:
    """0 -> 1 -> 2 -> back to 0 (read -7.1 m: 1.1 m from floor 0, past the 1 m tolerance, a new
    floor for the chain) -> 1 (+3.5 m). The loop's least squares put that floor 0.8 m from floor
    0 and no transition joins the two: one floor."""
    assert cluster_visits([3.0, 3.0, -7.1, 3.5], 1.0) == [0, 1, 2, 0, 1]


def test_same_input_same_output(cfg: FloorsConfig) -> None:
    trace = synthetic_trace(building_walk(), transients=4, seed=9)
    a = segment_pressure(trace.pressure, None, cfg)
    b = segment_pressure(trace.pressure, None, cfg)
    assert a.transitions == b.transitions and a.floors == b.floors
    assert np.array_equal(a.height_filtered_m, b.height_filtered_m)


def test_too_few_samples_is_a_typed_error(cfg: FloorsConfig) -> None:
    series = PressureSeries(np.arange(5, dtype=np.int64), np.full(5, 101300.0))
    with pytest.raises(MissingDataError, match="usable samples"):
        segment_pressure(series, None, cfg)


def test_baseline_sliding_mean_runs_the_same_pipeline() -> None:
    trace = synthetic_trace(building_walk(4.0, "elevator"), seed=0)
    seg = segment_pressure(trace.pressure, None, FloorsConfig(filter=FilterConfig(method="sliding_mean")))
    # On a clean elevator walk the baseline finds the floors too (it fails on stairs: see
    # pipelines/compare_floors.py); its transition times are only the smoothed speed's.
    assert len(seg.floors) == 4 and len(seg.transitions) == 6


def test_an_hour_over_five_floors_with_drift_steps_and_spikes(cfg: FloorsConfig) -> None:
    """The benchmark's walk (pipelines/bench_floors.py) at 10 Hz: every floor change found."""
    import importlib.util
    from pathlib import Path

    bench = Path(__file__).resolve().parents[2] / "pipelines" / "bench_floors.py"
    spec = importlib.util.spec_from_file_location("bench_floors", bench)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    trace = synthetic_trace(
        module.hour_walk(1.0), rate_hz=10.0, drift_pa_per_h=200.0, transients=40, spikes=100, seed=0
    )
    seg = segment_pressure(trace.pressure, None, cfg)
    assert len(trace.transitions) == 18
    _check(seg, trace, timing_s=1.0)


def test_unsorted_duplicate_and_nan_samples_are_cleaned(cfg: FloorsConfig) -> None:
    trace = synthetic_trace(building_walk(4.0, "elevator"), seed=10)
    stamps = trace.pressure.stamp_ns
    pressure = trace.pressure.pressure_pa.copy()
    pressure[100] = np.nan
    order = np.random.default_rng(0).permutation(stamps.shape[0])
    messy = PressureSeries(
        np.concatenate((stamps[order], stamps[:50])), np.concatenate((pressure[order], pressure[:50]))
    )
    seg = segment_pressure(messy, None, cfg)
    assert seg.stamp_ns.shape[0] == stamps.shape[0] - 1
    assert np.all(np.diff(seg.stamp_ns) > 0)
    assert len(seg.floors) == 4 and len(seg.transitions) == 6
