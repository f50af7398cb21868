"""Metric comparison, verdicts, baseline files and the three reports (pure logic, literal metrics)."""

from __future__ import annotations

import json
import math
import re
import xml.etree.ElementTree as ET
from collections.abc import Callable
from pathlib import Path

import pytest

from pipelines.regress.compare import (
    compare_metrics,
    flatten_metrics,
    judge,
    read_baseline,
    read_baseline_entries,
    updated_baseline,
    updated_machines,
    write_baseline,
)
from pipelines.regress.manifest import Manifest, ManifestError, Tolerance, Tolerances, load_manifest
from pipelines.regress.model import CheckStatus, LogOutcome, LogResult, RunResult, Verdict
from pipelines.regress.report import junit_xml, markdown_summary, results_json, write_reports


@pytest.fixture
def manifest(write_manifest: Callable[..., Path]) -> Manifest:
    return load_manifest(
        write_manifest(
            {
                "name": "unit",
                "baseline": "base.json",
                "tolerances": {
                    "default": {"abs": 0.005},
                    "metrics": {"points.*": {"abs": 0.01, "rel": 0.1}},
                },
                "logs": [
                    {"name": "good", "simulate": {"scenario": "tiny"}},
                    {"name": "worse", "simulate": {"scenario": "tiny"}},
                    {"name": "broken", "simulate": {"scenario": "tiny"}},
                    {"name": "fresh", "simulate": {"scenario": "tiny"}},
                ],
            }
        )
    )


def _outcome(name: str, metrics: dict[str, float], error: str | None = None,
             machine: str = "") -> LogOutcome:
    return LogOutcome(
        name=name,
        ok=error is None,
        metrics=metrics,
        wall_s=12.5,
        out_dir=f"/tmp/{name}",
        error=error,
        stage="build" if error else None,
        machine=machine,
    )


def test_flatten_nested_and_odd_values() -> None:
    flat = flatten_metrics({"points": {"rmse_m": 0.1, "floor0": {"count": 3}}, "ok": True, "n": None, "s": "x"})
    assert flat["points.rmse_m"] == 0.1
    assert flat["points.floor0.count"] == 3.0
    assert flat["ok"] == 1.0
    assert math.isnan(flat["n"])
    assert "s" not in flat


def test_tolerance_boundaries_and_directions(manifest: Manifest, eval_metrics: dict[str, float]) -> None:
    tol = manifest.tolerances
    current = dict(eval_metrics)
    # points.rmse_m: allowed = 0.01 + 0.1 * 0.042 = 0.0142
    current["points.rmse_m"] = 0.042 + 0.0141  # inside
    current["points.z_rmse_m"] = 0.011 + 0.0112  # allowed 0.0111: just outside
    current["trajectory.ape_rmse_m"] = 0.085 - 0.3  # much better
    current["cloud.fscore_10cm"] = 0.81 - 0.006  # higher-better, dropped beyond 0.005
    current["cloud.fscore_miss_10cm"] = 0.19 + 0.004  # lower-better, rose within 0.005
    current["floors.count_correct"] = 1.0
    checks = {
        c.metric: c
        for c in compare_metrics(
            current, eval_metrics, tol, manifest.is_higher_better, manifest.is_ignored
        )
    }
    assert checks["points.rmse_m"].status is CheckStatus.OK
    assert checks["points.rmse_m"].allowed == pytest.approx(0.0142)
    assert checks["points.z_rmse_m"].status is CheckStatus.REGRESSED
    assert checks["trajectory.ape_rmse_m"].status is CheckStatus.IMPROVED
    assert checks["cloud.fscore_10cm"].status is CheckStatus.REGRESSED
    assert checks["cloud.fscore_10cm"].worsening == pytest.approx(0.006)
    assert checks["cloud.fscore_miss_10cm"].status is CheckStatus.OK
    assert checks["floors.count_correct"].status is CheckStatus.OK
    assert "points.count" not in checks and "trajectory.pairs" not in checks  # ignored sizes
    regressed = sorted(m for m, c in checks.items() if c.status is CheckStatus.REGRESSED)
    assert regressed == ["cloud.fscore_10cm", "points.z_rmse_m"]


def test_identical_rebuild_passes_with_zero_tolerance(eval_metrics: dict[str, float]) -> None:
    tol = Tolerances(default=Tolerance(abs=0.0, rel=0.0))
    checks = compare_metrics(eval_metrics, eval_metrics, tol, lambda _: False)
    assert {c.status for c in checks} == {CheckStatus.OK}
    worse = dict(eval_metrics, **{"floors.inter.dz_m": 0.04 + 1e-9})
    bad = [c.metric for c in compare_metrics(worse, eval_metrics, tol, lambda _: False) if c.status is CheckStatus.REGRESSED]
    assert bad == ["floors.inter.dz_m"]


