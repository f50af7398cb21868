"""The regression manifest: which logs, their ground truth, the config, and the tolerances.

A manifest is YAML. Paths in it are relative to the manifest file. Example::

    name: sim_quick
    baseline: ../baselines/sim_quick.json
    config_overrides: {mapping: {voxel_size_m: 0.2}}
    ignore: ["*.count", "cloud.*"]
    tolerances:
      default: {abs: 0.02, rel: 0.10}
      metrics:
        "floors.count_error": {abs: 0}
    logs:
      - name: tiny
        simulate: {scenario: tiny, seed: 0}
      - name: lobby
        log: /data/lobby.mcap
        ground_truth: {points: /data/lobby_points.csv, floors: /data/lobby_floors.json}
      - name: tiny-day2
        simulate: {scenario: tiny-day2, seed: 0}
        localize: {map_simulate: {scenario: tiny-day1, seed: 0}}
      - name: office3-day1+day2
        simulate: {scenario: office3-day1, seed: 0}
        build_with: [{scenario: office3-day2, seed: 0}]

Every model forbids unknown keys, so a typo is an error naming the manifest file and the key.
"""

from __future__ import annotations

import fnmatch
import os
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, ValidationError, model_validator

from mfmap.errors import ConfigError

ROOT = Path(__file__).resolve().parent.parent.parent
# Shared with the `sim_run` test fixture, so simulated logs are generated once for both.
DEFAULT_SIM_CACHE = Path(os.environ.get("MFMAP_SIM_CACHE", ROOT / ".cache" / "sim"))

# Directions of mfmap.eval's metrics (glob patterns); everything else is lower-is-better.
# eval gives each higher-is-better metric an error-style twin (`*_miss_*`, `*_wrong_*`), which
# `lower_better` claims back from the broad higher-better patterns.
DEFAULT_HIGHER_BETTER = [
    "*.hilti_points",
    "*.hilti_score",
    "*.precision_*",
    "*.recall_*",
    "*.fscore_*",
    "*.count_correct",
    "*.time_correct_share",
    "*.localised_share",
]
DEFAULT_LOWER_BETTER = ["*_miss*", "*_wrong*"]
# Sizes of the inputs rather than qualities of the map: reported, not compared.
DEFAULT_IGNORE = [
    "*.count",
    "*.count_gt",
    "*.count_est",
    "*.map_points",
    "*.ref_points",
    "*.pairs",
    "*.transitions_gt",
]


class ManifestError(ConfigError):
    """A regression manifest that is missing, malformed or refers to missing files."""


class Tolerance(BaseModel):
    """How much worse than the baseline a metric may get: abs + rel * |baseline|."""

    model_config = ConfigDict(extra="forbid")

    abs: float = Field(0.0, ge=0.0, description="allowed worsening in the metric's unit")
    rel: float = Field(0.0, ge=0.0, description="allowed worsening as a fraction of |baseline|")

    def allowed(self, baseline: float) -> float:
        """The largest worsening that still passes for this baseline value."""
        return self.abs + self.rel * abs(baseline)


class Tolerances(BaseModel):
    """A default tolerance and per-metric ones (exact names or glob patterns like `points.*`)."""

    model_config = ConfigDict(extra="forbid")

    default: Tolerance = Field(
        default_factory=lambda: Tolerance(abs=1e-6, rel=1e-3),
        description="used for every metric not matched below",
    )
    metrics: dict[str, Tolerance] = Field(
        default_factory=dict, description="metric name or glob pattern -> tolerance"
    )

    def for_metric(self, name: str) -> Tolerance:
        """Exact name first, then the longest matching pattern, then the default."""
        if name in self.metrics:
            return self.metrics[name]
        matches = [p for p in self.metrics if fnmatch.fnmatchcase(name, p)]
        if matches:
            return self.metrics[max(matches, key=len)]
        return self.default

    def merged(self, other: Tolerances | None) -> Tolerances:
        """These tolerances with a log's own on top."""
        if other is None:
            return self
        fields = other.model_fields_set
        return Tolerances(
            default=other.default if "default" in fields else self.default,
            metrics={**self.metrics, **other.metrics},
        )


class Simulate(BaseModel):
    """A log generated on demand by `mfmap simulate` and cached."""

    model_config = ConfigDict(extra="forbid")

    scenario: str = Field(description="scenario name, see `mfmap simulate --list`")
    seed: int = Field(0, description="simulator seed")
    fmt: Literal["mcap", "ros1", "ros2"] = Field("mcap", description="log format to write")
    duration_scale: float = Field(1.0, gt=0.0, description="repeat the route to lengthen the log")


