from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class FloorsConfig(BaseModel):
    """Barometer filtering, transition detection and floor clustering."""

    model_config = ConfigDict(extra="forbid")

    temperature_k: float = Field(295.0, description="air temperature for pressure -> height (seed 000)")
    min_floor_height_m: float = Field(2.0, description="smallest height change that is a floor change")
