"""`mfmap floors` end to end: read the barometer (and motion) from a log or a CSV, segment it."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from mfmap.config import MfmapConfig
from mfmap.errors import LogError
from mfmap.floors.imu import ImuTiming
from mfmap.floors.io import read_pressure_csv
from mfmap.floors.motion import MotionEvidence, motion_from_imu, motion_from_odometry
from mfmap.floors.segment import segment_pressure
from mfmap.logs import collect_warnings
from mfmap.types import FloorSegmentation

if TYPE_CHECKING:
    from mfmap.ingest.source import LogSource

logger = logging.getLogger(__name__)

CSV_SUFFIXES = (".csv", ".tsv", ".txt")


def segment_path(path: Path, cfg: MfmapConfig) -> FloorSegmentation:
    """Floors of a log (.mcap, .bag, ROS 2 bag folder) or of a t,pressure CSV."""
    if not path.exists():
        raise LogError("no such file or folder", path)
    if path.is_file() and path.suffix.lower() in CSV_SUFFIXES:
        pressure, warnings = read_pressure_csv(path)
        seg = segment_pressure(pressure, None, cfg.floors)
        return dataclasses.replace(seg, warnings=tuple(warnings) + seg.warnings)

    from mfmap.ingest import open_log

    with open_log(path, cfg.ingest) as src:
        with collect_warnings() as notes:
            cfg, _ = barometer_temperature(src, cfg)
        pressure = src.pressure()
        motion: MotionEvidence | None = None
        odom = src.odometry()
        imu = src.imu()
        if odom is not None and len(odom) > 1:
            motion = motion_from_odometry(odom, cfg.floors)
        elif imu is not None and len(imu) > 1:
            motion = motion_from_imu(imu, cfg.floors)
        warnings = list(src.warnings) + [n.removeprefix("floors: ") for n in notes.lines()]
    seg = segment_pressure(pressure, motion, cfg.floors, ImuTiming.of(imu))
    if motion is None:
        warnings.append("no odometry or IMU: transition kinds are unknown")
    return dataclasses.replace(seg, warnings=tuple(warnings) + seg.warnings)


# A Temperature topic reads the air's temperature, or the sensor's die a few kelvin warmer; outside
# this range (deg C) it is not the air of a building (a wrong topic, another unit).
_AIR_C = (-30.0, 60.0)


def barometer_temperature(src: LogSource, cfg: MfmapConfig) -> tuple[MfmapConfig, float | None]:
    """The config the stages use, with floors.temperature_k from the barometer's Temperature
    topic (its median) when the log has one and the user did not set the temperature, and the
    sigma of the barometer's height scale that goes with it (None: the graph's default, for the
    assumed temperature). Its notes are logged."""
    temperature = src.temperature()
    if temperature is None or len(temperature) == 0:
        return cfg, None
    median_c = float(np.median(temperature.temperature_c))
    if "temperature_k" in cfg.floors.model_fields_set:
        logger.warning("temperature_k set in the config (%g K): the barometer's Temperature topic %s "
                       "(%.1f deg C) is not used", cfg.floors.temperature_k, temperature.topic, median_c)
        return cfg, None
    if not _AIR_C[0] <= median_c <= _AIR_C[1]:
        logger.warning("%s reads %.1f deg C, not the air of a building: not used for the barometer's "
                       "scale", temperature.topic, median_c)
        return cfg, None
    temperature_k = median_c + 273.15
    logger.warning("barometer's height scale at %.1f deg C (median of %s)", median_c, temperature.topic)
    floors = cfg.floors.model_copy(update={"temperature_k": temperature_k})
    return cfg.model_copy(update={"floors": floors}), cfg.graph.barometer.temperature_sigma_k / temperature_k
