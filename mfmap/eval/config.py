from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, field_validator


class EvalConfig(BaseModel):
    """Scoring against ground truth."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    fscore_thresholds_m: list[float] = Field(
        default_factory=lambda: [0.05, 0.10, 0.20],
        description="Distances (m) at which cloud precision, recall and F-score are reported.",
    )
    max_time_diff_s: float = Field(
        0.01,
        gt=0,
        description="Largest time difference (s) for pairing estimated and ground-truth poses "
        "(nearest stamp, as evo does).",
    )
    floor_z_margin_m: float = Field(
        0.15,
        ge=0,
        description="A reference point without a floor field belongs to the highest floor whose "
        "elevation is at most this far above the point.",
    )
    transition_match_s: float = Field(
        30.0,
        ge=0,
        description="An estimated transition matches a ground-truth one when their time windows "
        "overlap or their midpoints are at most this far apart (s).",
    )

    @field_validator("fscore_thresholds_m")
    @classmethod
    def _positive(cls, value: list[float]) -> list[float]:
        if not value or not all(0.0 < v <= 100.0 for v in value):
            raise ValueError(f"must be one or more distances in (0, 100] m, got {value}")
        return value
