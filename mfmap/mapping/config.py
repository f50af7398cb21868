"""mapping stage configuration: per-floor lidar odometry, keyframes, loops and the cabin."""

from __future__ import annotations

from enum import Enum

from pydantic import BaseModel, ConfigDict, Field, model_validator

_SECTION = ConfigDict(extra="forbid", allow_inf_nan=False)


class MotionPrior(str, Enum):
    """Where the initial guess for each scan's registration comes from."""

    AUTO = "auto"  # wheel odometry (translation) + IMU gyro (rotation) when present
    ODOMETRY = "odometry"
    IMU = "imu"
    CONSTANT_VELOCITY = "constant_velocity"


class MotionConfig(BaseModel):
    """The motion prior between registrations and the stand-still shortcuts."""

    model_config = _SECTION

    prior: MotionPrior = Field(MotionPrior.AUTO, description="initial guess per scan")
    odom_scale_min_m: float = Field(
        5.0, ge=0.0,
        description="calibrate the wheel odometry's distance scale against the lidar once this "
        "much travel between keyframes has been registered since the last elevator ride (0: off); "
        "the motion prior that carries the robot out of the cabin moves with that scale",
    )
    standstill_hold_s: float = Field(
        0.0, ge=0.0,
        description="a speed knob, off by default: while the wheel odometry and the gyro say the "
        "robot has not moved since the last registered scan (under 5 mm and 0.05 degrees), scans "
        "take that pose instead of being registered again, for up to this long (0: off). Fewer "
        "scans are registered, but a stand-still then carries one registration's error instead "
        "of the median of many",
    )
    turn_hold_m: float = Field(
        0.01, ge=0.0,
        description="turning in place: while the wheel odometry has moved less than this since "
        "the robot stopped, a registration that the gyro says turned more than a degree keeps "
        "the median x, y of the stand-still's registrations and takes only its rotation and "
        "height (0: off; not on stair walks). Registered freely, the scans drift while the robot "
        "turns on the spot, as where it turns out of an elevator cabin",
    )


class IcpConfig(BaseModel):
    """Scan-to-map registration (ICP) and how it is checked against the gyro."""

    model_config = _SECTION

    max_iterations: int = Field(30, ge=1, le=1000, description="ICP iterations per scan")
    tolerance: float = Field(
        1e-4, gt=0.0, lt=1.0, description="ICP stops when fitness and RMSE change less than this (relative)"
    )
    initial_threshold_m: float = Field(
        1.0, gt=0.0, le=100.0, description="correspondence distance until the adaptive threshold has samples"
    )
    min_motion_m: float = Field(
        0.0, ge=0.0, le=10.0, description="model corrections below this do not feed the adaptive threshold"
    )
    min_threshold_m: float = Field(
        0.4, ge=0.0, le=100.0, description="the adaptive correspondence threshold never goes below this"
    )
    max_gyro_disagreement_deg: float = Field(
        0.2, ge=0.0,
        description="with an IMU, keep the gyro's rotation for a scan whose registration turns "
        "its heading more than this from the gyro's (0: off)",
    )
    gyro_low_fitness: float = Field(
        0.95, ge=0.0, le=1.0,
        description="below this registration fitness (a scan seeing much new structure) the "
        "gyro disagreement allowed is halved, and the heading is blended with the gyro's",
    )
    heading_sigma_deg: float = Field(
        0.035, ge=0.0,
        description="heading noise of a registration at full overlap, growing as 1 / fitness: "
        "below gyro_low_fitness a registered heading and the gyro's prediction are weighed "
        "by their variances (the gyro's angle random walk is measured at the log's "
        "stand-stills); 0: the registration's heading as it is",
    )
    tilt_share: float = Field(
        0.2, ge=0.0, le=1.0,
        description="off stair walks, with the gyro's prediction of a scan's rotation, the share "
        "of the registration's change of the robot's tilt that is taken (1: all of it): a "
        "16-beam scan registered against the map tilts as the robot turns (1-1.4 deg after a 90 "
        "deg turn on the spot), which the gyro does not; the registrations still take out the "
        "gyro's slow drift",
    )
    fine_kernel_m: float = Field(
        0.03, ge=0.0,
        description="Tukey kernel of the last ICP pass, at about twice the lidar's range noise: "
        "every registered scan, and every loop, is refined with it (0: off). The wide kernel "
        "that the correspondence threshold sets lets points near corners and at the edges of "
        "the map pull each registration back along the way the robot drives, and the maps come "
        "out short",
    )
    max_jump_m: float = Field(
        0.05, ge=0.0,
        description="off stair walks, a registration that puts the scan further than this "
        "from the motion prior (wheels and gyro since the last scan) is not taken, up to "
        "three in a row (0: no limit; none while the robot tips, as stepping off stairs): a "
        "scan that sees the far face of a thin wall first otherwise slips onto its near face "
        "in one step, and the map after it with it",
    )
    facing_surfaces: bool = Field(
        False,
        description="match a scan's points only to map surfaces that face the lidar (the map "
        "keeps the side each surface was seen from), so the far face of a thin wall seen for "
        "the first time is not matched to its near face; off: the stair climbs it registers, "
        "which set floors' heights, are less repeatable with it",
    )


