"""Depth and colour cameras: which topics, and how their pixels become points."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, model_validator


class CameraTopics(BaseModel):
    """One camera's topics, for a log whose names the discovery cannot pair."""

    model_config = ConfigDict(extra="forbid")

    depth: str = Field(description="sensor_msgs/Image (16UC1, 32FC1) or CompressedImage (compressedDepth)")
    info: str = Field("", description="the depth image's sensor_msgs/CameraInfo ('' = <depth ns>/camera_info)")
    colour: str = Field("", description="Image (rgb8, bgr8) or CompressedImage (jpeg, png); '' = none")
    colour_info: str = Field("", description="the colour image's CameraInfo ('' = <colour ns>/camera_info)")


class CameraConfig(BaseModel):
    """Depth cameras as a range sensor for the clouds and grids, colour for the clouds."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    enabled: bool = Field(True, description="use the log's depth cameras (found by message type)")
    cameras: list[CameraTopics] = Field(
        default_factory=list,
        description="explicit cameras; a problem with one of these is an error, while a camera "
        "found by discovery is skipped with a warning (the lidar carries the build)",
    )
    decimation: int = Field(4, ge=1, le=64, description="back-project every n-th pixel of every n-th row")
    min_range_m: float = Field(0.3, ge=0.0, le=100.0, description="depth closer than this is dropped")
    max_range_m: float = Field(
        4.0, gt=0.0, le=100.0,
        description="depth farther than this is dropped (structured-light and stereo noise grows "
        "with the square of the range)",
    )
    colour_max_offset_s: float = Field(
        0.05, ge=0.0, le=10.0, description="a colour image pairs with the depth image this close in time"
    )
    max_pose_gap_s: float = Field(
        0.5, gt=0.0, le=60.0,
        description="an image is posed between the two trajectory poses around its stamp when "
        "they are at most this far apart (else left out)",
    )
    image_min_motion_m: float = Field(
        0.1, ge=0.0, description="an image is used after the robot moved this far (or turned "
        "image_min_turn_deg) since the camera's last used image",
    )
    image_min_turn_deg: float = Field(5.0, ge=0.0, description="see image_min_motion_m")

    @model_validator(mode="after")
    def _consistent(self) -> CameraConfig:
        if not self.min_range_m < self.max_range_m:
            raise ValueError(
                f"min_range_m {self.min_range_m:g} must be less than max_range_m {self.max_range_m:g}")
        return self
