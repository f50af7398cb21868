"""Several logs of one building built into one map: real builds of the simulator's session logs,
placed by real registration, scored against the sessions' merged ground truth."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest

from mfmap import pipeline
from mfmap.config import MfmapConfig
from mfmap.eval import evaluate
from mfmap.eval.sessions import merge_sessions
from mfmap.multilog import build_logs
from mfmap.multilog.place import UnplacedLogsError


@pytest.fixture(scope="module")
def extended(sim_run: Callable[..., Path], tmp_path_factory: pytest.TempPathFactory
             ) -> tuple[Path, Path, str]:
    """tiny-day3 (the lower floor, 40 s) built alone, then extended with tiny-day1 (both floors,
    another day): (the first build, the extended build, its report.json before extending)."""
    root = tmp_path_factory.mktemp("multilog")
    first = root / "day3"
    pipeline.build(sim_run("tiny-day3") / "log.mcap", first, MfmapConfig())
    before = (first / "report.json").read_text()
    out = root / "day3+day1"
    build_logs([sim_run("tiny-day1") / "log.mcap"], out, MfmapConfig(), extend=first)
    return first, out, before


def test_extend_reads_the_build_and_writes_a_new_one(extended: tuple[Path, Path, str]) -> None:
    first, out, before = extended
    assert (first / "report.json").read_text() == before
    logs = json.loads((out / "report.json").read_text())["logs"]
    assert [Path(item["log"]).parent.name for item in logs] == ["tiny-day3-mcap-0", "tiny-day1-mcap-0"]
    assert sorted(p.name for p in (out / "trajectories").iterdir()) == ["0-log.tum", "1-log.tum"]


def test_second_log_shares_the_lower_floor_and_adds_the_upper(
        extended: tuple[Path, Path, str]) -> None:
    _, out, _ = extended
    report = json.loads((out / "report.json").read_text())
    day1 = report["logs"][1]
    assert day1["floors"] == {"0": 0, "1": 1}  # its upper floor is new to the building
    (registration,) = day1["registration"]
    assert registration["building_floor"] == 0
    assert registration["fitness"] > 0.9
    assert registration["runner_up_fitness"] < 0.6
    # Both sessions start at the dock: the frames are one.
    assert abs(day1["frame"]["x_m"]) < 0.02 and abs(day1["frame"]["y_m"]) < 0.02
    assert abs(day1["frame"]["yaw_deg"]) < 0.2
    assert report["graph"]["factors"]["inter_log"]["count"] > 0
    assert report["counts"]["logs"] == 2


def test_merged_map_scores_against_both_sessions_truth(
        extended: tuple[Path, Path, str], sim_run: Callable[..., Path]) -> None:
    _, out, _ = extended
    truth = merge_sessions([sim_run("tiny-day3"), sim_run("tiny-day1")], out / "truth")
    result = evaluate(out, points=truth.points, floors=truth.floors, trajectory=truth.trajectory)
    m = result.metrics
    # Checkpoints of both days: P1 and P2 on the lower floor (day 3 and day 1), P2 upstairs.
    assert m["points.count"] == 5
    assert m["points.floor0.count"] == 4
    assert m["points.floor0.rmse_m"] < 0.016
    assert m["points.floor1.rmse_m"] < 0.025
    assert m["floors.count_error"] == 0
    assert m["floors.elevation_error_max_m"] < 0.02
    assert m["trajectory.floor0.ape_rmse_m"] < 0.03


def test_a_log_of_another_building_is_refused(sim_run: Callable[..., Path], tmp_path: Path) -> None:
    out = tmp_path / "out"
    foreign = sim_run("gen-tiny") / "log.mcap"
    with pytest.raises(UnplacedLogsError) as err:
        build_logs([sim_run("tiny-day3") / "log.mcap", foreign], out, MfmapConfig())
    message = str(err.value)
    assert "\n" not in message
    assert "cannot merge" in message and "log.mcap" in message
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []  # no partial folder left either
