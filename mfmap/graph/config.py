from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class GraphConfig(BaseModel):
    """The building's factor graph; the switches are the ablations."""

    model_config = ConfigDict(extra="forbid")

    barometer_factors: bool = Field(True, description="barometric height factors")
    elevator_continuity: bool = Field(True, description="x, y, yaw tight across a ride")
    inter_floor_registration: bool = Field(True, description="global registration between floors")
