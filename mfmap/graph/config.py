"""graph stage configuration: the building's factor graph."""
from __future__ import annotations

from enum import Enum

from pydantic import BaseModel, ConfigDict, Field, model_validator

_SECTION = ConfigDict(extra="forbid", allow_inf_nan=False)


class RobustKernel(str, Enum):
    HUBER = "huber"
    CAUCHY = "cauchy"


class BaroSource(str, Enum):
    FILTERED = "filtered"  # the floors stage's filtered height trace
    RAW = "raw"  # the pressure samples


class AblationConfig(BaseModel):
    """Switches that leave one kind of factor out of the graph, for ablation studies."""

    model_config = _SECTION

    barometer_factors: bool = Field(True, description="barometric height factors")
    elevator_continuity: bool = Field(True, description="x, y, yaw tight across a ride")
    inter_floor_registration: bool = Field(True, description="global registration between floors")
    same_floor_height_tie: bool = Field(
        True, description="soft tie: consecutive keyframes of one floor share z (ground robots)"
    )
    gravity_factors: bool = Field(True, description="roll/pitch near gravity (IMU, or level)")
    transition_height: bool = Field(
        True, description="the barometer's height change across each transition (scaled, with the "
        "floors' pressure offsets) as a z factor"
    )
    imu_ride_height: bool = Field(
        True,
        description="each elevator ride's height change from the IMU (vertical specific force "
        "integrated twice, zero velocity at both ends) as its own z factor",
    )
    walk_height: bool = Field(
        True, description="each stair walk's height change from the lidar odometry as its own z factor"
    )


class RobustConfig(BaseModel):
    """Robust kernels, the loop gate and the outlier report."""

    model_config = _SECTION

    kernel: RobustKernel = Field(
        RobustKernel.HUBER, description="robust kernel for odometry edges (loops use Cauchy)"
    )
    k: float = Field(1.345, gt=0.0, description="robust kernel width (whitened units)")
    loop_gate_m: float = Field(
        1.5, gt=0.0, description="drop a loop edge that disagrees with the mapping's map by more (m)"
    )
    loop_gate_deg: float = Field(15.0, gt=0.0, description="... or by more than this rotation (deg)")
    outlier_chi2_p: float = Field(
        0.999, gt=0.0, lt=1.0, description="a factor whose Mahalanobis residual exceeds this chi2 quantile is an outlier"
    )


class BarometerConfig(BaseModel):
    """Barometric height factors, the barometer's bias, scale and per-floor offsets."""

    model_config = _SECTION

    source: BaroSource = Field(
        BaroSource.FILTERED,
        description="'filtered': the floors stage's filtered height trace (spikes and door/HVAC "
        "transients removed); 'raw': the pressure samples",
    )
    sigma_m: float = Field(
        0.5, gt=0.0,
        description="barometric height noise per keyframe (m). More than one reading's noise "
        "(about 5 cm over the averaging window): door and HVAC steps and weather last many "
        "keyframes, so the keyframes' errors are not independent",
    )
    window_s: float = Field(0.5, gt=0.0, le=3600.0, description="pressure averaged +- this around a keyframe")
    bias_random_walk_m_sqrt_s: float = Field(
        0.01, gt=0.0, description="barometer bias drift: sigma of the random walk per sqrt(second)"
    )
    scale_sigma: float = Field(
        0.04,
        gt=0,
        description="uncertainty of the barometer's height scale at floors.temperature_k when the log "
        "has no Temperature topic (0.34 % per kelvin: 0.04 spans 0-40 deg C around 22 deg C); the "
        "scale-true heights (IMU rides, lidar walks) calibrate it",
    )
    temperature_sigma_k: float = Field(
        2.0,
        gt=0,
        description="uncertainty of a Temperature topic's mean as the temperature of the air between "
        "the floors (K); sets the scale's prior with it",
    )
    offset_sigma_m: float = Field(
        0.2,
        ge=0,
        description="spread of the floors' pressure offsets (ventilation, stack effect), as a height "
        "(m), before the data; refined from the transitions measured both ways",
    )


