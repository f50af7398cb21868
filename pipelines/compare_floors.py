"""The LeGO-LOAM elevator paper's sliding-mean baseline against the floors stage's method, case by case.

For every simulator scenario (its own barometer model), two harsh synthetic walks and the two
real IPIN 2023 phone traces, both methods run the same transition/floor pipeline; only the
filtering differs (`floors.filter.method`). Prints a markdown table: floor count right?, floor sequence
right?, worst transition timing error (s), worst elevation error (m).

    .venv/bin/python pipelines/compare_floors.py [--seeds 0 1]
"""

from __future__ import annotations

import argparse
import csv
import itertools
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mfmap.floors.config import FilterConfig, FilterMethod, FloorsConfig
from mfmap.floors.io import read_pressure_csv
from mfmap.floors.motion import MotionEvidence, motion_from_odometry
from mfmap.floors.segment import segment_pressure
from mfmap.sim.traces import building_walk, sim_barometer, synthetic_trace
from mfmap.types import FloorSegmentation, PressureSeries

ROOT = Path(__file__).resolve().parent.parent
IPIN = ROOT / "tests" / "data" / "ipin2023"
SIM_SCENARIOS = ["tiny", "two-floor", "three-floor-revisit", "three-floor-drift", "stairs", "single-floor", "long"]


@dataclass
class Truth:
    n_floors: int
    sequence: list[int]  # floor rank (0 = lowest) of each visit
    transitions: list[tuple[float, float]]  # (start, end) epoch s; label windows for real data
    elevations: list[float] | None  # sorted, relative to the start floor
    windows: bool = False  # transitions are label windows (real data): error = time outside


@dataclass
class Score:
    count_ok: bool
    sequence_ok: bool
    timing_s: float
    elevation_m: float


def score(seg: FloorSegmentation, truth: Truth) -> Score:
    start = seg.visits()[0][0] if seg.floors else 0
    ranks = [fid for fid, _, _ in seg.visits()]
    count_ok = len(seg.floors) == truth.n_floors
    # Real labels number floors from the start floor; compare shapes of the sequences.
    if truth.windows:
        seq_ok = [r - start for r in ranks] == truth.sequence
    else:
        seq_ok = ranks == truth.sequence
    timing = float("nan")
    if len(seg.transitions) == len(truth.transitions) and truth.transitions:
        errs = []
        for tr, (a, b) in zip(seg.transitions, truth.transitions, strict=True):
            s, e = tr.start_ns / 1e9, tr.end_ns / 1e9
            if truth.windows:
                errs.append(max(a - s, e - b, 0.0))
            else:
                errs.append(max(abs(s - a), abs(e - b)))
        timing = max(errs)
    elif not truth.transitions and not seg.transitions:
        timing = 0.0
    elev = float("nan")
    if truth.elevations is not None and count_ok:
        elev = max(abs(f.elevation_m - e) for f, e in zip(seg.floors, truth.elevations, strict=True))
    return Score(count_ok, seq_ok, timing, elev)


def sim_case(scenario: str, seed: int) -> tuple[PressureSeries, MotionEvidence, Truth]:
    sim = sim_barometer(scenario, seed)
    gt = sim.gt_floors
    floors = sorted(gt["floors"], key=lambda f: f["elevation_m"])
    rank = {f["id"]: i for i, f in enumerate(floors)}
    visits = sorted((v[0], rank[f["id"]]) for f in gt["floors"] for v in f["visits"])
    start_s = gt["sim"]["start_ns"] / 1e9
    start_el = next(f["elevation_m"] for f in gt["floors"] if any(abs(v[0] - start_s) < 1 for v in f["visits"]))
    truth = Truth(
        len(floors),
        [r for _, r in visits],
        [(t["t_start"], t["t_end"]) for t in gt["transitions"]],
        [f["elevation_m"] - start_el for f in floors],
    )
    return sim.pressure, motion_from_odometry(sim.odometry, FloorsConfig()), truth


def synthetic_case(kind: str, seed: int) -> tuple[PressureSeries, None, Truth]:
    trace = synthetic_trace(
        building_walk(4.0 if kind == "elevator" else 3.0, kind),
        drift_pa_per_h=200.0,
        transients=8,
        spikes=20,
        seed=seed,
    )
    order = np.argsort(np.argsort(trace.elevations))
    t0 = trace.pressure.stamp_ns[0] / 1e9
    levels = [int(order[t.from_level]) for t in trace.transitions] + [int(order[trace.transitions[-1].to_level])]
    truth = Truth(
        len(trace.elevations),
        levels,
        [(t0 + t.start_s, t0 + t.end_s) for t in trace.transitions],
        sorted(trace.elevations),
    )
    return trace.pressure, None, truth


def real_case(name: str) -> tuple[PressureSeries, None, Truth]:
    series, _ = read_pressure_csv(IPIN / f"{name}_pressure.csv")
    with (IPIN / f"{name}_floor_labels.csv").open() as f:
        labels = [(float(r["app_time_s"]), int(r["floor"])) for r in csv.DictReader(f)]
    seq = [labels[0][1]] + [f1 for (_, f0), (_, f1) in itertools.pairwise(labels) if f1 != f0]
    windows = [(t0, t1) for (t0, f0), (t1, f1) in itertools.pairwise(labels) if f1 != f0]
    return series, None, Truth(len(set(seq)), seq, windows, None, windows=True)


def fmt(x: float, unit: str) -> str:
    return "-" if np.isnan(x) else f"{x:.2f} {unit}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    args = parser.parse_args()
    cases: list[tuple[str, PressureSeries, MotionEvidence | None, Truth]] = []
    for seed in args.seeds:
        for scenario in SIM_SCENARIOS:
            cases.append((f"sim {scenario} (seed {seed})", *sim_case(scenario, seed)))
        for kind in ("elevator", "stairs"):
            cases.append((f"synthetic {kind}, 200 Pa/h, 8 steps (seed {seed})", *synthetic_case(kind, seed)))
    cases.append(("real IPIN Trial51 (phone, stairs)", *real_case("IPIN2023_T3_TrainingTrial51_repetition02")))
    cases.append(("real IPIN Trial04 (phone, one floor)", *real_case("IPIN2023_T3_TrainingTrial04_repetition03")))

    print("| case | floors (truth) | baseline: count / sequence / timing / elevation | "
          "rts: count / sequence / timing / elevation |")
    print("|---|---|---|---|")
    totals = {m: [0, 0] for m in FilterMethod}
    t_wall = time.perf_counter()
    for name, pressure, motion, truth in cases:
        row = [name, str(truth.n_floors)]
        for method in (FilterMethod.SLIDING_MEAN, FilterMethod.RTS):
            seg = segment_pressure(pressure, motion, FloorsConfig(filter=FilterConfig(method=method)))
            s = score(seg, truth)
            totals[method][0] += int(s.count_ok)
            totals[method][1] += int(s.sequence_ok)
            row.append(
                f"{len(seg.floors)} {'ok' if s.count_ok else 'WRONG'} / {'ok' if s.sequence_ok else 'WRONG'} / "
                f"{fmt(s.timing_s, 's')} / {fmt(s.elevation_m, 'm')}"
            )
        print("| " + " | ".join(row) + " |")
    n = len(cases)
    for method, (count, seq) in totals.items():
        print(f"\n{method.value}: floor count right in {count}/{n} cases, floor sequence right in {seq}/{n}")
    print(f"({time.perf_counter() - t_wall:.1f} s; timing = worst |start/end - truth|, for real data the "
          "time outside the label window; elevation = worst |floor elevation - truth|)")


if __name__ == "__main__":
    main()
