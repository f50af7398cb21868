"""Real phone barometer traces (IPIN 2023 Track 3, CC-BY-4.0): a person on stairs."""

from __future__ import annotations

import csv
import itertools
from pathlib import Path

import numpy as np
import pytest

from mfmap.config import MfmapConfig
from mfmap.floors import segment_path
from mfmap.floors.io import read_pressure_csv
from mfmap.floors.segment import segment_pressure
from mfmap.types import PressureSeries

TRIAL51 = "IPIN2023_T3_TrainingTrial51_repetition02"
TRIAL04 = "IPIN2023_T3_TrainingTrial04_repetition03"


def _labels(path: Path) -> list[tuple[float, int]]:
    with path.open() as f:
        return [(float(r["app_time_s"]), int(r["floor"])) for r in csv.DictReader(f)]


def _label_windows(labels: list[tuple[float, int]]) -> list[tuple[float, float, int, int]]:
    """(last waypoint on the old floor, first on the new one, old, new) for each floor change."""
    return [(t0, t1, f0, f1) for (t0, f0), (t1, f1) in itertools.pairwise(labels) if f0 != f1]


def test_trial51_three_floors_and_the_labelled_sequence(ipin_dir: Path) -> None:
    seg = segment_path(ipin_dir / f"{TRIAL51}_pressure.csv", MfmapConfig())
    assert len(seg.floors) == 3
    # Map ids back to the labels' floor numbers: the start floor is label 0.
    start_id = seg.visits()[0][0]
    sequence = [fid - start_id for fid, _, _ in seg.visits()]
    assert sequence == [0, -1, -2, -1, 0, -1, -2, -1, 0]
    windows = _label_windows(_labels(ipin_dir / f"{TRIAL51}_floor_labels.csv"))
    assert len(windows) == len(seg.transitions) == 8
    for tr, (t_from, t_to, f_from, f_to) in zip(seg.transitions, windows, strict=True):
        # The change happens between the last waypoint on the old floor and the first on the
        # new one; ours must lie within 3 s of that window at both ends.
        assert (tr.from_floor - start_id, tr.to_floor - start_id) == (f_from, f_to)
        assert tr.start_ns / 1e9 > t_from - 3.0 and tr.end_ns / 1e9 < t_to + 3.0
        assert tr.end_ns > tr.start_ns
    # Floors about 0.30-0.35 hPa (2.5-3 m) apart, elevations from the start floor.
    elevations = sorted(f.elevation_m for f in seg.floors)
    assert elevations[2] == 0.0
    assert 2.3 < elevations[2] - elevations[1] < 3.6 and 2.3 < elevations[1] - elevations[0] < 3.6


def test_trial51_every_labelled_waypoint_is_on_its_floor(ipin_dir: Path) -> None:
    seg = segment_path(ipin_dir / f"{TRIAL51}_pressure.csv", MfmapConfig())
    start_id = seg.visits()[0][0]
    labels = _labels(ipin_dir / f"{TRIAL51}_floor_labels.csv")
    got = [seg.floor_at(round(t * 1e9)) for t, _ in labels]
    # Waypoints at the foot or head of a flight fall inside our transition (-1, 1-2 s of
    # slack); none may be on a wrong floor. Today 10 of the 16 are on a floor.
    for g, (_, want) in zip(got, labels, strict=True):
        assert g == -1 or g - start_id == want
    assert sum(g >= 0 for g in got) >= 10


def test_trial04_single_floor_gives_one_floor(ipin_dir: Path) -> None:
    seg = segment_path(ipin_dir / f"{TRIAL04}_pressure.csv", MfmapConfig())
    assert len(seg.floors) == 1
    assert len(seg.transitions) == 0
    assert np.all(seg.floor_of_sample == 0)


def test_raw_getsensordata_log_gives_the_same_floors(shared_dir: Path, ipin_dir: Path) -> None:
    """The phone's own log format (PRES lines in mbar) reads to the same trace as the CSV."""
    raw = shared_dir / "realdata" / "floor_segmentation" / "ipin2023" / "raw" / f"{TRIAL51}.txt"
    from_raw = segment_path(raw, MfmapConfig())
    from_csv = segment_path(ipin_dir / f"{TRIAL51}_pressure.csv", MfmapConfig())
    assert np.array_equal(from_raw.stamp_ns, from_csv.stamp_ns)
    assert from_raw.transitions == from_csv.transitions


@pytest.mark.parametrize("cut_s", [(85.0, 95.0), (87.0, 95.0), (86.0, 97.0)])
def test_down_two_floors_without_stopping_on_the_middle_one(ipin_dir: Path, cut_s: tuple[float, float]) -> None:
    """Trial51 with most of the first stay on floor -1 cut out (the samples after it moved back):
    the phone goes down two floors by the stairs and holds the middle one for 5-10 s on the way,
    no visit. One transition 0 -> -2, no extra floor."""
    pressure, _ = read_pressure_csv(ipin_dir / f"{TRIAL51}_pressure.csv")
    t_s = (pressure.stamp_ns - pressure.stamp_ns[0]) / 1e9
    a, b = cut_s
    keep = (t_s < a) | (t_s > b)
    shift = np.where(t_s > b, round((b - a) * 1e9), 0)
    spliced = PressureSeries((pressure.stamp_ns - shift)[keep], pressure.pressure_pa[keep])
    seg = segment_pressure(spliced, None, MfmapConfig().floors)
    assert len(seg.floors) == 3
    start_id = seg.visits()[0][0]
    assert [fid - start_id for fid, _, _ in seg.visits()] == [0, -2, -1, 0, -1, -2, -1, 0]
    # The joined transition runs from the first flight's start to the second's end.
    first = seg.transitions[0]
    assert abs((first.start_ns - pressure.stamp_ns[0]) / 1e9 - 63.7) < 3.0
    assert abs((first.end_ns - pressure.stamp_ns[0]) / 1e9 - (108.7 - (b - a))) < 3.0
    assert first.height_change_m < -5.0