class HeightsConfig(BaseModel):
    """Height changes across transitions and the same-floor height tie."""

    model_config = _SECTION

    transition_sigma_z_m: float = Field(
        0.03, gt=0.0, description="noise of the floors stage's height change, used where the fit below cannot run (m)"
    )
    transition_window_s: float = Field(
        120.0,
        ge=0,
        description="height change across a transition from a fit over up to this much of the raw "
        "barometer trace on each side (s), with its own sigma; 0: the floors stage's change at "
        "transition_sigma_z_m",
    )
    gate_sigma: float = Field(
        4.0,
        gt=0,
        description="a height measurement further than this many sigmas from what the others say is "
        "left out (mfmap.graph.heights)",
    )
    tie_sigma_m: float = Field(0.02, gt=0.0, description="same-floor z tie between keyframes")


class ElevatorConfig(BaseModel):
    """What an elevator ride holds."""

    model_config = _SECTION

    sigma_xy_m: float = Field(0.3, gt=0.0, description="x, y held through an elevator ride")
    sigma_yaw_deg: float = Field(3.0, gt=0.0, description="yaw held through an elevator ride")


class GravityConfig(BaseModel):
    """Roll and pitch of each keyframe from the IMU's gravity."""

    model_config = _SECTION

    sigma_deg: float = Field(
        0.5, gt=0.0, description="roll/pitch from gravity (robust, Huber); each keyframe's up is "
        "measured over +- 1 s with the gyro's rotation taken out"
    )
    minus_odometry: bool = Field(
        True,
        description="take the robot's own acceleration (from the wheel odometry's twist) out of "
        "the IMU's mean specific force before it is read as gravity",
    )


class InterfloorConfig(BaseModel):
    """Registration between adjacent floors on their shared structure."""

    model_config = _SECTION

    voxel_m: float = Field(0.1, ge=0.01, le=5.0, description="voxel for inter-floor registration")
    band_m: tuple[float, float] = Field(
        (0.5, 1.5), description="height band above each floor used to register floors"
    )
    min_fitness: float = Field(
        0.2, ge=0.0, le=1.0, description="reject an inter-floor match with fewer overlapping points"
    )
    ambiguity_ratio: float = Field(
        0.9, ge=0.0, le=1.0, description="reject when a distinct solution scores this close to the best"
    )
    max_correction_m: float = Field(
        1.0, gt=0.0, description="reject a correction larger than this (m) as implausible"
    )
    max_correction_deg: float = Field(
        20.0, gt=0.0, description="reject a yaw correction larger than this (deg) as implausible"
    )
    robust_m: float = Field(
        0.015, ge=0.0, description="the fine ICP weighs a point-to-plane residual of this size (m) "
        "half (Cauchy), so structure only one floor has pulls little; 0: least squares",
    )
    sigma_xy_m: float = Field(0.01, gt=0.0, description="inter-floor factor noise in x, y")
    sigma_yaw_deg: float = Field(0.05, gt=0.0, description="inter-floor factor noise in yaw")
    anchors: int = Field(
        8, ge=1, le=1000, description="keyframe pairs that share a registration's factor (its "
        "sigmas grow by the root of their number): the registration places the floors' whole "
        "clouds, not one keyframe's local pose",
    )

    @model_validator(mode="after")
    def _consistent(self) -> InterfloorConfig:
        lo, hi = self.band_m
        if not lo < hi:
            raise ValueError(f"band_m {self.band_m} must be (min, max) with min < max")
        return self


class GraphConfig(BaseModel):
    """The building's factor graph; `ablation` holds the switches."""

    model_config = _SECTION

    prior_sigma: float = Field(1e-4, gt=0.0, description="prior on the first keyframe (m, rad)")
    max_iterations: int = Field(100, ge=1, le=100_000, description="Levenberg-Marquardt iterations")
    seed: int = Field(0, description="seed for RANSAC in inter-floor registration")
    ablation: AblationConfig = Field(
        default_factory=AblationConfig, description="factor kinds on or off (all on: the full graph)"
    )
    robust: RobustConfig = Field(
        default_factory=RobustConfig, description="robust kernels, loop gate, outlier report"
    )
    barometer: BarometerConfig = Field(
        default_factory=BarometerConfig, description="barometric height factors, bias, scale and offsets"
    )
    heights: HeightsConfig = Field(
        default_factory=HeightsConfig, description="height changes across transitions, same-floor tie"
    )
    elevator: ElevatorConfig = Field(default_factory=ElevatorConfig, description="elevator rides")
    gravity: GravityConfig = Field(default_factory=GravityConfig, description="gravity factors")
    interfloor: InterfloorConfig = Field(
        default_factory=InterfloorConfig, description="registration between adjacent floors"
    )
