from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from mfmap.config import MfmapConfig, dump_config, load_config
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
    assert (cfg.mapping.voxel_size_m, cfg.mapping.map_voxel_size_m, cfg.mapping.scan_stride) == (0.4, 0.2, 2)
    assert cfg.model_copy(update={"mapping": default.mapping}) == default
