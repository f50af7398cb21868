"""Manifest parsing: paths resolved against the file, one-line errors naming file and key."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from pipelines.regress.manifest import (
    DEFAULT_SIM_CACHE,
    ManifestError,
    Tolerance,
    Tolerances,
    load_manifest,
)
from pipelines.regress.runner import make_jobs, resolve_config, sim_folder

ROOT = Path(__file__).resolve().parents[2]


def _minimal(**extra: object) -> dict[str, object]:
    data: dict[str, object] = {
        "name": "t",
        "baseline": "base.json",
        "logs": [{"name": "tiny", "simulate": {"scenario": "tiny"}}],
    }
    data.update(extra)
    return data


def test_paths_resolve_against_the_manifest_folder(
    write_manifest: Callable[..., Path], tmp_path: Path
) -> None:
    (tmp_path / "run.mcap").write_bytes(b"")
    (tmp_path / "gt").mkdir()
    (tmp_path / "gt" / "points.csv").write_text("label,floor,x,y,z,t_start,t_end\n")
    path = write_manifest(
        _minimal(
            logs=[
                {"name": "a", "log": "run.mcap", "ground_truth": {"points": "gt/points.csv"}},
                {"name": "b", "simulate": {"scenario": "tiny", "seed": 3}},
            ]
        )
    )
    m = load_manifest(path)
    assert m.baseline == tmp_path / "base.json"
    assert m.logs[0].log == tmp_path / "run.mcap"
    assert m.logs[0].ground_truth.points == tmp_path / "gt" / "points.csv"
    assert m.logs[1].simulate is not None and m.logs[1].simulate.seed == 3
    assert m.sim_cache_dir() == DEFAULT_SIM_CACHE


@pytest.mark.parametrize(
    ("data", "message"),
    [
        (_minimal(tolerance={"default": {"abs": 1}}), "unknown key 'tolerance'"),
        (
            _minimal(logs=[{"name": "x", "simulate": {"scenario": "tiny", "sed": 1}}]),
            "unknown key 'logs[x].simulate.sed'",
        ),
        (
            _minimal(logs=[{"name": "x"}]),
            "invalid value for 'logs[x]': give exactly one of 'log' or 'simulate'",
        ),
        (
            _minimal(logs=[{"name": "x", "log": "a.mcap", "simulate": {"scenario": "tiny"}}]),
            "give exactly one of 'log' or 'simulate'",
        ),
        ({"name": "t", "logs": [{"name": "x", "log": "a"}]}, "missing key 'baseline'"),
        (_minimal(logs=[]), "invalid value for 'logs'"),
        (
            _minimal(tolerances={"metrics": {"points.rmse_m": {"abs": -1}}}),
            "invalid value for 'tolerances.metrics.points.rmse_m.abs'",
        ),
        (
            _minimal(
                logs=[
                    {"name": "x", "simulate": {"scenario": "tiny"}},
                    {"name": "x", "simulate": {"scenario": "stairs"}},
                ]
            ),
            "duplicate log name 'x'",
        ),
    ],
)
def test_bad_manifest_is_one_line_naming_file_and_key(
    write_manifest: Callable[..., Path], data: dict[str, object], message: str
) -> None:
    path = write_manifest(data)
    with pytest.raises(ManifestError) as err:
        load_manifest(path)
    text = str(err.value)
    assert text.startswith(f"{path}: ")
    assert message in text
    assert "\n" not in text


def test_missing_log_file_is_named(write_manifest: Callable[..., Path], tmp_path: Path) -> None:
    path = write_manifest(_minimal(logs=[{"name": "lobby", "log": "nope.mcap"}]))
    with pytest.raises(ManifestError, match=r"logs\[lobby\]\.log not found: .*nope\.mcap"):
        load_manifest(path)


def test_localize_entry_names_one_map(write_manifest: Callable[..., Path], tmp_path: Path) -> None:
    entry = {"name": "day2", "simulate": {"scenario": "tiny-day2"},
             "localize": {"map_simulate": {"scenario": "tiny-day1"}}}
    m = load_manifest(write_manifest(_minimal(logs=[entry])))
    jobs = make_jobs(m, tmp_path / "out")
    assert jobs[0].localize is not None
    assert jobs[0].localize["map_simulate"]["scenario"] == "tiny-day1"
    both = {**entry, "localize": {"map_simulate": {"scenario": "tiny-day1"}, "map_dir": "maps/a"}}
    with pytest.raises(ManifestError, match="exactly one of 'map_simulate', 'map_log' or 'map_dir'"):
        load_manifest(write_manifest(_minimal(logs=[both])))
    missing = {**entry, "localize": {"map_dir": "maps/none"}}
    with pytest.raises(ManifestError, match=r"logs\[day2\]\.localize\.map_dir not found"):
        load_manifest(write_manifest(_minimal(logs=[missing])))


def test_build_with_entry_names_the_other_logs(write_manifest: Callable[..., Path],
                                               tmp_path: Path) -> None:
    entry = {"name": "office3-day1+day2", "simulate": {"scenario": "office3-day1"},
             "build_with": [{"scenario": "office3-day2"}]}
    jobs = make_jobs(load_manifest(write_manifest(_minimal(logs=[entry]))), tmp_path / "out")
    assert [sim["scenario"] for sim in jobs[0].build_with] == ["office3-day2"]
    both = {**entry, "localize": {"map_simulate": {"scenario": "tiny-day1"}}}
    with pytest.raises(ManifestError, match="at most one of 'build_with' or 'localize'"):
        load_manifest(write_manifest(_minimal(logs=[both])))


def test_not_a_mapping_and_not_yaml(tmp_path: Path) -> None:
    bad = tmp_path / "list.yaml"
    bad.write_text("- 1\n- 2\n")
    with pytest.raises(ManifestError, match="expected a mapping"):
        load_manifest(bad)
    broken = tmp_path / "broken.yaml"
    broken.write_text("name: [unclosed\n")
    with pytest.raises(ManifestError, match="not valid YAML"):
        load_manifest(broken)
    with pytest.raises(ManifestError, match="manifest not found"):
        load_manifest(tmp_path / "absent.yaml")
    binary = tmp_path / "log.mcap"  # a log passed where the manifest goes
    binary.write_bytes(b"\x89MCAP0\r\n\xf0\x9f\xff\x00")
    with pytest.raises(ManifestError, match=r"log\.mcap: not a text file \(not UTF-8\)"):
        load_manifest(binary)


def test_tolerance_lookup_exact_then_longest_pattern_then_default() -> None:
    tol = Tolerances(
        default=Tolerance(abs=0.01),
        metrics={
            "points.*": Tolerance(abs=0.1),
            "points.floor*.rmse_m": Tolerance(abs=0.2),
            "points.rmse_m": Tolerance(rel=0.5),
        },
    )
    assert tol.for_metric("points.rmse_m").allowed(0.04) == pytest.approx(0.02)
    assert tol.for_metric("points.floor1.rmse_m").allowed(1.0) == pytest.approx(0.2)
    assert tol.for_metric("points.max_m").allowed(1.0) == pytest.approx(0.1)
    assert tol.for_metric("trajectory.ape_rmse_m").allowed(3.0) == pytest.approx(0.01)
    merged = tol.merged(Tolerances(metrics={"points.max_m": Tolerance(abs=1.0)}))
    assert merged.default.abs == 0.01  # the log did not set a default: the manifest's stays
    assert merged.for_metric("points.max_m").allowed(0.0) == 1.0


def test_directions_follow_eval_names(write_manifest: Callable[..., Path]) -> None:
    m = load_manifest(write_manifest(_minimal()))
    assert m.is_higher_better("cloud.fscore_10cm")
    assert m.is_higher_better("cloud.floor1.recall_5cm")
    assert m.is_higher_better("points.hilti_score")
    assert m.is_higher_better("floors.time_correct_share")
    assert not m.is_higher_better("cloud.fscore_miss_10cm")
    assert not m.is_higher_better("floors.time_wrong_share")
    assert not m.is_higher_better("points.rmse_m")
    assert m.is_ignored("points.count") and m.is_ignored("cloud.map_points")
    assert not m.is_ignored("points.rmse_m")


def test_config_layers_and_bad_config_key(write_manifest: Callable[..., Path], tmp_path: Path) -> None:
    (tmp_path / "c.yaml").write_text("graph:\n  ablation:\n    barometer_factors: false\n")
    path = write_manifest(
        _minimal(
            config="c.yaml",
            config_overrides={"mapping": {"voxel_size_m": 0.3}},
            logs=[
                {"name": "a", "simulate": {"scenario": "tiny"}},
                {
                    "name": "b",
                    "simulate": {"scenario": "tiny"},
                    "config_overrides": {"graph": {"ablation": {"barometer_factors": True}}},
                },
            ],
        )
    )
    m = load_manifest(path)
    a, b = (resolve_config(m, e) for e in m.logs)
    assert a["graph"]["ablation"]["barometer_factors"] is False and a["mapping"]["voxel_size_m"] == 0.3
    assert b["graph"]["ablation"]["barometer_factors"] is True and b["mapping"]["voxel_size_m"] == 0.3
    # Only what the layers set: a default stays a default for the stage that tells them apart.
    assert "floors" not in a and set(a["mapping"]) == {"voxel_size_m"}
    jobs = make_jobs(m, tmp_path / "out")
    assert [j.name for j in jobs] == ["a", "b"]
    assert jobs[0].out_dir == str(tmp_path / "out" / "logs" / "a")

    bad = write_manifest(_minimal(config_overrides={"graph": {"barometer_factor": False}}), "bad.yaml")
    with pytest.raises(ManifestError, match=r"logs\[tiny\]\).*unknown key 'graph.barometer_factor'"):
        make_jobs(load_manifest(bad), tmp_path / "out")


def test_sim_folder_matches_the_test_fixture_layout(write_manifest: Callable[..., Path]) -> None:
    m = load_manifest(write_manifest(_minimal()))
    sim = m.logs[0].simulate
    assert sim is not None
    assert sim_folder(Path("/c"), sim) == Path("/c/tiny-mcap-0")
    scaled = sim.model_copy(update={"duration_scale": 2.0, "seed": 4})
    # The `sim_run` fixture names kwargs runs `<scenario>-<fmt>-<seed>-duration_scale=2.0`.
    assert sim_folder(Path("/c"), scaled) == Path("/c/tiny-mcap-4-duration_scale=2.0")


@pytest.mark.parametrize("name", ["sim_quick.yaml", "sim_full.yaml", "sim_seeds.yaml", "stress.yaml",
                                  "localize.yaml", "multilog.yaml"])
def test_shipped_manifests_load(name: str) -> None:
    from mfmap.sim import SCENARIOS

    m = load_manifest(ROOT / "pipelines" / "manifests" / name)
    assert m.baseline.parent == ROOT / "pipelines" / "baselines"
    assert all(e.simulate is not None and e.simulate.scenario in SCENARIOS for e in m.logs)
    assert len(make_jobs(m, Path("/tmp/x"))) == len(m.logs)


def test_stress_manifest_covers_every_condition() -> None:
    """At least 12 logs from at least 4 buildings, each hard condition in at least two (the
    routes and buildings only: seconds, no sensors), some on the 2D LaserScan."""
    from mfmap.sim.run import build_trajectory
    from mfmap.sim.scenarios import SCENARIOS, building_for

    m = load_manifest(ROOT / "pipelines" / "manifests" / "stress.yaml")
    assert len(m.logs) >= 12
    seen: dict[str, int] = {}
    buildings = set()
    for e in m.logs:
        assert e.simulate is not None
        spec = SCENARIOS[e.simulate.scenario]
        b = building_for(spec, e.simulate.seed)
        tr = build_trajectory(spec, b, e.simulate.seed, 1)
        buildings.add(b.spec)
        rides = [t for t in tr.transitions if t.kind == "elevator"]
        walks = [t for t in tr.transitions if t.kind == "stairs"]
        conditions = {
            "harsh air": spec.world.outdoor_minus_indoor_k is not None and spec.world.temperature_sensor is not None,
            "switch-back stairs": b.spec.stairwell.kind == "switchback" and bool(walks),
            "floor passed on stairs": any(abs(t.to_floor - t.from_floor) > 1 for t in walks),
            "elevator stop": any(t.t_start_s < d[0] < t.t_end_s for t in rides for d in tr.door_open),
            "unequal storeys": not b.uniform,
            "generated building": b.spec.name.startswith("generated"),
            "storey under 3 m": min(b.storeys_m) < 3.0,
            "storey over 5.5 m": max(b.storeys_m) >= 5.5,
            "2D LaserScan": spec.lidar is None and spec.laser is not None,
        }
        for k, v in conditions.items():
            seen[k] = seen.get(k, 0) + int(v)
    assert len(buildings) >= 4
    assert all(n >= 2 for n in seen.values()), seen
