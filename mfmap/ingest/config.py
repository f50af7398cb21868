from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


class IngestConfig(BaseModel):
    """Which topics play which role; by default chosen by message type."""

    model_config = ConfigDict(extra="forbid")

    topics: dict[str, str] = Field(
        default_factory=dict,
        description="role -> topic overrides, e.g. {lidar: /os1/points, baro: /pressure}",
    )
    base_frame: str = Field("base_link", description="robot base frame for /tf_static")
    pressure_unit: Literal["auto", "Pa", "hPa", "kPa"] = Field(
        "auto",
        description="unit the barometer publishes in; auto detects hPa/kPa by magnitude",
    )
    drop_zero_points: bool = Field(
        True, description="drop lidar points at exactly (0, 0, 0), the no-return of many drivers"
    )
    max_cloud_mb: float = Field(
        1024.0, description="a PointCloud2 claiming more than this many MB is rejected as corrupt"
    )
    window_margin_s: float = Field(
        2.0,
        description="extra log time read around a requested stamp window (header stamps lag "
        "or lead the log time by up to this much)",
    )
    reorder_depth: int = Field(
        8,
        description="records are re-sorted by header stamp within this many messages",
    )
