"""`mfmap floors` end to end: read the barometer (and motion) from a log or a CSV, segment it."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

from mfmap.config import MfmapConfig
from mfmap.errors import LogError
from mfmap.floors.io import read_pressure_csv
from mfmap.floors.motion import MotionEvidence, motion_from_imu, motion_from_odometry
from mfmap.floors.segment import segment_pressure
from mfmap.types import FloorSegmentation

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
        pressure = src.pressure()
        motion: MotionEvidence | None = None
        odom = src.odometry()
        if odom is not None and len(odom) > 1:
            motion = motion_from_odometry(odom, cfg.floors)
        else:
            imu = src.imu()
            if imu is not None and len(imu) > 1:
                motion = motion_from_imu(imu, cfg.floors)
        warnings = list(src.warnings)
    seg = segment_pressure(pressure, motion, cfg.floors)
    if motion is None:
        warnings.append("no odometry or IMU: transition kinds are unknown")
    return dataclasses.replace(seg, warnings=tuple(warnings) + seg.warnings)