class LocalMapConfig(BaseModel):
    """The sliding local map each scan registers against."""

    model_config = _SECTION

    voxel_size_m: float = Field(0.15, ge=0.01, le=5.0, description="voxel of the local map")
    keyframes: int = Field(30, ge=1, le=10_000, description="keyframes in the sliding local map")
    radius_m: float = Field(30.0, gt=0.0, le=10_000.0, description="local map keeps keyframes within this")


class KeyframesConfig(BaseModel):
    """When a keyframe is made, and the cloud it keeps."""

    model_config = _SECTION

    voxel_size_m: float = Field(0.1, ge=0.01, le=5.0, description="voxel of the cloud kept per keyframe")
    distance_m: float = Field(1.0, gt=0.0, le=1000.0, description="new keyframe after this much travel")
    angle_deg: float = Field(15.0, gt=0.0, le=360.0, description="new keyframe after this much rotation")


class OdomEdgeConfig(BaseModel):
    """Noise of the odometry edge between consecutive keyframes."""

    model_config = _SECTION

    sigma_m: float = Field(0.01, gt=0.0, description="odometry edge noise per keyframe (m)")
    sigma_per_m: float = Field(0.005, ge=0.0, description="odometry edge noise growing per metre "
                               "(across a stair walk, per metre walked: x, y drift with the way "
                               "along the flights, not with the line between the ends)")
    sigma_deg: float = Field(0.15, gt=0.0, description="odometry edge rotation noise (deg)")


