"""export stage configuration: output clouds, occupancy grids and files."""
from __future__ import annotations

from enum import Enum

from pydantic import BaseModel, ConfigDict, Field, model_validator

_SECTION = ConfigDict(extra="forbid", allow_inf_nan=False)

# Memory per grid cell while a floor's grid is drawn (free and occupied masks, the image).
GRID_BYTES_PER_CELL = 4


class CloudSource(str, Enum):
    SCANS = "scans"  # every lidar scan at its optimised pose (the log is read a second time)
    KEYFRAMES = "keyframes"  # the mapping stage's keyframe clouds only (faster, sparser)


class GridConfig(BaseModel):
    """Each floor's occupancy grid."""

    model_config = _SECTION

    resolution_m: float = Field(0.05, ge=0.005, le=10.0, description="occupancy grid cell size")
    band_m: tuple[float, float] = Field(
        (0.1, 1.8), description="obstacles: points this high above the floor (min, max)"
    )
    level_band: bool = Field(
        True,
        description="measure the obstacle band in the robot's frame (a ground robot stands level "
        "on its floor), so a small roll/pitch error of a pose cannot lift the floor into the band",
    )
    view_spacing_m: float = Field(
        0.25, gt=0.0, description="ray-cast free space from a scan after this much travel (or 10 deg turn)"
    )
    min_hits: int = Field(
        2, ge=1, description="a cell is occupied when this many scans hit it (1 for keyframes)"
    )
    max_range_m: float = Field(30.0, gt=0.0, le=1000.0, description="free space is ray-cast up to this range")
    max_mb: float = Field(
        2048.0, gt=0.0, le=1e6,
        description="a floor's occupancy grid may take this much memory (about 4 bytes a cell "
        "while it is drawn): a larger one is refused before it is allocated",
    )

    @model_validator(mode="after")
    def _consistent(self) -> GridConfig:
        band_lo, band_hi = self.band_m
        if not band_lo < band_hi:
            raise ValueError(f"band_m {self.band_m} must be (min, max) with min < max")
        # One scan's view alone spans twice the ray-cast range: the smallest grid there is.
        cells = (2.0 * self.max_range_m / self.resolution_m) ** 2
        if cells * GRID_BYTES_PER_CELL > self.max_mb * 1e6:
            raise ValueError(
                f"resolution_m {self.resolution_m:g} with max_range_m "
                f"{self.max_range_m:g} makes even one scan's grid {cells:.3g} cells, more "
                f"than max_mb ({self.max_mb:g} MB) allows")
        return self


class CloudConfig(BaseModel):
    """Each floor's exported point cloud."""

    model_config = _SECTION

    voxel_m: float = Field(0.05, ge=0.005, le=10.0, description="voxel of the exported clouds")
    min_range_m: float = Field(0.4, ge=0.0, le=100.0, description="drop returns closer than this (robot body)")
    source: CloudSource = Field(
        CloudSource.SCANS,
        description="clouds and grids from every lidar scan at its optimised pose ('scans') "
        "or from the keyframe clouds only ('keyframes', faster, sparser)",
    )


class ExportConfig(BaseModel):
    """Output clouds and occupancy grids."""

    model_config = _SECTION

    transition_margin_s: float = Field(
        3.0, ge=0.0, le=3600.0, description="scans this close to a ride or stair walk stay out of the floor maps"
    )
    scan_min_motion_m: float = Field(
        0.05, ge=0.0,
        description="clouds and grids use a scan only after the robot moved this far (or turned "
        "scan_min_turn_deg) since the last one used: a robot standing still adds nothing",
    )
    scan_min_turn_deg: float = Field(2.0, ge=0.0, description="see scan_min_motion_m")
    deskew: bool = Field(
        True,
        description="move each lidar point to the scan's stamp with the optimised trajectory "
        "(columns fire at their own time over the sweep)",
    )
    workers: int = Field(
        2,
        ge=1,
        le=256,
        description="processes reading the log a second time for the clouds and grids, one group "
        "of floors each (the maps are the same for any number; the build's mapping workers are "
        "reused, so they cost no second start-up)",
    )
    html_report: bool = Field(True, description="write report.html")
    grid: GridConfig = Field(default_factory=GridConfig, description="each floor's occupancy grid")
    cloud: CloudConfig = Field(default_factory=CloudConfig, description="each floor's point cloud")
