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


def _describe(err: ValidationError) -> str:
    first = err.errors()[0]
    where = ".".join(str(p) for p in first["loc"])
    if first["type"] == "extra_forbidden":
        return f"unknown key '{where}'"
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
