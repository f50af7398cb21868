"""The regression pipeline end to end: real simulated logs, real builds and evals, local and Ray.

The quick shipped manifest (`pipelines/manifests/sim_quick.yaml`, two short scenarios) is run
once locally and once on a local Ray instance; the committed baseline must pass, the two
backends must agree exactly, and a deliberately worse configuration must fail naming the metric.
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from pipelines.regress.manifest import load_manifest
from pipelines.regress.model import RunResult, Verdict
from pipelines.regress.runner import make_jobs, run_regression
from pipelines.regression import lay_config
from pipelines.regression import main as regression_main

ROOT = Path(__file__).resolve().parents[2]
QUICK = ROOT / "pipelines" / "manifests" / "sim_quick.yaml"
QUICK_BASELINE = ROOT / "pipelines" / "baselines" / "sim_quick.json"


@pytest.fixture(scope="module")
def ray_local() -> Iterator[None]:
    """A local Ray instance for this module, as CI runs it."""
    ray = pytest.importorskip("ray", reason="the ray extra is not installed: pip install -e .[ray]")
    from pipelines.regress.runner import init_ray

    init_ray(num_cpus=2)
    yield
    ray.shutdown()


def test_broken_log_is_an_error_row_on_both_backends(tmp_path: Path, ray_local: None) -> None:
    """Each log that cannot be built is an error row with its message; one failing does not
    stop the next, on either backend, and both backends report the same errors."""
    (tmp_path / "garbage.mcap").write_bytes(b"\x89MCAP0\r\nthis is not an mcap file")
    (tmp_path / "empty.bag").write_bytes(b"")
    manifest_path = tmp_path / "broken.yaml"
    manifest_path.write_text(
        yaml.safe_dump(
            {
                "name": "broken",
                "baseline": "base.json",
                "logs": [
                    {"name": "garbage", "log": "garbage.mcap"},
                    {"name": "empty", "log": "empty.bag"},
                ],
            }
        )
    )
    manifest = load_manifest(manifest_path)
    local = run_regression(manifest, tmp_path / "local", workers=2)
    on_ray = run_regression(manifest, tmp_path / "ray", use_ray=True)
    for run in (local, on_ray):
        assert run.exit_code == 1
        assert sorted(r.name for r in run.results) == ["empty", "garbage"]
        assert {r.verdict for r in run.results} == {Verdict.ERROR}
        for r in run.results:
            assert r.outcome.stage == "build"
            assert r.outcome.error is not None and "\n" not in r.outcome.error
    errors_local = {r.name: r.outcome.error for r in local.results}
    errors_ray = {r.name: r.outcome.error for r in on_ray.results}
    assert errors_local == errors_ray
    assert "garbage.mcap" in (errors_local["garbage"] or "")
    assert on_ray.backend.startswith("ray[local, 2 CPUs]")
    suite = ET.parse(tmp_path / "ray" / "junit.xml").getroot().find("testsuite")
    assert suite is not None and suite.get("errors") == "2"


def test_unexpected_error_is_retried_once_then_reported(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A job that raises something other than an MfmapError (a bug, a crash) gets one retry."""
    from pipelines.regress.model import LogJob
    from pipelines.regress.runner import run_local

    # A scenario spec the simulator's model rejects inside the worker (pydantic, not MfmapError).
    job = LogJob(name="odd", out_dir=str(tmp_path / "odd"), config={}, simulate={"scenario": 3.5})
    with caplog.at_level("WARNING", logger="pipelines.regress.runner"):
        (outcome,) = list(run_local([job], workers=1))
    assert not outcome.ok and outcome.stage == "simulate"
    assert outcome.error is not None and outcome.error.startswith("ValidationError:")
    retries = [r for r in caplog.records if "retrying once" in r.getMessage()]
    assert len(retries) == 1


