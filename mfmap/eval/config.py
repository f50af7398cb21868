from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class EvalConfig(BaseModel):
    """Scoring against ground truth."""

    model_config = ConfigDict(extra="forbid")

    fscore_thresholds_m: list[float] = Field(default_factory=lambda: [0.05, 0.10, 0.20])
