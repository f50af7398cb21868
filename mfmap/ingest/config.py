from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator


class LidarTimeConfig(BaseModel):
    """How a lidar's per-point time is read; `auto` decides each part from the data."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    field: str = Field(
        "auto",
        description="the per-point time field: auto (the first of t, time, timestamp, "
        "time_stamp, offset_time, ts, time_offset whose values make sense), a field name, or "
        "none (ignore every time field)",
    )
    unit: Literal["auto", "s", "ms", "us", "ns"] = Field(
        "auto", description="unit of the time field's values; auto: the one that makes a "
        "scan last about one scan period")
    reference: Literal["auto", "relative", "absolute"] = Field(
        "auto",
        description="relative: values count from the scan's header stamp (or its sweep start, "
        "see stamp); absolute: the same clock as the header stamp (epoch)",
    )
    stamp: Literal["auto", "start", "end"] = Field(
        "auto",
        description="for relative values that start at 0: where the header stamp sits in the "
        "sweep (end: values count from the sweep start, the stamp is its end, as some drivers "
        "stamp the last packet); auto reads it from the values and the recorder's clock",
    )
    without_time: Literal["auto", "azimuth", "none"] = Field(
        "auto",
        description="a lidar without per-point time: azimuth deskews a spinning lidar by each "
        "point's azimuth (auto: when the data show a spinning sweep), none maps it without "
        "deskew",
    )
    spin: Literal["auto", "cw", "ccw"] = Field(
        "auto", description="azimuth deskew: spin direction seen from above the sensor")

Metres = Annotated[float, Field(ge=-100.0, le=100.0)]


class ExtrinsicConfig(BaseModel):
    """A sensor frame's pose in its parent frame, for a log that lacks the transform."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    parent: str = Field("base_link", description="the parent frame (the base, or a frame the "
                        "log's transforms reach)")
    # A mount further than this from the base is a typo (millimetres for metres), and would
    # stretch every grid around it.
    xyz: tuple[Metres, Metres, Metres] = Field((0.0, 0.0, 0.0), description="translation (m)")
    rpy_deg: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0), description="roll, pitch, yaw (degrees; fixed axes x, y, z, as tf2)")


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
    lidar_time: LidarTimeConfig = Field(
        default_factory=LidarTimeConfig,
        description="how the 3D lidar's per-point time is read (auto: decided from the data)",
    )
    scan2d_beam_time: Literal["auto", "as_stated", "reversed"] = Field(
        "auto",
        description="2D LaserScan beam times: as_stated (beam i at i * time_increment), "
        "reversed (the array runs against the sweep, as rplidar_ros publishes), auto: checked "
        "against the gyro on turning scans",
    )
    extrinsics: dict[str, ExtrinsicConfig] = Field(
        default_factory=dict,
        description="sensor frame -> {parent, xyz, rpy_deg}: transforms the log lacks (these "
        "win over the log's own)",
    )
    assume_identity_extrinsics: bool = Field(
        False,
        description="a sensor frame with no transform to the base is placed at the base with "
        "no rotation (a warning) instead of stopping the build",
    )

    @field_validator("extrinsics")
    @classmethod
    def _no_self_parent(cls, value: dict[str, ExtrinsicConfig]) -> dict[str, ExtrinsicConfig]:
        for frame, spec in value.items():
            if spec.parent.lstrip("/") == frame.lstrip("/"):
                raise ValueError(f"frame '{frame}' cannot be its own parent")
        return value