class Localize(BaseModel):
    """The log is localised (`mfmap localize`) in a map instead of built: the map is a
    simulated log built first, a log built first, or a build's folder."""

    model_config = ConfigDict(extra="forbid")

    map_simulate: Simulate | None = Field(None, description="the map's log, simulated")
    map_log: Path | None = Field(None, description="the map's log (MCAP, ROS 1/2 bag)")
    map_dir: Path | None = Field(None, description="a built map (mfmap build's output folder)")
    foreign: bool = Field(
        False, description="the log is of another building: every scan it poses is wrong"
    )

    @model_validator(mode="after")
    def _one_map(self) -> Localize:
        if sum(x is not None for x in (self.map_simulate, self.map_log, self.map_dir)) != 1:
            raise ValueError("give exactly one of 'map_simulate', 'map_log' or 'map_dir'")
        return self


class GroundTruth(BaseModel):
    """Ground-truth files for `mfmap eval`; any may be absent."""

    model_config = ConfigDict(extra="forbid")

    points: Path | None = Field(None, description="checkpoints CSV")
    cloud: Path | None = Field(None, description="reference cloud PLY/PCD")
    trajectory: Path | None = Field(None, description="ground-truth TUM trajectory")
    floors: Path | None = Field(None, description="ground-truth floors JSON")


GroundTruthKind = Literal["points", "cloud", "trajectory", "floors"]


class Resources(BaseModel):
    """What one log's build needs; sizes the local pool and Ray's task requests."""

    model_config = ConfigDict(extra="forbid")

    num_cpus: float = Field(1.0, gt=0.0, description="CPUs one build uses")
    memory_gb: float = Field(2.0, gt=0.0, description="peak memory of one build")


class LogEntry(BaseModel):
    """One log of the regression set: a file on disk or a simulated scenario."""

    model_config = ConfigDict(extra="forbid")

    name: str = Field(description="unique name; the key in the baseline")
    log: Path | None = Field(None, description="MCAP file, ROS 1 bag or ROS 2 bag folder")
    simulate: Simulate | None = Field(None, description="generate the log with the simulator")
    localize: Localize | None = Field(None, description="localise the log in a map, not build it")
    build_with: list[Simulate] = Field(
        default_factory=list,
        description="other simulated logs of the building, built with this one into one map "
        "(`mfmap build A B ...`; this log first, its start the building frame) and scored "
        "against the logs' merged ground truth",
    )
    ground_truth: GroundTruth = Field(default_factory=GroundTruth)
    skip_ground_truth: list[GroundTruthKind] = Field(
        default_factory=list,
        description="ground truth not scored, e.g. [cloud] (the slowest; meaningless for 2D scans)",
    )
    config: Path | None = Field(None, description="mfmap config file for this log")
    config_overrides: dict[str, Any] = Field(
        default_factory=dict, description="nested overrides on top of the configs"
    )
    tolerances: Tolerances | None = Field(None, description="tolerances for this log only")
    resources: Resources | None = Field(None, description="overrides the manifest's resources")

    @model_validator(mode="after")
    def _one_source(self) -> LogEntry:
        if (self.log is None) == (self.simulate is None):
            raise ValueError("give exactly one of 'log' or 'simulate'")
        if self.build_with and self.localize is not None:
            raise ValueError("give at most one of 'build_with' or 'localize'")
        return self


class Manifest(BaseModel):
    """The whole regression set."""

    model_config = ConfigDict(extra="forbid")

    name: str = Field(description="name of the regression set, shown in the reports")
    baseline: Path = Field(description="baseline JSON (written by --update-baseline)")
    config: Path | None = Field(None, description="mfmap config file for every log")
    config_overrides: dict[str, Any] = Field(
        default_factory=dict, description="nested overrides for every log"
    )
    sim_cache: Path | None = Field(None, description="where simulated logs are cached")
    higher_better: list[str] = Field(
        default_factory=lambda: list(DEFAULT_HIGHER_BETTER),
        description="metric names or glob patterns where larger is better",
    )
    lower_better: list[str] = Field(
        default_factory=lambda: list(DEFAULT_LOWER_BETTER),
        description="patterns where smaller is better even if higher_better matches",
    )
    ignore: list[str] = Field(
        default_factory=lambda: list(DEFAULT_IGNORE),
        description="metric names or glob patterns not compared",
    )
    tolerances: Tolerances = Field(default_factory=Tolerances)
    resources: Resources = Field(default_factory=Resources)
    logs: list[LogEntry] = Field(min_length=1, description="the logs")

    # Set by load_manifest: the file this came from (paths above are resolved against it).
    _source: Path | None = PrivateAttr(default=None)

    @property
    def source(self) -> Path | None:
        """The manifest file, when loaded from one."""
        return self._source

    @model_validator(mode="after")
    def _unique_names(self) -> Manifest:
        seen: set[str] = set()
        for entry in self.logs:
            if entry.name in seen:
                raise ValueError(f"duplicate log name '{entry.name}'")
            seen.add(entry.name)
        return self

    def is_higher_better(self, metric: str) -> bool:
        if any(fnmatch.fnmatchcase(metric, p) for p in self.lower_better):
            return False
        return any(fnmatch.fnmatchcase(metric, p) for p in self.higher_better)

    def is_ignored(self, metric: str) -> bool:
        return any(fnmatch.fnmatchcase(metric, p) for p in self.ignore)

    def tolerances_for(self, entry: LogEntry) -> Tolerances:
        return self.tolerances.merged(entry.tolerances)

    def resources_for(self, entry: LogEntry) -> Resources:
        return entry.resources if entry.resources is not None else self.resources

    def sim_cache_dir(self) -> Path:
        return self.sim_cache if self.sim_cache is not None else DEFAULT_SIM_CACHE


