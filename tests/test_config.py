from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from mfmap.config import RENAMED_KEYS, MfmapConfig, config_from_dict, dump_config, load_config
from mfmap.errors import ConfigError

ROOT = Path(__file__).resolve().parent.parent


def test_sample_config_is_what_mfmap_config_prints() -> None:
    printed = subprocess.run(
        [sys.executable, "-m", "mfmap.cli", "config"], capture_output=True, text=True, check=True
    ).stdout
    assert printed == (ROOT / "sample_configs" / "default.yaml").read_text()


def test_sample_config_loads_to_the_defaults() -> None:
    cfg = load_config(ROOT / "sample_configs" / "default.yaml")
    assert dump_config(cfg) == dump_config(load_config(None))


def test_unknown_key_names_key_and_file(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("floors:\n  temprature_k: 290\n")
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert str(err.value) == f"{path}: unknown key 'floors.temprature_k'"


def test_unknown_stage_and_bad_value(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("mappin: {}\n")
    with pytest.raises(ConfigError, match="unknown key 'mappin'"):
        load_config(path)
    path.write_text("floors:\n  temperature_k: warm\n")
    with pytest.raises(ConfigError, match=r"invalid value for 'floors\.temperature_k'"):
        load_config(path)


def test_overrides_and_partial_file(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text("floors:\n  temperature_k: 280\n")
    cfg = load_config(path, {"ingest": {"topics": {"lidar": "/x"}}})
    assert cfg.floors.temperature_k == 280.0
    assert cfg.ingest.topics == {"lidar": "/x"}
    assert cfg.mapping == load_config(None).mapping


def test_missing_and_non_mapping_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="config file not found"):
        load_config(tmp_path / "nope.yaml")
    path = tmp_path / "list.yaml"
    path.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="expected a mapping"):
        load_config(path)


def test_fast_preset_loads_and_changes_only_mapping() -> None:
    cfg = load_config(ROOT / "sample_configs" / "fast.yaml")
    default = MfmapConfig()
    assert (cfg.mapping.voxel_size_m, cfg.mapping.local_map.voxel_size_m, cfg.mapping.scan_stride) == (0.4, 0.2, 2)
    assert cfg.model_copy(update={"mapping": default.mapping}) == default


@pytest.mark.parametrize(("text", "message"), [
    # Each once failed only in a worker after the build started, or allocated without bound,
    # or passed and gave a degraded map.
    ("mapping: {voxel_size_m: 0}", r"'mapping\.voxel_size_m': Input should be greater than or equal to 0\.01 \(got 0\)"),
    ("mapping: {voxel_size_m: -0.1}", r"'mapping\.voxel_size_m': Input should be greater"),
    ("mapping: {voxel_size_m: 1.0e-9}", r"'mapping\.voxel_size_m': .* \(got 1e-09\)"),
    ("mapping: {voxel_size_m: .nan}", r"'mapping\.voxel_size_m': Input should be a finite number"),
    ("mapping: {min_range_m: 50}", r"'mapping': min_range_m \(50\) must be below max_range_m \(40\)"),
    ("export: {grid: {resolution_m: 1.0e-6}}", r"'export\.grid\.resolution_m': Input should be greater"),
    ("export: {grid: {resolution_m: 0.005, max_range_m: 500}}", r"makes even one scan's grid 4e\+10 cells"),
    ("export: {grid: {band_m: [1.8, 0.1]}}", r"'export\.grid': band_m \(1\.8, 0\.1\) must be \(min, max\)"),
    ("ingest: {max_cloud_mb: -1}", r"'ingest\.max_cloud_mb': Input should be greater than 0"),
    ("graph: {interfloor: {voxel_m: .inf}}", r"'graph\.interfloor\.voxel_m': Input should be a finite number"),
    ("graph: {interfloor: {band_m: [1.5, 0.5]}}", r"'graph\.interfloor': band_m \(1\.5, 0\.5\) must be"),
    ("graph: {robust: {outlier_chi2_p: 1.5}}", r"'graph\.robust\.outlier_chi2_p': Input should be less than 1"),
    ("floors: {transitions: {stop_vertical_speed_m_s: 0.5}}",
     r"'floors\.transitions': vertical speeds must be stop < min < max"),
    ("mapping: {cabin: {size_m: [2.4, 0]}}", r"'mapping\.cabin': size_m \(2\.4, 0\.0\) must be two sizes"),
    ("mapping: {icp: {max_iterations: 0}}", r"'mapping\.icp\.max_iterations': Input should be greater"),
    ("mapping: {workers: 100000}", r"'mapping\.workers': Input should be less than or equal to 256"),
    ("eval: {fscore_thresholds_m: [0.05, -1]}", r"must be one or more distances in \(0, 100\] m"),
    ("ingest: {extrinsics: {lidar: {xyz: [0, 0, 500]}}}",
     r"'ingest\.extrinsics\.lidar\.xyz\.2': Input should be less than or equal to 100"),
    ("ingest: {extrinsics: {lidar: {rpy_deg: [0, .nan, 0]}}}",
     r"'ingest\.extrinsics\.lidar\.rpy_deg\.1': Input should be a finite number"),
])
def test_values_that_would_fail_a_stage_are_refused_at_load(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "c.yaml"
    path.write_text(text + "\n")
    with pytest.raises(ConfigError, match=message) as err:
        load_config(path)
    assert "\n" not in str(err.value) and str(err.value).startswith(f"{path}: invalid value for ")


def test_a_binary_config_is_one_line(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_bytes(bytes(range(256)) * 4)
    res = subprocess.run([sys.executable, "-m", "mfmap.cli", "config", "--config", str(path)],
                         capture_output=True, text=True)
    assert res.returncode == 1
    assert res.stderr.strip() == f"mfmap: error: {path}: not a text file (byte 128 is not UTF-8)"


def test_a_flat_key_of_before_the_sections_names_its_new_key(tmp_path: Path) -> None:
    path = tmp_path / "old.yaml"
    path.write_text("mapping:\n  icp_max_iterations: 10\n")
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert str(err.value) == (
        f"{path}: unknown key 'mapping.icp_max_iterations' (it is now 'mapping.icp.max_iterations')")


def _leaves(data: dict[str, object], prefix: str = "") -> list[str]:
    out: list[str] = []
    for key, value in data.items():
        if isinstance(value, dict) and key not in ("topics", "extrinsics"):
            out += _leaves(value, f"{prefix}{key}.")
        else:
            out.append(prefix + key)
    return out


def test_every_renamed_key_is_refused_and_its_new_key_exists() -> None:
    leaves = set(_leaves(MfmapConfig().model_dump(mode="json")))
    assert len(RENAMED_KEYS) == 114
    assert len(set(RENAMED_KEYS.values())) == len(RENAMED_KEYS)
    for old, new in RENAMED_KEYS.items():
        assert new in leaves and old not in leaves
        stage, key = old.split(".")
        with pytest.raises(ConfigError, match=f"it is now '{new}'"):
            config_from_dict({stage: {key: None}})


def test_ablation_switches_have_their_own_section() -> None:
    switches = MfmapConfig().graph.ablation.model_dump()
    assert len(switches) == 8 and all(value is True for value in switches.values())