class StairsConfig(BaseModel):
    """How a stair walk's climb and turn are weighed, and the pose levelled after it."""

    model_config = _SECTION

    sigma_z_m: float = Field(
        0.05,
        gt=0,
        description="height noise of the odometry edge across a stair walk (every scan on the "
        "stairs is registered): it and the barometer's height change across the walk set the "
        "floors' heights",
    )
    sigma_yaw_deg: float = Field(
        0.3,
        gt=0,
        description="heading noise of the registrations' turn across a stair walk (they slip "
        "as the robot tips onto the first step)",
    )
    gyro_sigma_yaw_deg: float = Field(
        0.1,
        ge=0,
        description="heading noise of the IMU gyro's turn across a stair walk (its bias "
        "wanders). With a gyro, the walk's turn is the two weighed by their variances and the "
        "scans on the way follow the gyro (0: the registrations' turn)",
    )
    max_jump_m: float = Field(
        0.1, ge=0.0,
        description="on a stair walk, a registration that puts the scan further than this "
        "from the motion prior (wheels and gyro since the last scan) is not taken, up to "
        "three in a row (0: no limit): as the robot tips onto a landing, a registration can "
        "lock onto steps lower down and drop the climb by a step or two at once",
    )
    walk_margin_s: float = Field(
        2.0, ge=0.0, le=30.0,
        description="map each stair walk this much wider on each side than the floors stage times "
        "it (s): the approach to the first step and the step off the last are mapped as stairs, "
        "every scan registered and the heading free, not as the floor's",
    )
    climb_registrations: int = Field(
        3, ge=1, le=8,
        description="registrations of each stair walk's scans whose median climb sets the floor "
        "reached: the odometry's and copies of it at other scan voxels (1: the odometry's "
        "alone; 2: their mean). Each costs the walk's registration time again",
    )
    climb_voxel_spread: float = Field(
        0.05, gt=0.0, le=0.3,
        description="how far apart the copies' scan voxels are, as a share of `voxel_size_m` "
        "(alternately above and below it)",
    )
    level_window_s: float = Field(
        10.0, le=3600.0, ge=0.0,
        description="after stairs, level the pose by the mean accelerometer over this long "
        "(0: off)",
    )
    prior_while_tipping: bool = Field(
        True,
        description="on a stair walk, a scan taken while the base tips (its tilt changes more "
        "than 0.5 degrees since the scan before by the motion prior: stepping onto or off a "
        "flight) is posed by the motion prior (gyro and wheels) and not registered: the "
        "registrations of the tip dropped or raised the climb by 3-12 cm at once, within "
        "`max_jump_m`, and a keyframe taken there kept it",
    )
    hold_tilt_level_deg: float = Field(
        4.0, ge=0.0, le=15.0,
        description="on a stair walk, a scan whose base stands within this of level for a "
        "second either side (the accelerometer) is on a landing or a floor passed through: its "
        "tilt is held to the gyro's as on a floor (`icp.tilt_share`), since a stairwell's walls "
        "and a few steps let the registration's tilt wander (0: never held on a walk)",
    )


class LoopsConfig(BaseModel):
    """Loop closure within a floor: candidate search, verification and edge noise."""

    model_config = _SECTION

    closure: bool = Field(True, description="search and verify loop closures (same floor)")
    radius_m: float = Field(4.0, ge=0.0, le=10_000.0, description="position candidates within this distance")
    min_separation: int = Field(
        15, ge=1, description="within a visit, candidates at least this many keyframes apart"
    )
    descriptor_threshold: float = Field(
        0.25, ge=0.0, le=1.0, description="Scan Context distance below which a place is a candidate"
    )
    submap_keyframes: int = Field(
        2, ge=0, le=1000, description="a loop target is its keyframe plus this many neighbours on each side"
    )
    max_candidates: int = Field(3, ge=0, le=1000, description="candidates verified per keyframe")
    min_fitness: float = Field(0.55, ge=0.0, le=1.0, description="accept a loop with this overlap or more")
    max_rmse_m: float = Field(0.06, gt=0.0, description="accept a loop with this inlier RMSE or less")
    ambiguity_m: float = Field(
        0.05, gt=0.0, description="perturbed starts must agree within this, else the match is ambiguous"
    )
    min_information_ratio: float = Field(
        0.02, ge=0.0, le=1.0, description="smallest/largest eigenvalue of the loop's translation information"
    )
    both_ways: bool = Field(
        True, description="verify a loop the other way round too (what one place saw and the other "
        "did not pulls a registration one way only)",
    )
    agreement_m: float = Field(
        0.02, gt=0.0,
        description="the loop registered the other way round must pass the same checks and "
        "agree within this",
    )
    max_correction_m: float = Field(
        1.0, gt=0.0, description="reject a loop that moves the keyframe more than this from odometry"
    )
    sigma_m: float = Field(0.01, gt=0.0, description="loop edge noise (m)")
    sigma_deg: float = Field(0.3, gt=0.0, description="loop edge noise (deg)")
    sigma_growth_per_m: float = Field(
        1.0, ge=0.0,
        description="a loop's sigmas grow by this factor per metre between its keyframes: a "
        "verified loop between distant keyframes is less accurate, and the neighbours of one "
        "such loop share its error",
    )


