"""What the mapping stage reads: a log's scans, and a way to open the log again in a worker."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np

from mfmap.types import F32, I64, Cloud, ImuSeries, OdomSeries, Role, Scan2D

if TYPE_CHECKING:
    from mfmap.ingest.config import IngestConfig
    from mfmap.ingest.source import LogSource


class LogSourceLike(Protocol):
    """What the mapping stage needs from `mfmap.ingest.LogSource`."""

    @property
    def roles(self) -> dict[Role, str]: ...

    def clouds(self, start_ns: int | None = None, end_ns: int | None = None) -> Iterator[Cloud]: ...

    def scans2d(
        self, start_ns: int | None = None, end_ns: int | None = None
    ) -> Iterator[Scan2D]: ...

    def odometry(self) -> OdomSeries | None: ...

    def imu(self) -> ImuSeries | None: ...

    def count(self, role: Role) -> int: ...


def read_scans(source: LogSourceLike, planar: bool, start_ns: int | None = None,
               end_ns: int | None = None) -> Iterator[tuple[int, str, F32, I64 | None]]:
    """The lidar scans (3D clouds, or LaserScans as points at z = 0) in the stamps' window."""
    if planar:
        for scan in source.scans2d(start_ns, end_ns):
            xyz = np.zeros((len(scan.xy), 3), dtype=np.float32)
            xyz[:, :2] = scan.xy
            yield scan.stamp_ns, scan.frame_id, xyz, scan.t_offset_ns
    else:
        for cloud in source.clouds(start_ns, end_ns):
            yield cloud.stamp_ns, cloud.frame_id, cloud.xyz, cloud.t_offset_ns


@dataclass(frozen=True)
class LogOpener:
    """Opens a log file again, as it was opened (a worker process cannot be handed the open
    source): its path and its resolved ingest configuration, both picklable."""

    path: Path
    ingest: IngestConfig

    def __call__(self) -> LogSource:
        from mfmap.ingest import open_log

        return open_log(self.path, self.ingest)


def reopener(source: LogSourceLike) -> LogOpener | None:
    """How to open `source` again, when it is a log opened by `mfmap.ingest` (None otherwise:
    a source held in memory is mapped in one pass)."""
    from mfmap.ingest.source import LogSource

    if isinstance(source, LogSource):
        return LogOpener(source.path, source.config)
    return None