def _describe(err: ValidationError, data: dict[str, Any]) -> str:
    first = err.errors()[0]
    loc = list(first["loc"])
    # Name a log by its name rather than its index, which a reader would have to count.
    if len(loc) >= 2 and loc[0] == "logs" and isinstance(loc[1], int):
        logs = data.get("logs")
        if isinstance(logs, list) and loc[1] < len(logs) and isinstance(logs[loc[1]], dict):
            name = logs[loc[1]].get("name")
            if isinstance(name, str):
                loc[1] = f"[{name}]"
    where = ".".join(str(p) for p in loc).replace(".[", "[")
    if first["type"] == "extra_forbidden":
        return f"unknown key '{where}'"
    if first["type"] == "missing":
        return f"missing key '{where}'"
    msg = first["msg"].removeprefix("Value error, ")
    return f"invalid value for '{where}': {msg}" if where else msg


def _resolve(base: Path, path: Path | None) -> Path | None:
    if path is None:
        return None
    path = path.expanduser()
    return path if path.is_absolute() else (base / path).resolve()


def manifest_from_dict(data: Any, source: Path) -> Manifest:
    """Validate a parsed manifest and resolve its paths against `source`'s folder."""
    if not isinstance(data, dict):
        raise ManifestError("expected a mapping with 'name', 'baseline' and 'logs'", source)
    try:
        manifest = Manifest.model_validate(data)
    except ValidationError as err:
        raise ManifestError(_describe(err, data), source) from err
    base = source.resolve().parent
    manifest._source = source.resolve()
    manifest.baseline = _resolve(base, manifest.baseline) or manifest.baseline
    manifest.config = _resolve(base, manifest.config)
    manifest.sim_cache = _resolve(base, manifest.sim_cache)
    for entry in manifest.logs:
        entry.log = _resolve(base, entry.log)
        entry.config = _resolve(base, entry.config)
        if entry.localize is not None:
            entry.localize.map_log = _resolve(base, entry.localize.map_log)
            entry.localize.map_dir = _resolve(base, entry.localize.map_dir)
        gt = entry.ground_truth
        gt.points = _resolve(base, gt.points)
        gt.cloud = _resolve(base, gt.cloud)
        gt.trajectory = _resolve(base, gt.trajectory)
        gt.floors = _resolve(base, gt.floors)
    return manifest


def check_files(manifest: Manifest) -> None:
    """Every file a manifest names exists (simulated logs are made later)."""
    source = manifest.source if manifest.source is not None else Path("<manifest>")
    if manifest.config is not None and not manifest.config.is_file():
        raise ManifestError(f"config file not found: {manifest.config}", source)
    for entry in manifest.logs:
        if entry.log is not None and not entry.log.exists():
            raise ManifestError(f"logs[{entry.name}].log not found: {entry.log}", source)
        if entry.config is not None and not entry.config.is_file():
            raise ManifestError(f"logs[{entry.name}].config not found: {entry.config}", source)
        loc = entry.localize
        for key, given in (("map_log", loc.map_log), ("map_dir", loc.map_dir)) if loc else ():
            if given is not None and not given.exists():
                raise ManifestError(f"logs[{entry.name}].localize.{key} not found: {given}", source)
        for key, path in entry.ground_truth.model_dump().items():
            if path is not None and not Path(path).exists():
                raise ManifestError(
                    f"logs[{entry.name}].ground_truth.{key} not found: {path}", source
                )


def load_manifest(path: Path, check: bool = True) -> Manifest:
    """Read, validate and resolve a manifest; errors name the file and the key."""
    if not path.is_file():
        raise ManifestError("manifest not found", path)
    try:
        data = yaml.safe_load(path.read_text())
    except UnicodeDecodeError as err:
        raise ManifestError("not a text file (not UTF-8)", path) from err
    except (OSError, yaml.YAMLError) as err:
        raise ManifestError(f"not valid YAML ({err.__class__.__name__})", path) from err
    manifest = manifest_from_dict(data, path)
    if check:
        check_files(manifest)
    return manifest
