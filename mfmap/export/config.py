"""export stage."""
from __future__ import annotations

from enum import Enum

from pydantic import BaseModel, ConfigDict, Field


class CloudSource(str, Enum):
    SCANS = "scans"  # every lidar scan at its optimised pose (the log is read a second time)
    KEYFRAMES = "keyframes"  # the mapping stage's keyframe clouds only (faster, sparser)


class ExportConfig(BaseModel):
    """Output clouds and occupancy grids."""

    model_config = ConfigDict(extra="forbid")

    grid_resolution_m: float = Field(0.05, description="occupancy grid cell size")
    grid_band_m: tuple[float, float] = Field(
        (0.1, 1.8), description="obstacles: points this high above the floor (min, max)"
    )
    grid_level_band: bool = Field(
        True,
        description="measure the obstacle band in the robot's frame (a ground robot stands level "
        "on its floor), so a small roll/pitch error of a pose cannot lift the floor into the band",
    )
    grid_view_spacing_m: float = Field(
        0.25, description="ray-cast free space from a scan after this much travel (or 10 deg turn)"
    )
    grid_min_hits: int = Field(
        2, ge=1, description="a cell is occupied when this many scans hit it (1 for keyframes)"
    )
    transition_margin_s: float = Field(
        3.0, description="scans this close to a ride or stair walk stay out of the floor maps"
    )
    grid_max_range_m: float = Field(30.0, description="free space is ray-cast up to this range")
    scan_min_motion_m: float = Field(
        0.05,
        description="clouds and grids use a scan only after the robot moved this far (or turned "
        "scan_min_turn_deg) since the last one used: a robot standing still adds nothing",
    )
    scan_min_turn_deg: float = Field(2.0, description="see scan_min_motion_m")
    deskew: bool = Field(
        True,
        description="move each lidar point to the scan's stamp with the optimised trajectory "
        "(columns fire at their own time over the sweep)",
    )
    cloud_voxel_m: float = Field(0.05, description="voxel of the exported clouds")
    cloud_min_range_m: float = Field(0.4, description="drop returns closer than this (robot body)")
    cloud_source: CloudSource = Field(
        CloudSource.SCANS,
        description="clouds and grids from every lidar scan at its optimised pose ('scans') "
        "or from the keyframe clouds only ('keyframes', faster, sparser)",
    )
    workers: int = Field(
        2,
        ge=1,
        description="processes reading the log a second time for the clouds and grids, one group "
        "of floors each (the maps are the same for any number; the build's mapping workers are "
        "reused, so they cost no second start-up)",
    )
    html_report: bool = Field(True, description="write report.html")