def test_cli_exit_codes_and_update_baseline_keeps_failed_entry(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "garbage.mcap").write_bytes(b"not an mcap file at all")
    baseline = tmp_path / "base.json"
    baseline.write_text(json.dumps({"format": 1, "logs": {"garbage": {"metrics": {"points.rmse_m": 0.05}}}}))
    manifest = tmp_path / "m.yaml"
    manifest.write_text(
        yaml.safe_dump({"name": "cli", "baseline": "base.json", "logs": [{"name": "garbage", "log": "garbage.mcap"}]})
    )
    code = regression_main([str(manifest), "--out", str(tmp_path / "out"), "--workers", "1", "--update-baseline"])
    assert code == 1
    out = capsys.readouterr()
    assert "| garbage | error |" in out.out
    assert "error       garbage" in out.err
    # The failed build did not erase its reference.
    assert json.loads(baseline.read_text())["logs"]["garbage"]["metrics"] == {"points.rmse_m": 0.05}
    results = json.loads((tmp_path / "out" / "results.json").read_text())
    assert results["exit_code"] == 1 and results["failed"] == ["garbage"]

    manifest.write_text("name: cli\nbaseline: base.json\nlogs:\n  - name: x\n    lg: a.mcap\n")
    assert regression_main([str(manifest)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"regression: error: {manifest}: unknown key 'logs[x].lg'"]
    with pytest.raises(SystemExit) as exc:
        regression_main([str(manifest), "--workers", "0"])
    assert exc.value.code == 2


def test_config_file_is_laid_over_every_log(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--config FILE: an ablation over the whole set, over the manifest's and the logs' own
    overrides; it cannot update the baseline, and a key mfmap does not know is a usage error."""
    manifest = tmp_path / "m.yaml"
    manifest.write_text(yaml.safe_dump({
        "name": "abl", "baseline": "base.json",
        "config_overrides": {"graph": {"ablation": {"walk_height": True}}},
        "logs": [{"name": "a", "log": "a.mcap"},
                 {"name": "b", "log": "b.mcap", "config_overrides": {"graph": {"ablation": {"imu_ride_height": True}}}}],
    }))
    for name in ("a", "b"):
        (tmp_path / f"{name}.mcap").write_bytes(b"")
    baro_only = tmp_path / "baro_only.yaml"
    baro_only.write_text("graph:\n  ablation:\n    imu_ride_height: false\n    walk_height: false\n")
    loaded = load_manifest(manifest)
    lay_config(loaded, baro_only)
    for job in make_jobs(loaded, tmp_path / "out"):
        assert job.config["graph"]["ablation"] == {"imu_ride_height": False, "walk_height": False}, job.name
    with pytest.raises(SystemExit) as exc:
        regression_main([str(manifest), "--config", str(baro_only), "--update-baseline"])
    assert exc.value.code == 2
    capsys.readouterr()
    baro_only.write_text("graph:\n  ablation:\n    imu_ride_hieght: false\n")
    assert regression_main([str(manifest), "--config", str(baro_only), "--out", str(tmp_path / "o")]) == 2
    assert "imu_ride_hieght" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------
# The shipped quick set: real simulated logs, real builds, the committed baseline.


def _quick_tiny(folder: Path, **extra: object) -> Path:
    """The quick manifest with its `tiny` log alone (and `extra` keys), written in `folder`."""
    data = yaml.safe_load(QUICK.read_text())
    data["baseline"] = str(QUICK_BASELINE)
    data["logs"] = [e for e in data["logs"] if e["name"] == "tiny"]
    data.update(extra)
    path = folder / "tiny.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.fixture(scope="module")
def quick_local(tmp_path_factory: pytest.TempPathFactory) -> RunResult:
    out = tmp_path_factory.mktemp("quick-local")
    return run_regression(load_manifest(QUICK), out)


def test_quick_set_passes_against_committed_baseline(quick_local: RunResult) -> None:
    verdicts = {r.name: r.verdict for r in quick_local.results}
    assert verdicts == {"tiny": Verdict.PASS, "tiny-2d": Verdict.PASS}, [
        (r.name, r.outcome.error, [c.describe() for c in r.regressions]) for r in quick_local.results
    ]
    assert quick_local.exit_code == 0
    tiny = next(r for r in quick_local.results if r.name == "tiny")
    # The map is good, not only unchanged: absolute errors against the simulator's ground truth.
    assert tiny.outcome.metrics["floors.count_correct"] == 1.0
    assert tiny.outcome.metrics["trajectory.ape_rmse_m"] < 0.5
    assert tiny.outcome.metrics["floors.elevation_error_max_m"] < 0.5


def test_ray_run_equals_local_run(
    quick_local: RunResult, ray_local: None, tmp_path: Path
) -> None:
    """The quick set's 3D log rebuilt on Ray gives the local run's figures bit for bit. One log
    shows it (the job is the same function on either backend); each more is a whole build."""
    on_ray = run_regression(load_manifest(_quick_tiny(tmp_path)), tmp_path / "ray", use_ray=True)
    local = next(r for r in quick_local.results if r.name == "tiny")
    (remote,) = on_ray.results
    assert remote.outcome.metrics == local.outcome.metrics  # bit-identical: deterministic builds
    assert remote.verdict is local.verdict is Verdict.PASS


def test_worse_config_fails_naming_the_metric(tmp_path: Path) -> None:
    """Inter-floor registration, elevator continuity and the cabin filter off: nothing but the
    odometry across the ride places floor 1 over floor 0, and the cabin's walls pull it, so the
    upper floor's error is what regresses (measured: 7.5 -> 38.5 mm; with the cabin filter on,
    11.5 mm, within the tolerance)."""
    path = _quick_tiny(tmp_path, config_overrides={
        "graph": {"ablation": {"inter_floor_registration": False, "elevator_continuity": False}},
        "mapping": {"cabin": {"filter": False}},
    })
    run = run_regression(load_manifest(path), tmp_path / "out", workers=1)
    assert run.exit_code == 1
    (tiny,) = run.results
    assert tiny.verdict is Verdict.REGRESSED
    regressed = [c.metric for c in tiny.regressions]
    assert "points.floor1.rmse_m" in regressed, regressed
    # The start floor, which the switches cannot touch, keeps its accuracy.
    assert not [m for m in regressed if ".floor0." in m], regressed
    summary = (tmp_path / "out" / "summary.md").read_text()
    row = next(line for line in summary.splitlines() if line.startswith("| tiny |"))
    assert "| regressed |" in row and f"| {len(regressed)} |" in row
    failure = ET.parse(tmp_path / "out" / "junit.xml").getroot().find("testsuite/testcase/failure")
    assert failure is not None
    assert all(m in (failure.get("message") or "") for m in regressed)
