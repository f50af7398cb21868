from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


class IngestConfig(BaseModel):
    """Which topics play which role; by default chosen by message type."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

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
        1024.0, gt=0, le=1e6,
        description="a PointCloud2 claiming more than this many MB is rejected as corrupt",
    )
    window_margin_s: float = Field(
        2.0, ge=0, le=3600,
        description="extra log time read around a requested stamp window (header stamps lag "
        "or lead the log time by up to this much)",
    )
    reorder_depth: int = Field(
        8, ge=1, le=100_000,
        description="records are re-sorted by header stamp within this many messages",
    )
    max_gap_s: float = Field(
        600.0, gt=0, le=86_400,
        description="a sensor stream whose stamps jump ahead by more than this, or step back, "
        "has a clock that was reset: it is cut to its longest consistent part (the rest dropped, "
        "with a warning), so a stamp a year ahead cannot make the log a year long",
    )
