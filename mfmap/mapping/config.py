from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class MappingConfig(BaseModel):
    """Per-floor lidar odometry, keyframes and loop closure."""

    model_config = ConfigDict(extra="forbid")

    voxel_size_m: float = Field(0.2, description="downsampling voxel for registration")