def test_missing_nan_and_new_metrics(manifest: Manifest, eval_metrics: dict[str, float]) -> None:
    current = {k: v for k, v in eval_metrics.items() if k != "floors.inter.dx_m"}
    current["trajectory.ape_rmse_m"] = math.nan
    current["points.floor2.rmse_m"] = 0.3
    base = dict(eval_metrics, **{"cloud.accuracy_median_m": math.nan})
    checks = {c.metric: c for c in compare_metrics(current, base, manifest.tolerances, manifest.is_higher_better)}
    assert checks["floors.inter.dx_m"].status is CheckStatus.MISSING
    assert checks["trajectory.ape_rmse_m"].status is CheckStatus.MISSING
    assert checks["points.floor2.rmse_m"].status is CheckStatus.NEW
    assert checks["cloud.accuracy_median_m"].status is CheckStatus.OK  # NaN before: nothing to lose
    assert checks["floors.inter.dx_m"].severity == math.inf


def _results(manifest: Manifest, eval_metrics: dict[str, float]) -> list[LogResult]:
    base = {"good": eval_metrics, "worse": eval_metrics, "broken": eval_metrics}
    worse = dict(eval_metrics, **{"floors.inter.dx_m": 1.9, "trajectory.ape_rmse_m": 0.4})
    outcomes = [
        _outcome("good", dict(eval_metrics)),
        _outcome("worse", worse),
        _outcome("broken", {}, error="log.mcap: no barometer topic | found none"),
        _outcome("fresh", dict(eval_metrics)),
    ]
    return [judge(o, base.get(o.name), manifest) for o in outcomes]


def test_verdicts(manifest: Manifest, eval_metrics: dict[str, float]) -> None:
    verdicts = {r.name: r.verdict for r in _results(manifest, eval_metrics)}
    assert verdicts == {
        "good": Verdict.PASS,
        "worse": Verdict.REGRESSED,
        "broken": Verdict.ERROR,
        "fresh": Verdict.NO_BASELINE,
    }
    worse = next(r for r in _results(manifest, eval_metrics) if r.name == "worse")
    # floors.inter.dx_m rose 0.05 -> 1.9 (37x), ape 0.085 -> 0.4 (3.7x): dx first.
    assert [c.metric for c in worse.regressions] == ["floors.inter.dx_m", "trajectory.ape_rmse_m"]


def test_reports_worst_first_and_parseable(
    manifest: Manifest, eval_metrics: dict[str, float], tmp_path: Path
) -> None:
    run = RunResult("unit", "local[2 workers]", 40.0, _results(manifest, eval_metrics))
    assert run.exit_code == 1
    md = markdown_summary(run)
    rows = [line for line in md.splitlines() if line.startswith("| ") and not line.startswith("| log")]
    assert [r.split("|")[1].strip() for r in rows] == ["broken", "worse", "fresh", "good"]
    assert "FAIL (3 of 4 logs)" in md
    assert "build failed: log.mcap: no barometer topic \\| found none" in md  # pipe escaped
    assert "floors.inter.dx_m 0.05 -> 1.9" in rows[1]
    # The escaped pipe did not add a column: 7 cells, 8 unescaped pipes, in every row.
    assert [len(re.findall(r"(?<!\\)\|", r)) for r in rows] == [8, 8, 8, 8]

    root = ET.fromstring(junit_xml(run))
    suite = root.find("testsuite")
    assert suite is not None
    assert (suite.get("tests"), suite.get("failures"), suite.get("errors")) == ("4", "2", "1")
    cases = {c.get("name"): c for c in suite.findall("testcase")}
    assert set(cases) == {"good", "worse", "broken", "fresh"}
    failure = cases["worse"].find("failure")
    assert failure is not None
    assert failure.get("message") == "regressed: floors.inter.dx_m, trajectory.ape_rmse_m"
    error = cases["broken"].find("error")
    assert error is not None and "no barometer topic" in (error.get("message") or "")
    assert cases["good"].find("failure") is None and cases["good"].find("error") is None

    data = results_json(run)
    assert data["exit_code"] == 1
    assert data["failed"] == ["broken", "worse", "fresh"]
    worse = next(log for log in data["logs"] if log["name"] == "worse")
    assert worse["regressed_metrics"] == ["floors.inter.dx_m", "trajectory.ape_rmse_m"]
    json.dumps(data, allow_nan=False)  # strict JSON: NaN became null

    paths = write_reports(run, tmp_path / "r")
    assert sorted(p.name for p in (tmp_path / "r").iterdir()) == ["junit.xml", "results.json", "summary.md"]
    ET.parse(paths["junit"])


def test_all_pass_exit_zero(manifest: Manifest, eval_metrics: dict[str, float]) -> None:
    results = [judge(_outcome("good", dict(eval_metrics)), eval_metrics, manifest)]
    run = RunResult("unit", "local[1 workers]", 1.0, results)
    assert run.exit_code == 0
    assert "PASS" in markdown_summary(run).splitlines()[0]


