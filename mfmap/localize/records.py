"""What `mfmap localize` records: a scan's status, the per-scan track, a query for the global
search, the command's hint and result, and the stages' timings."""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from enum import IntEnum
from pathlib import Path
from typing import Any

import numpy as np

from mfmap.types import F64


class Status(IntEnum):
    """What a scan's pose rests on (scans.csv's `status`)."""

    TRACKED = 0  # registered against its floor
    PREDICTED = 1  # between registered scans: the motion prior, corrected by the next one
    FIXED = 2  # in the query window of a global fix: the motion prior from the fix
    RIDE = 3  # in an elevator: x, y, yaw held, z from the barometer
    STAIRS = 4  # on stairs: the motion prior, z from the barometer
    NO_FIX = 5  # no global fix yet (searching)
    LOST = 6  # the track stopped fitting: not posed
    NO_FLOOR = 7  # on a floor the map does not have
    AMBIGUOUS = 8  # the barometer's hypotheses disagree about this visit's floor

    @property
    def localised(self) -> bool:
        return self <= Status.STAIRS

    @property
    def label(self) -> str:
        return self.name.lower().replace("_", " ")


@dataclass(frozen=True)
class Hint:
    """`--initial-pose x y yaw` and/or `--floor N`: where the log starts, in the map's frame."""

    floor: int | None = None
    x_m: float | None = None
    y_m: float | None = None
    yaw_deg: float | None = None

    @property
    def has_pose(self) -> bool:
        return self.x_m is not None and self.y_m is not None and self.yaw_deg is not None


@dataclass
class LocalizeResult:
    """What `mfmap localize` did and where its outputs are."""

    log: Path
    map: Path
    out: Path
    log_duration_s: float
    elapsed_s: float
    cpu_s: float
    scans: int
    localised_share: float
    first_fix_s: float | None  # log time from the log's start to the first fix
    offset_m: float | None  # map elevation - the log's barometric level
    floors: list[dict[str, Any]]
    spans: list[dict[str, Any]]  # not localised
    searches: int
    files: list[str]
    warnings: list[str] = field(default_factory=list)
    cpu_timings_s: dict[str, float] = field(default_factory=dict)

    @classmethod
    def of(cls, log: Path, map_dir: Path, out: Path, log_duration_s: float, summary: dict[str, Any],
           files: list[str], warnings: list[str], cpu_timings_s: dict[str, float]) -> LocalizeResult:
        """The result from report.json's `summary`."""
        return cls(
            log=log, map=map_dir, out=out, log_duration_s=log_duration_s,
            elapsed_s=summary["elapsed_s"], cpu_s=summary["cpu_s"], scans=summary["scans"],
            localised_share=summary["localised_share"], first_fix_s=summary["first_fix_s"],
            offset_m=summary["offset_m"], floors=summary["floors"], spans=summary["not_localised"],
            searches=summary["searches"], files=files, warnings=warnings,
            cpu_timings_s=cpu_timings_s,
        )

    @property
    def realtime_factor(self) -> float:
        """Log duration / wall time (above 1: faster than real time)."""
        return self.log_duration_s / self.elapsed_s if self.elapsed_s > 0 else math.inf

    @property
    def cpu_realtime_factor(self) -> float:
        """Log duration / CPU time: what the run costs, whatever else the machine runs."""
        return self.log_duration_s / self.cpu_s if self.cpu_s > 0 else math.inf


@dataclass
class Track:
    """Per-scan results, filled as the scans stream by."""

    stamps_ns: list[int] = field(default_factory=list)
    poses: list[F64] = field(default_factory=list)
    floor: list[int] = field(default_factory=list)
    status: list[Status] = field(default_factory=list)
    fitness: list[float] = field(default_factory=list)

    def add(self, stamp_ns: int, status: Status, pose: F64 | None = None, floor: int = -1) -> int:
        self.stamps_ns.append(stamp_ns)
        self.poses.append(pose if pose is not None else np.full((4, 4), np.nan))
        self.floor.append(floor)
        self.status.append(status)
        self.fitness.append(math.nan)
        return len(self.stamps_ns) - 1


@dataclass
class Query:
    """Scans gathered for a global search, each with its pose in the first one's frame."""

    start_ns: int
    chains: dict[int, F64] = field(default_factory=dict)  # scan index -> pose in the query frame
    clouds: list[tuple[int, F64]] = field(default_factory=list)  # (scan index, base points)
    last_ns: int = 0


class Timings:
    """Wall and CPU seconds per stage (the CPU's do not depend on what else the machine runs)."""

    def __init__(self) -> None:
        self.wall_s: dict[str, float] = {}
        self.cpu_s: dict[str, float] = {}

    @contextlib.contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        wall, cpu = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            self.wall_s[name] = self.wall_s.get(name, 0.0) + time.perf_counter() - wall
            self.cpu_s[name] = self.cpu_s.get(name, 0.0) + time.process_time() - cpu
