"""The configuration: one pydantic model per stage, combined into MfmapConfig.

Every model forbids unknown keys, so a typo in a YAML file is an error that names the key and the
file instead of a setting silently ignored.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from mfmap.errors import ConfigError, MfmapError, read_text
from mfmap.eval.config import EvalConfig
from mfmap.export.config import ExportConfig
from mfmap.floors.config import FloorsConfig
from mfmap.graph.config import GraphConfig
from mfmap.ingest.camera_config import CameraConfig
from mfmap.ingest.config import IngestConfig
from mfmap.localize.config import LocalizeConfig
from mfmap.mapping.config import MappingConfig

__all__ = [
    "RENAMED_KEYS",
    "CameraConfig",
    "EvalConfig",
    "ExportConfig",
    "FloorsConfig",
    "GraphConfig",
    "IngestConfig",
    "LocalizeConfig",
    "MappingConfig",
    "MfmapConfig",
    "dump_config",
    "load_config",
]


class MfmapConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    ingest: IngestConfig = Field(default_factory=IngestConfig)
    camera: CameraConfig = Field(default_factory=CameraConfig)
    floors: FloorsConfig = Field(default_factory=FloorsConfig)
    mapping: MappingConfig = Field(default_factory=MappingConfig)
    graph: GraphConfig = Field(default_factory=GraphConfig)
    export: ExportConfig = Field(default_factory=ExportConfig)
    eval: EvalConfig = Field(default_factory=EvalConfig)
    localize: LocalizeConfig = Field(default_factory=LocalizeConfig)


# Keys of the flat per-stage sections that came before the nested ones, and where each went:
# a file that still uses one is refused with the new name in the message.
RENAMED_KEYS: dict[str, str] = {
    "mapping.map_voxel_size_m": "mapping.local_map.voxel_size_m",
    "mapping.keyframe_voxel_size_m": "mapping.keyframes.voxel_size_m",
    "mapping.odom_scale_min_m": "mapping.motion.odom_scale_min_m",
    "mapping.motion_prior": "mapping.motion.prior",
    "mapping.icp_max_iterations": "mapping.icp.max_iterations",
    "mapping.icp_tolerance": "mapping.icp.tolerance",
    "mapping.icp_initial_threshold_m": "mapping.icp.initial_threshold_m",
    "mapping.icp_min_motion_m": "mapping.icp.min_motion_m",
    "mapping.icp_min_threshold_m": "mapping.icp.min_threshold_m",
    "mapping.icp_max_gyro_disagreement_deg": "mapping.icp.max_gyro_disagreement_deg",
    "mapping.icp_gyro_low_fitness": "mapping.icp.gyro_low_fitness",
    "mapping.icp_heading_sigma_deg": "mapping.icp.heading_sigma_deg",
    "mapping.icp_fine_kernel_m": "mapping.icp.fine_kernel_m",
    "mapping.standstill_hold_s": "mapping.motion.standstill_hold_s",
    "mapping.turn_hold_m": "mapping.motion.turn_hold_m",
    "mapping.local_map_keyframes": "mapping.local_map.keyframes",
    "mapping.local_map_radius_m": "mapping.local_map.radius_m",
    "mapping.keyframe_distance_m": "mapping.keyframes.distance_m",
    "mapping.keyframe_angle_deg": "mapping.keyframes.angle_deg",
    "mapping.odom_sigma_m": "mapping.odom_edge.sigma_m",
    "mapping.odom_sigma_per_m": "mapping.odom_edge.sigma_per_m",
    "mapping.odom_sigma_deg": "mapping.odom_edge.sigma_deg",
    "mapping.stairs_sigma_z_m": "mapping.stairs.sigma_z_m",
    "mapping.stairs_sigma_yaw_deg": "mapping.stairs.sigma_yaw_deg",
    "mapping.stairs_gyro_sigma_yaw_deg": "mapping.stairs.gyro_sigma_yaw_deg",
    "mapping.loop_closure": "mapping.loops.closure",
    "mapping.loop_radius_m": "mapping.loops.radius_m",
    "mapping.loop_min_separation": "mapping.loops.min_separation",
    "mapping.loop_descriptor_threshold": "mapping.loops.descriptor_threshold",
    "mapping.loop_submap_keyframes": "mapping.loops.submap_keyframes",
    "mapping.loop_max_candidates": "mapping.loops.max_candidates",
    "mapping.loop_min_fitness": "mapping.loops.min_fitness",
    "mapping.loop_max_rmse_m": "mapping.loops.max_rmse_m",
    "mapping.loop_ambiguity_m": "mapping.loops.ambiguity_m",
    "mapping.loop_min_information_ratio": "mapping.loops.min_information_ratio",
    "mapping.loop_max_correction_m": "mapping.loops.max_correction_m",
    "mapping.loop_sigma_m": "mapping.loops.sigma_m",
    "mapping.loop_sigma_deg": "mapping.loops.sigma_deg",
    "mapping.loop_sigma_growth_per_m": "mapping.loops.sigma_growth_per_m",
    "mapping.level_window_s": "mapping.stairs.level_window_s",
    "mapping.cabin_filter": "mapping.cabin.filter",
    "mapping.cabin_size_m": "mapping.cabin.size_m",
    "mapping.cabin_window_s": "mapping.cabin.window_s",
    "graph.barometer_factors": "graph.ablation.barometer_factors",
    "graph.elevator_continuity": "graph.ablation.elevator_continuity",
    "graph.inter_floor_registration": "graph.ablation.inter_floor_registration",
    "graph.same_floor_height_tie": "graph.ablation.same_floor_height_tie",
    "graph.gravity_factors": "graph.ablation.gravity_factors",
    "graph.robust_kernel": "graph.robust.kernel",
    "graph.loop_gate_m": "graph.robust.loop_gate_m",
    "graph.loop_gate_deg": "graph.robust.loop_gate_deg",
    "graph.robust_k": "graph.robust.k",
    "graph.baro_source": "graph.barometer.source",
    "graph.baro_sigma_m": "graph.barometer.sigma_m",
    "graph.baro_window_s": "graph.barometer.window_s",
    "graph.bias_random_walk_m_sqrt_s": "graph.barometer.bias_random_walk_m_sqrt_s",
    "graph.height_tie_sigma_m": "graph.heights.tie_sigma_m",
    "graph.elevator_sigma_xy_m": "graph.elevator.sigma_xy_m",
    "graph.elevator_sigma_yaw_deg": "graph.elevator.sigma_yaw_deg",
    "graph.transition_height": "graph.ablation.transition_height",
    "graph.transition_sigma_z_m": "graph.heights.transition_sigma_z_m",
    "graph.transition_window_s": "graph.heights.transition_window_s",
    "graph.imu_ride_height": "graph.ablation.imu_ride_height",
    "graph.walk_height": "graph.ablation.walk_height",
    "graph.baro_scale_sigma": "graph.barometer.scale_sigma",
    "graph.temperature_sigma_k": "graph.barometer.temperature_sigma_k",
    "graph.baro_offset_sigma_m": "graph.barometer.offset_sigma_m",
    "graph.height_gate_sigma": "graph.heights.gate_sigma",
    "graph.gravity_sigma_deg": "graph.gravity.sigma_deg",
    "graph.gravity_minus_odometry": "graph.gravity.minus_odometry",
    "graph.interfloor_voxel_m": "graph.interfloor.voxel_m",
    "graph.interfloor_band_m": "graph.interfloor.band_m",
    "graph.interfloor_min_fitness": "graph.interfloor.min_fitness",
    "graph.interfloor_ambiguity_ratio": "graph.interfloor.ambiguity_ratio",
    "graph.interfloor_max_correction_m": "graph.interfloor.max_correction_m",
    "graph.interfloor_max_correction_deg": "graph.interfloor.max_correction_deg",
    "graph.interfloor_sigma_xy_m": "graph.interfloor.sigma_xy_m",
    "graph.interfloor_sigma_yaw_deg": "graph.interfloor.sigma_yaw_deg",
    "graph.outlier_chi2_p": "graph.robust.outlier_chi2_p",
    "floors.method": "floors.filter.method",
    "floors.sliding_window_samples": "floors.filter.sliding_window_samples",
    "floors.spike_window_s": "floors.filter.spike_window_s",
    "floors.spike_threshold_sigma": "floors.filter.spike_threshold_sigma",
    "floors.max_transient_s": "floors.filter.max_transient_s",
    "floors.noise_m": "floors.filter.noise_m",
    "floors.accel_noise_m_s2": "floors.filter.accel_noise_m_s2",
    "floors.min_vertical_speed_m_s": "floors.transitions.min_vertical_speed_m_s",
    "floors.max_vertical_speed_m_s": "floors.transitions.max_vertical_speed_m_s",
    "floors.max_vertical_accel_m_s2": "floors.transitions.max_vertical_accel_m_s2",
    "floors.stop_vertical_speed_m_s": "floors.transitions.stop_vertical_speed_m_s",
    "floors.max_pause_s": "floors.transitions.max_pause_s",
    "floors.landing_max_path_m": "floors.transitions.landing_max_path_m",
    "floors.min_visit_s": "floors.transitions.min_visit_s",
    "floors.level_window_s": "floors.transitions.level_window_s",
    "floors.transition_window_s": "floors.transitions.window_s",
    "floors.moving_speed_m_s": "floors.moving.speed_m_s",
    "floors.moving_yaw_rate_rad_s": "floors.moving.yaw_rate_rad_s",
    "floors.moving_accel_std_m_s2": "floors.moving.accel_std_m_s2",
    "export.grid_resolution_m": "export.grid.resolution_m",
    "export.grid_band_m": "export.grid.band_m",
    "export.grid_level_band": "export.grid.level_band",
    "export.grid_view_spacing_m": "export.grid.view_spacing_m",
    "export.grid_min_hits": "export.grid.min_hits",
    "export.grid_max_range_m": "export.grid.max_range_m",
    "export.cloud_voxel_m": "export.cloud.voxel_m",
    "export.cloud_min_range_m": "export.cloud.min_range_m",
    "export.cloud_source": "export.cloud.source",
    "export.max_grid_mb": "export.grid.max_mb",
    "localize.search_resolution_m": "localize.search.resolution_m",
    "localize.search_yaw_step_deg": "localize.search.yaw_step_deg",
    "localize.search_range_m": "localize.search.range_m",
    "localize.search_candidates": "localize.search.candidates",
    "localize.query_voxel_m": "localize.search.query_voxel_m",
    "localize.query_window_s": "localize.search.query_window_s",
}


def _describe(err: ValidationError) -> str:
    first = err.errors()[0]
    where = ".".join(str(p) for p in first["loc"])
    if first["type"] == "extra_forbidden":
        moved = RENAMED_KEYS.get(where)
        return f"unknown key '{where}'" + (f" (it is now '{moved}')" if moved else "")
    msg = str(first["msg"]).removeprefix("Value error, ")
    given = first.get("input")
    if first["type"] != "value_error" and isinstance(given, (int, float, str)):
        msg += f" (got {given!r:.40})"
    return f"invalid value for '{where}': {msg}"


def config_from_dict(data: dict[str, Any], source: Path | str = "<config>") -> MfmapConfig:
    try:
        return MfmapConfig.model_validate(data)
    except ValidationError as err:
        raise ConfigError(_describe(err), source) from err


def read_yaml_mapping(path: Path, error: type[MfmapError] = ConfigError) -> dict[str, Any]:
    """A config YAML file as a dict (an empty file is {}); problems raise `error` naming the file."""
    text = read_text(path, error)
    try:
        loaded = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise error(f"not valid YAML ({err.__class__.__name__})", path) from err
    if loaded is None:
        return {}
    if not isinstance(loaded, dict):
        raise error("expected a mapping of stage names at the top level", path)
    return loaded


def load_config(path: Path | None, overrides: dict[str, Any] | None = None) -> MfmapConfig:
    """Defaults, then the YAML file (if any), then overrides (nested dict)."""
    data: dict[str, Any] = {}
    if path is not None:
        if not path.is_file():
            raise ConfigError("config file not found", path)
        data = read_yaml_mapping(path)
    if overrides:
        data = merge_dicts(data, overrides)
    return config_from_dict(data, path if path is not None else "<config>")


def merge_dicts(base: dict[str, Any], extra: dict[str, Any]) -> dict[str, Any]:
    """`extra` laid over `base`, nested mappings merged key by key."""
    out = dict(base)
    for key, value in extra.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge_dicts(out[key], value)
        else:
            out[key] = value
    return out


def dump_config(config: MfmapConfig, comments: bool = False) -> str:
    """YAML text of a config; `mfmap config` prints it with each key's description as a
    comment above it, so that a copy of the defaults explains itself."""
    header = "# mfmap configuration (mfmap config prints the defaults)\n"
    if not comments:
        return header + yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False)
    return header + "".join(_commented(config, 0))


_COMMENT_WIDTH = 96


def _commented(model: BaseModel, depth: int) -> list[str]:
    """`model` as YAML lines, a nested model as a block, each field's description above it."""
    import textwrap

    indent = "  " * depth
    plain = model.model_dump(mode="json")
    lines: list[str] = []
    for name, info in type(model).model_fields.items():
        if info.description:
            width = max(_COMMENT_WIDTH - len(indent) - 2, 40)
            lines += [f"{indent}# {text}\n" for text in textwrap.wrap(info.description, width)]
        value = getattr(model, name)
        if isinstance(value, BaseModel):
            lines.append(f"{indent}{name}:\n")
            lines += _commented(value, depth + 1)
            continue
        text = yaml.safe_dump({name: plain[name]}, sort_keys=False, width=10_000)
        lines += [f"{indent}{line}\n" for line in text.splitlines()]
    return lines
