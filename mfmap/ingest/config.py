from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class IngestConfig(BaseModel):
    """Which topics play which role; by default chosen by message type."""

    model_config = ConfigDict(extra="forbid")

    topics: dict[str, str] = Field(
        default_factory=dict,
        description="role -> topic overrides, e.g. {lidar: /os1/points, baro: /pressure}",
    )
    base_frame: str = Field("base_link", description="robot base frame for /tf_static")
