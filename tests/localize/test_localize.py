"""`mfmap localize` against the simulator's truth: other days' logs of a built building, a log of
another building, and what it refuses.

The map is tiny-day1's build (both floors of the office block from the dock, so the map's frame
is the building frame the ground truth is in). The figures are asserted with tolerances around
what a run measures (docs/localize.md), never as exact counts.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from mfmap.config import MfmapConfig
from mfmap.errors import MapError, MfmapError, MissingDataError, OutputError
from mfmap.localize.score import score_localization

MAP = "tiny-day1"
Localized = Callable[..., tuple[Path, Path, Any]]


def _score(sim: Path, out: Path) -> dict[str, float]:
    return score_localization(out, sim / "gt_trajectory.tum", sim / "gt_floors.json")


def test_upper_floor_start_rides_down(localized: Localized) -> None:
    """tiny-day2 starts upstairs facing north (not where the map's log started), rides down."""
    sim, out, result = localized(MAP, "tiny-day2")
    m = _score(sim, out)
    assert m["floors.time_correct_share"] >= 0.99
    assert m["localize.pos_median_m"] <= 0.03  # measured 7 mm
    assert m["localize.pos_p95_m"] <= 0.06  # measured 22 mm
    assert m["trajectory.ape_rmse_m"] <= 0.05
    assert m["trajectory.z_rmse_m"] <= 0.03  # the ride's z from the accelerometer's profile
    assert m["localize.yaw_p95_deg"] <= 1.0
    assert m["localize.first_fix_s"] <= 10.0
    assert m["localize.localised_share"] >= 0.95
    assert m["localize.wrong_share"] == 0.0
    report = json.loads((out / "report.json").read_text())
    assert report["first_fix_floor"] == 1  # the upper floor of the map
    floors = {f["id"]: f for f in json.loads((out / "floors.json").read_text())["floors"]}
    on = {fid: sum(b - a for a, b in f["visits"]) for fid, f in floors.items()}
    assert on[0] > 30.0 and on[1] > 10.0
    rows = (out / "scans.csv").read_text().splitlines()
    assert len(rows) == result.scans + 1
    assert (out / "floors" / "0" / "path.png").stat().st_size > 0
    assert (out / "report.html").stat().st_size > 0


def test_lower_floor_alone(localized: Localized) -> None:
    """tiny-day3 never leaves the lower floor: the barometer alone cannot say which floor it is."""
    sim, out, _ = localized(MAP, "tiny-day3")
    m = _score(sim, out)
    assert m["floors.time_correct_share"] >= 0.99
    assert m["localize.pos_median_m"] <= 0.03
    assert m["localize.pos_p95_m"] <= 0.06
    assert m["localize.yaw_p95_deg"] <= 1.0
    assert m["localize.first_fix_s"] <= 10.0
    assert m["localize.wrong_share"] == 0.0


def test_same_output_twice(localized: Localized, sim_run: Callable[..., Path],
                           sim_map: Callable[[str], Path], tmp_path: Path) -> None:
    from mfmap.localize import localize

    _, first, _ = localized(MAP, "tiny-day3")
    again = tmp_path / "again"
    localize(sim_run("tiny-day3") / "log.mcap", sim_map(MAP), again, MfmapConfig())
    for name in ("trajectory.tum", "scans.csv", "floors.json"):
        assert (again / name).read_bytes() == (first / name).read_bytes(), name


def test_another_building_is_not_localised(localized: Localized) -> None:
    """gen-tiny is a generated building: none of its scans may be posed in the office's map."""
    _, out, result = localized(MAP, "gen-tiny")
    assert result.localised_share == 0.0
    assert (out / "trajectory.tum").read_text() == ""
    spans = json.loads((out / "report.json").read_text())["not_localised"]
    assert len(spans) == 1
    assert spans[0]["scans"] == result.scans
    assert spans[0]["best_fitness"] < MfmapConfig().localize.fix_fitness
    assert result.searches >= 1


def test_wrong_hint_is_dropped(sim_run: Callable[..., Path], sim_map: Callable[[str], Path],
                               tmp_path: Path) -> None:
    """An initial pose that does not fit is said so and searched past, not followed."""
    from mfmap.localize import Hint, localize

    sim = sim_run("tiny-day3")
    out = tmp_path / "hinted"
    result = localize(sim / "log.mcap", sim_map(MAP), out, MfmapConfig(),
                      hint=Hint(floor=0, x_m=5.0, y_m=-8.0, yaw_deg=135.0))
    assert any("initial pose does not fit" in w for w in result.warnings)
    m = _score(sim, out)
    assert m["localize.pos_p95_m"] <= 0.06
    assert m["localize.wrong_share"] == 0.0


# ----- refused in one line --------------------------------------------------------------------

def _localize(log: Path, map_dir: Path, out: Path, **kwargs: Any) -> Any:
    from mfmap.localize import localize

    return localize(log, map_dir, out, MfmapConfig(), **kwargs)


def test_folder_that_is_not_a_build(sim_run: Callable[..., Path], tmp_path: Path) -> None:
    log = sim_run("tiny-day3") / "log.mcap"
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(MapError, match="not a finished mfmap build") as err:
        _localize(log, empty, tmp_path / "out")
    assert str(empty) in str(err.value)
    with pytest.raises(MapError, match="not a folder"):
        _localize(log, log, tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_build_with_a_floor_cloud_missing(sim_run: Callable[..., Path],
                                          sim_map: Callable[[str], Path], tmp_path: Path) -> None:
    broken = tmp_path / "map"
    shutil.copytree(sim_map(MAP), broken)
    (broken / "floors" / "1" / "cloud.ply").unlink()
    with pytest.raises(MapError, match="floor 1's cloud is missing") as err:
        _localize(sim_run("tiny-day3") / "log.mcap", broken, tmp_path / "out")
    assert str(broken / "floors" / "1" / "cloud.ply") in str(err.value)


def test_log_without_a_3d_lidar(sim_run: Callable[..., Path], sim_map: Callable[[str], Path],
                                tmp_path: Path) -> None:
    log = sim_run("tiny-2d") / "log.mcap"
    with pytest.raises(MissingDataError, match="needs a 3D lidar") as err:
        _localize(log, sim_map(MAP), tmp_path / "out")
    assert str(log) in str(err.value)
    assert not (tmp_path / "out").exists()  # no partial output left


def test_output_inside_the_map_and_a_floor_it_lacks(sim_run: Callable[..., Path],
                                                    sim_map: Callable[[str], Path],
                                                    tmp_path: Path) -> None:
    from mfmap.localize import Hint

    log, map_dir = sim_run("tiny-day3") / "log.mcap", sim_map(MAP)
    with pytest.raises(OutputError, match="holds the input"):
        _localize(log, map_dir, map_dir.parent)
    with pytest.raises(OutputError, match="is inside the input folder"):
        _localize(log, map_dir, map_dir / "loc")
    with pytest.raises(MfmapError, match="--floor 5: the map has floors 0, 1"):
        _localize(log, map_dir, tmp_path / "out", hint=Hint(floor=5))


def test_cli_bad_map_is_one_line(sim_run: Callable[..., Path], tmp_path: Path) -> None:
    not_a_map = tmp_path / "notamap"
    not_a_map.mkdir()
    res = subprocess.run(
        [sys.executable, "-m", "mfmap.cli", "localize", str(sim_run("tiny-day3") / "log.mcap"),
         "--map", str(not_a_map), "-o", str(tmp_path / "out")],
        capture_output=True, text=True, timeout=120)
    assert res.returncode == 1
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and str(not_a_map) in lines[0], lines
    assert "not a finished mfmap build" in lines[0]
