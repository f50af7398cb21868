from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class ExportConfig(BaseModel):
    """Output clouds and occupancy grids."""

    model_config = ConfigDict(extra="forbid")

    grid_resolution_m: float = Field(0.05, description="occupancy grid cell size")
