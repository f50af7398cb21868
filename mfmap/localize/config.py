"""localize stage configuration."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class SearchConfig(BaseModel):
    """The global search for the robot's place in the map (coarse grid, then ICP)."""

    model_config = ConfigDict(extra="forbid")

    resolution_m: float = Field(0.25, gt=0, description="coarse cell")
    yaw_step_deg: float = Field(3.0, gt=0, description="coarse yaw step")
    range_m: float = Field(25.0, gt=0, description="query points within this range of the robot")
    candidates: int = Field(8, ge=1, description="places refined by ICP")
    query_voxel_m: float = Field(0.15, gt=0, description="voxel of the query")
    query_window_s: float = Field(1.0, gt=0, description="scans over this long make one query")


class LocalizeConfig(BaseModel):
    """Placing a new log in a built map: floor hypotheses, global search, tracking."""

    model_config = ConfigDict(extra="forbid")

    map_voxel_m: float = Field(0.1, gt=0, description="voxel of each floor's cloud for tracking")
    scan_voxel_m: float = Field(0.3, gt=0, description="voxel of a scan for tracking")
    scan_points: int = Field(
        500, ge=50,
        description="a tracked scan registers at most this many of its thinned points (evenly "
        "spread over the scan): the map is already dense, and the cost is per point",
    )
    min_range_m: float = Field(0.4, ge=0, description="drop returns closer than this (robot body)")
    max_range_m: float = Field(40.0, gt=0, description="drop returns farther than this")
    register_distance_m: float = Field(
        0.25, gt=0,
        description="a scan is registered once the robot moved this far since the last "
        "registered one (or turned register_angle_deg, or register_interval_s passed); the "
        "scans between take the motion prior, corrected by the registrations either side",
    )
    icp_tolerance: float = Field(
        1e-3, gt=0,
        description="a tracked scan's ICP pass stops when its fitness and inlier RMSE (m) change "
        "less than this",
    )
    register_angle_deg: float = Field(3.0, gt=0, description="see register_distance_m")
    register_interval_s: float = Field(1.0, gt=0, description="see register_distance_m")
    fit_distance_m: float = Field(
        0.1, gt=0,
        description="a scan point fits the map when the map has a point this close: fitness is "
        "the share of a scan's points that fit",
    )
    track_fitness: float = Field(
        0.6, ge=0, le=1,
        description="a registration below this fitness does not count as tracked",
    )
    lost_after_s: float = Field(
        1.5, gt=0,
        description="the track is lost after this long without a registration at track_fitness",
    )
    floor_tolerance_share: float = Field(
        0.3, gt=0, lt=0.5,
        description="a floor level of the log lies on a map floor when within this share of the "
        "smallest storey of the map (and within floor_tolerance_max_m)",
    )
    floor_tolerance_max_m: float = Field(1.0, gt=0, description="see floor_tolerance_share")
    band_m: tuple[float, float] = Field(
        (0.25, 2.2),
        description="the global search matches the walls and furniture this high above the "
        "floor (floor and ceiling say nothing about x, y and yaw)",
    )
    fix_fitness: float = Field(
        0.75, ge=0, le=1,
        description="a global search result is a fix only at this fitness or more",
    )
    fix_misfit_ratio: float = Field(
        1.5, ge=1,
        description="... and only when every distinct place (another floor, or farther than "
        "distinct_m or distinct_deg on the same one) leaves this many times as many of the "
        "query's points unfit (1 - fitness): on floors that share their corridors the right "
        "floor fits most of a query, and the next one nearly as much",
    )
    distinct_m: float = Field(1.0, gt=0, description="see fix_misfit_ratio")
    distinct_deg: float = Field(10.0, gt=0, description="see fix_misfit_ratio")
    retry_s: float = Field(
        2.0, gt=0, description="without a fix, search again this much later"
    )
    max_searches: int = Field(
        200, ge=1,
        description="global searches per log at most (each costs a fraction of a second per "
        "floor); a log that never fits stops searching and is reported not localised",
    )
    html_report: bool = Field(True, description="write report.html")
    search: SearchConfig = Field(
        default_factory=SearchConfig, description="global search: coarse grid of places, then ICP"
    )