class CabinConfig(BaseModel):
    """Returns from inside the elevator cabin, dropped around each ride."""

    model_config = _SECTION

    filter: bool = Field(True, description="drop returns from inside the elevator cabin")
    size_m: tuple[float, float] = Field(
        (2.4, 2.4), description="cabin box (x, y in the robot's heading frame during the ride)"
    )
    window_s: float = Field(
        30.0, ge=0.0, le=3600.0, description="filter cabin returns this long before and after a ride"
    )

    @model_validator(mode="after")
    def _consistent(self) -> CabinConfig:
        if not all(0.0 < side <= 50.0 for side in self.size_m):
            raise ValueError(f"size_m {self.size_m} must be two sizes in (0, 50] m")
        return self


class MappingConfig(BaseModel):
    """Per-floor lidar odometry, keyframes and loop closure."""

    model_config = _SECTION

    voxel_size_m: float = Field(0.25, ge=0.01, le=5.0, description="downsampling voxel of each scan for registration")
    min_range_m: float = Field(0.4, ge=0.0, le=100.0, description="drop returns closer than this (robot body)")
    max_range_m: float = Field(40.0, gt=0.0, le=1000.0, description="drop returns farther than this")
    min_points_per_scan: int = Field(
        300, ge=0,
        description="a 3D lidar whose scans hold fewer points than this within min_range_m - "
        "max_range_m (the median of its first scans) is refused: scan registration needs "
        "structure, which a radar's or a very sparse sensor's few returns do not give (0: try)",
    )
    min_beams_per_scan: int = Field(
        30, ge=0, description="the same for a 2D laser scanner (LaserScan), in returns per scan",
    )
    scan_stride: int = Field(
        3, ge=1,
        description="register every n-th 3D scan; the others get a pose from the motion prior",
    )
    scan_stride_2d: int = Field(
        1, ge=1,
        description="the same for 2D scans (LaserScan), which cost little to register: every one",
    )
    deskew: bool = Field(True, description="undo motion during a sweep with per-point times")
    seed: int = Field(0, description="seed for any random choice (perturbed loop checks)")
    workers: int = Field(
        2, ge=1, le=256,
        description="processes mapping the runs of visits between elevator rides in parallel "
        "(1: one pass in the build's process; >1 gives slightly different, still reproducible "
        "results)",
    )
    split_at_stairs: bool = Field(
        False,
        description="a speed knob, off by default: with workers > 1 the runs are also split at "
        "each stair walk's end, so a log without elevator rides maps in parallel too; its "
        "results then differ from one pass's as after a ride",
    )
    motion: MotionConfig = Field(
        default_factory=MotionConfig, description="the motion prior and the stand-still shortcuts"
    )
    icp: IcpConfig = Field(default_factory=IcpConfig, description="scan-to-map registration (ICP)")
    local_map: LocalMapConfig = Field(
        default_factory=LocalMapConfig, description="the sliding local map scans register against"
    )
    keyframes: KeyframesConfig = Field(
        default_factory=KeyframesConfig, description="when a keyframe is made and what it keeps"
    )
    odom_edge: OdomEdgeConfig = Field(
        default_factory=OdomEdgeConfig, description="noise of the odometry edges between keyframes"
    )
    stairs: StairsConfig = Field(default_factory=StairsConfig, description="stair walks")
    loops: LoopsConfig = Field(default_factory=LoopsConfig, description="loop closure within a floor")
    cabin: CabinConfig = Field(default_factory=CabinConfig, description="the elevator cabin's returns")

    @model_validator(mode="after")
    def _consistent(self) -> MappingConfig:
        if self.min_range_m >= self.max_range_m:
            raise ValueError(f"min_range_m ({self.min_range_m:g}) must be below max_range_m "
                             f"({self.max_range_m:g}): no return would be kept")
        return self
