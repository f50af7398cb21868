"""The barometer's Temperature topic (sensor_msgs/Temperature in the barometer's frame)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

import tests.ingest.ingest_logwriter as lw
from mfmap.config import MfmapConfig
from mfmap.errors import LogError
from mfmap.floors.pipeline import barometer_temperature
from mfmap.ingest import open_log
from mfmap.ingest.config import IngestConfig
from mfmap.logs import collect_warnings
from mfmap.types import Role


def _temperature(store: Any, stamp_ns: int, frame: str, value_c: float) -> Any:
    return store.types["sensor_msgs/msg/Temperature"](
        header=lw._header(store, stamp_ns, frame), temperature=value_c, variance=0.0
    )


def _log(path: Path, ros1: bool, temps: dict[str, tuple[str, list[float]]]) -> Path:
    """A barometer in frame 'baro' (10 readings) and Temperature topics: name -> (frame, values)."""
    store = lw.typestore(ros1)
    items = [("/baro/pressure", "sensor_msgs/msg/FluidPressure", lw.T0_NS + i * 10**8,
              lw.pressure_msg(store, lw.T0_NS + i * 10**8, 101_000.0)) for i in range(10)]
    for topic, (frame, values) in temps.items():
        items += [(topic, "sensor_msgs/msg/Temperature", lw.T0_NS + i * 10**8 + 1,
                   _temperature(store, lw.T0_NS + i * 10**8 + 1, frame, v)) for i, v in enumerate(values)]
    items.sort(key=lambda item: item[2])
    return lw.write_mcap_items(path, items, store, ros1=ros1)


@pytest.mark.parametrize("ros1", [False, True])
def test_the_temperature_in_the_barometers_frame_is_read(tmp_path: Path, ros1: bool) -> None:
    """Two Temperature topics: the CPU's (more messages) and the barometer's; only the
    barometer's frame says anything about the air the barometer is in."""
    path = _log(tmp_path / "t.mcap", ros1, {
        "/cpu/temperature": ("cpu", [55.0] * 8),
        "/baro/temperature": ("baro", [21.0, 21.5, 22.0, 22.5, 23.0]),
    })
    with open_log(path) as src:
        assert src.roles[Role.TEMPERATURE] == "/cpu/temperature"  # by count, as every role
        series = src.temperature()
        assert series is not None
        assert series.topic == "/baro/temperature" and series.frame_id == "baro"
        assert series.temperature_c.tolist() == [21.0, 21.5, 22.0, 22.5, 23.0]
        assert np.all(np.diff(series.stamp_ns) > 0)
        assert len(src.pressure()) == 10  # read in the same pass
        with collect_warnings() as collected:
            cfg, sigma = barometer_temperature(src, MfmapConfig())
    assert cfg.floors.temperature_k == pytest.approx(22.0 + 273.15)
    assert sigma == pytest.approx(2.0 / (22.0 + 273.15))
    assert collected.lines() == ["floors: barometer's height scale at 22.0 deg C (median of /baro/temperature)"]


def test_no_temperature_in_the_barometers_frame(tmp_path: Path) -> None:
    path = _log(tmp_path / "t.mcap", False, {"/cpu/temperature": ("cpu", [55.0] * 3)})
    with open_log(path) as src:
        assert src.temperature() is None
        assert any("no Temperature topic in the barometer's frame 'baro'" in w for w in src.warnings)
        cfg, sigma = barometer_temperature(src, MfmapConfig())
    assert cfg.floors.temperature_k == MfmapConfig().floors.temperature_k and sigma is None
    # Chosen in the config, the topic is used whatever its frame.
    with open_log(path, IngestConfig(topics={"temperature": "/cpu/temperature"})) as src:
        series = src.temperature()
        assert series is not None and series.temperature_c.tolist() == [55.0] * 3
        cfg, sigma = barometer_temperature(src, MfmapConfig())
    # 55 deg C is within what a building's air can be; 200 is not.
    assert cfg.floors.temperature_k == pytest.approx(328.15)
    path = _log(tmp_path / "hot.mcap", False, {"/baro/temperature": ("baro", [200.0] * 3)})
    with open_log(path) as src, collect_warnings() as collected:
        cfg, sigma = barometer_temperature(src, MfmapConfig())
    assert sigma is None and cfg.floors.temperature_k == MfmapConfig().floors.temperature_k
    assert collected.lines() == ["floors: /baro/temperature reads 200.0 deg C, not the air of a building: not used for "
                        "the barometer's scale"]


def test_a_configured_temperature_wins(tmp_path: Path) -> None:
    path = _log(tmp_path / "t.mcap", False, {"/baro/temperature": ("baro", [30.0] * 3)})
    cfg = MfmapConfig.model_validate({"floors": {"temperature_k": 280.0}})
    with open_log(path) as src, collect_warnings() as collected:
        used, sigma = barometer_temperature(src, cfg)
    assert used.floors.temperature_k == 280.0 and sigma is None
    assert "is not used" in collected.lines()[0]


def test_a_temperature_topic_of_the_wrong_type_is_an_error(tmp_path: Path) -> None:
    path = _log(tmp_path / "t.mcap", False, {"/baro/temperature": ("baro", [20.0])})
    with pytest.raises(LogError, match="role temperature needs sensor_msgs/msg/Temperature"), \
            open_log(path, IngestConfig(topics={"temperature": "/baro/pressure"})):
        pass
