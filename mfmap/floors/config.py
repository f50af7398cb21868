"""floors stage configuration: barometer filtering, transitions and floor clustering."""

from __future__ import annotations

from enum import Enum

from pydantic import BaseModel, ConfigDict, Field, model_validator

_SECTION = ConfigDict(extra="forbid", allow_inf_nan=False)


class FilterMethod(str, Enum):
    """How the height trace is smoothed before transitions are looked for."""

    RTS = "rts"  # spike rejection + forward-backward (Rauch-Tung-Striebel) constant-velocity smoother
    SLIDING_MEAN = "sliding_mean"  # the LeGO-LOAM elevator paper's: mean of the last 30 samples


class FilterConfig(BaseModel):
    """How the barometer's height trace is cleaned and smoothed."""

    model_config = _SECTION

    method: FilterMethod = Field(
        FilterMethod.RTS, description="rts (spike rejection + RTS smoother) or sliding_mean (the LeGO-LOAM elevator paper's filter)"
    )
    sliding_window_samples: int = Field(
        30, ge=1, description="window of the sliding_mean baseline, in samples (the paper's 30)"
    )
    spike_window_s: float = Field(
        1.0, gt=0, description="half-width of the Hampel window that rejects single-sample spikes"
    )
    spike_threshold_sigma: float = Field(
        4.0, gt=0, description="a sample further than this many robust sigmas from its median is a spike"
    )
    max_transient_s: float = Field(
        8.0, ge=0, description="pressure pulses (doors, HVAC) up to this long are removed"
    )
    noise_m: float | None = Field(
        None, gt=0, description="barometer height noise (1 sigma, m); null = estimated from the trace"
    )
    accel_noise_m_s2: float = Field(
        0.3, gt=0, description="RTS process noise: vertical acceleration (1 sigma over 1 s, m/s^2)"
    )


class TransitionsConfig(BaseModel):
    """Which height changes are transitions between floors, and the height change of each."""

    model_config = _SECTION

    min_vertical_speed_m_s: float = Field(
        0.08, gt=0, description="a transition must reach this vertical speed (stairs, elevators)"
    )
    max_vertical_speed_m_s: float = Field(
        2.5, gt=0, description="faster height changes are pressure steps (doors, HVAC), not rides"
    )
    max_vertical_accel_m_s2: float = Field(
        1.5, gt=0, description="no ride or climb accelerates harder; faster steps are not floors"
    )
    stop_vertical_speed_m_s: float = Field(
        0.03, gt=0, description="a transition starts and ends where the vertical speed falls below this"
    )
    max_pause_s: float = Field(
        15.0, ge=0, description="partial height changes this close in time are joined (stair landings); "
        "further apart too when the level between is no floor visit (landing_max_path_m)"
    )
    landing_max_path_m: float = Field(
        5.0, gt=0,
        description="a level held between two height changes while the robot travels less than this "
        "(odometry) is not a floor visit: a stair landing, a floor passed through on the stairs, an "
        "elevator stop with the robot in the cabin; the changes either side are one transition",
    )
    min_visit_s: float = Field(
        10.0, ge=0,
        description="without odometry, a level held between two height changes for less than this (or "
        "while the IMU says the robot stood still) is not a floor visit",
    )
    level_window_s: float = Field(
        60.0, gt=0, description="floor level before/after a transition: robust line over this much of the visit (s)"
    )
    window_s: float = Field(
        120.0, ge=0,
        description="height change across each transition, which places the floors: one fit over up "
        "to this much of the raw trace on each side (a level either side, a shared drift slope, door "
        "steps left out; s); 0: robust lines over level_window_s",
    )

    @model_validator(mode="after")
    def _consistent(self) -> TransitionsConfig:
        if not self.stop_vertical_speed_m_s < self.min_vertical_speed_m_s < self.max_vertical_speed_m_s:
            raise ValueError(
                "vertical speeds must be stop < min < max (stop_vertical_speed_m_s "
                f"{self.stop_vertical_speed_m_s:g}, min_vertical_speed_m_s "
                f"{self.min_vertical_speed_m_s:g}, max_vertical_speed_m_s {self.max_vertical_speed_m_s:g})")
        return self


class MovingConfig(BaseModel):
    """When the robot counts as moving (an elevator ride is a height change while it stands)."""

    model_config = _SECTION

    speed_m_s: float = Field(
        0.05, gt=0, description="odometry horizontal speed above which the robot is moving"
    )
    yaw_rate_rad_s: float = Field(
        0.1, gt=0, description="odometry/IMU yaw rate above which the robot is moving"
    )
    accel_std_m_s2: float = Field(
        0.3, gt=0, description="IMU horizontal acceleration std (over 1 s) above which it is moving"
    )


class FloorsConfig(BaseModel):
    """Barometer filtering, transition detection and floor clustering."""

    model_config = _SECTION

    temperature_k: float = Field(
        295.0, ge=150.0, le=400.0,
        description="air temperature for pressure -> height (the barometer's Temperature topic "
        "sets it when this is not given)",
    )
    min_floor_height_m: float = Field(
        2.0, gt=0, description="smallest height change that is a floor change"
    )
    cluster_tolerance_m: float = Field(
        1.0, gt=0, description="visits whose elevations differ by less than this are the same floor"
    )
    filter: FilterConfig = Field(
        default_factory=FilterConfig, description="cleaning and smoothing the height trace"
    )
    transitions: TransitionsConfig = Field(
        default_factory=TransitionsConfig, description="height changes that are transitions"
    )
    moving: MovingConfig = Field(default_factory=MovingConfig, description="when the robot is moving")