def test_baseline_update_keeps_failed_logs_and_is_atomic(
    manifest: Manifest, eval_metrics: dict[str, float], tmp_path: Path
) -> None:
    path = tmp_path / "baselines" / "unit.json"
    previous = {"broken": {"points.rmse_m": 0.05}, "gone": {"points.rmse_m": 0.2}}
    write_baseline(path, previous, "unit")
    results = _results(manifest, eval_metrics)
    new = updated_baseline(read_baseline(path), results)
    write_baseline(path, new, "unit")
    back = read_baseline(path)
    assert sorted(back) == ["broken", "fresh", "gone", "good", "worse"]
    assert back["broken"] == {"points.rmse_m": 0.05}  # failed build: previous entry kept
    assert back["worse"]["floors.inter.dx_m"] == 1.9
    assert [p.name for p in path.parent.iterdir()] == ["unit.json"]  # no temp file left
    assert path.stat().st_mode & 0o044  # readable by others, as a committed file should be
    data = json.loads(path.read_text())
    assert data["manifest"] == "unit" and data["format"] == 1


HERE = "x86_64 AMD EPYC [sse4_2 avx avx2 fma avx512f]; numpy 2.4.6, open3d 0.20.0"
THERE = "x86_64 AMD EPYC [sse4_2 avx avx2 fma]; numpy 2.4.6, open3d 0.20.0"


def test_baseline_records_each_logs_machine(
    manifest: Manifest, eval_metrics: dict[str, float], tmp_path: Path
) -> None:
    path = tmp_path / "unit.json"
    write_baseline(path, {"good": eval_metrics, "broken": eval_metrics}, "unit",
                   {"good": THERE, "broken": THERE})
    assert read_baseline_entries(path)[1] == {"good": THERE, "broken": THERE}
    results = [judge(_outcome("good", eval_metrics, machine=HERE), eval_metrics, manifest, THERE),
               judge(_outcome("broken", {}, "boom", machine=HERE), eval_metrics, manifest, THERE)]
    machines = updated_machines(read_baseline_entries(path)[1], results)
    assert machines == {"good": HERE, "broken": THERE}  # a failed build keeps its old entry
    write_baseline(path, updated_baseline(read_baseline(path), results), "unit", machines)
    assert read_baseline_entries(path)[1] == {"good": HERE, "broken": THERE}
    assert json.loads(path.read_text())["logs"]["good"]["machine"] == HERE
    write_baseline(path, {"old": eval_metrics}, "unit")  # made before machines were recorded
    assert read_baseline_entries(path)[1] == {} and read_baseline(path)["old"] == eval_metrics


def test_summary_says_when_the_baseline_is_another_machines(
    manifest: Manifest, eval_metrics: dict[str, float]
) -> None:
    worse = dict(eval_metrics, **{"points.rmse_m": 0.2})
    same = [judge(_outcome("good", eval_metrics, machine=HERE), eval_metrics, manifest, HERE),
            judge(_outcome("worse", worse, machine=HERE), eval_metrics, manifest, HERE)]
    text = markdown_summary(RunResult("unit", "local[1 workers]", 1.0, same))
    assert "another machine" not in text
    other = [judge(_outcome("good", eval_metrics, machine=HERE), eval_metrics, manifest, HERE),
             judge(_outcome("worse", worse, machine=HERE), eval_metrics, manifest, THERE),
             judge(_outcome("fresh", worse, machine=HERE), eval_metrics, manifest, None)]
    assert [r.other_machine for r in other] == [False, True, True]
    text = markdown_summary(RunResult("unit", "local[1 workers]", 1.0, other))
    note = next(line for line in text.splitlines() if "another machine" in line)
    assert note.startswith("2 of 3 logs have a baseline made on another machine")
    assert f"({THERE} and a machine the baseline does not record) than this run ({HERE})" in note
    # A run that writes the baseline makes it this machine's: nothing to warn about.
    assert "another machine" not in markdown_summary(RunResult("unit", "x", 1.0, other, True))
    logs = {log["name"]: log for log in results_json(RunResult("unit", "x", 1.0, other))["logs"]}
    assert (logs["worse"]["baseline_machine"], logs["worse"]["machine"]) == (THERE, HERE)


def test_bad_baseline_file(tmp_path: Path) -> None:
    path = tmp_path / "b.json"
    path.write_text("{not json")
    with pytest.raises(ManifestError, match=r"b\.json: baseline is not readable JSON"):
        read_baseline(path)
    path.write_text(json.dumps({"logs": {"a": {"metric": {}}}}))
    with pytest.raises(ManifestError, match="baseline entry 'a' lacks 'metrics'"):
        read_baseline(path)
    path.write_bytes(b"\xf0\x9f\xff\x00")
    with pytest.raises(ManifestError, match=r"b\.json: baseline is not readable JSON"):
        read_baseline(path)
    assert read_baseline(tmp_path / "absent.json") == {}
