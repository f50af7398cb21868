"""A built map folder as `localize` uses it: each floor's elevation, cloud and grid.

The floors' clouds (floors/<id>/cloud.ply) are in the map's frame with z up; each is thinned to
`map_voxel_m` with normals for point-to-plane ICP, and, for the global search, the walls and
furniture in a height band above the floor become a 2D likelihood field.
"""

from __future__ import annotations

import itertools
import json
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mfmap.errors import MapError, MfmapError
from mfmap.types import F64

if TYPE_CHECKING:
    from mfmap.eval.grids import LoadedGrid
    from mfmap.localize.search import SearchField
    from mfmap.mapping.registration import IcpTarget

logger = logging.getLogger(__name__)
_MAP = {"stage": "map"}  # what is wrong with the map folder, apart from the localisation's own

# A floor needs this many points to be searched or tracked against.
MIN_FLOOR_POINTS = 200


@dataclass
class FloorMap:
    """One floor of the map."""

    id: int
    elevation_m: float
    points: F64  # (N, 3) map frame, thinned to the tracking voxel
    target: IcpTarget
    grid: LoadedGrid | None
    band_m: tuple[float, float]
    _field: SearchField | None = field(default=None, repr=False)

    def search_field(self, resolution_m: float) -> SearchField:
        """The floor's walls and furniture as a 2D likelihood field (made on first use)."""
        from mfmap.localize.search import SearchField

        if self._field is None or self._field.resolution_m != resolution_m:
            z = self.points[:, 2] - self.elevation_m
            band = (z > self.band_m[0]) & (z < self.band_m[1])
            self._field = SearchField.from_points(self.points[band, :2], resolution_m)
        return self._field


@dataclass
class BuildingMap:
    """The floors of a built map, its connectors (elevators, stairs) and where it came from."""

    path: Path
    floors: dict[int, FloorMap]
    connectors: list[dict[str, Any]]

    @property
    def elevations(self) -> dict[int, float]:
        return {fid: f.elevation_m for fid, f in self.floors.items()}

    def floor_tolerance_m(self, share: float, max_m: float) -> float:
        """How far a barometric level may lie from a floor and still be on it."""
        elev = sorted(self.elevations.values())
        gaps = [b - a for a, b in itertools.pairwise(elev)]
        return min(max_m, share * min(gaps)) if gaps else max_m


def load_map(path: Path, voxel_m: float, normal_radius_m: float,
             band_m: tuple[float, float]) -> BuildingMap:
    """Read a build's output folder; MapError names the file when it is not a usable map."""
    from mfmap.eval.io import INCOMPLETE_MARKER, read_floors_json, read_ply
    from mfmap.mapping.registration import IcpTarget, downsample

    path = Path(path)
    if not path.is_dir():
        raise MapError("not a folder (expected the output folder of mfmap build)", path)
    if (path / INCOMPLETE_MARKER).exists() or not (path / "report.json").is_file():
        raise MapError("not a finished mfmap build (report.json is missing)", path)
    floors_file = read_floors_json(path / "floors.json", MapError)
    connectors = _connectors(path / "floors.json")
    floors: dict[int, FloorMap] = {}
    for info in floors_file.floors:
        if not math.isfinite(info.elevation_m):
            raise MapError(f"floor {info.id} has no finite elevation", path / "floors.json")
        cloud_path = path / "floors" / str(info.id) / "cloud.ply"
        if not cloud_path.is_file():
            raise MapError(f"floor {info.id}'s cloud is missing", cloud_path)
        ply = read_ply(cloud_path, MapError)
        if not {"x", "y", "z"} <= set(ply):
            raise MapError("the cloud has no x, y, z", cloud_path)
        xyz = np.column_stack([ply["x"], ply["y"], ply["z"]]).astype(np.float64)
        xyz = xyz[np.isfinite(xyz).all(axis=1)]
        thin = downsample(xyz, voxel_m)
        if len(thin) < MIN_FLOOR_POINTS:
            logger.warning("floor %d: %d points in its cloud, too few to localise on; left out",
                           info.id, len(thin), extra=_MAP)
            continue
        floors[info.id] = FloorMap(info.id, info.elevation_m, thin,
                                   IcpTarget.estimate(thin, normal_radius_m),
                                   _grid(path / "floors" / str(info.id)), band_m)
    if not floors:
        raise MapError("no floor of the map has a usable cloud", path / "floors")
    return BuildingMap(path, floors, connectors)


def _connectors(path: Path) -> list[dict[str, Any]]:
    doc = json.loads(path.read_text())  # read_floors_json has parsed it already
    items = doc.get("connectors", []) if isinstance(doc, dict) else []
    return [c for c in items if isinstance(c, dict)]


def _grid(folder: Path) -> LoadedGrid | None:
    """The floor's occupancy grid, to draw the path on (optional: a map without grids works)."""
    from mfmap.eval.grids import load_grid

    if not (folder / "grid.yaml").is_file():
        return None
    try:
        return load_grid(folder)
    except (MfmapError, OSError, ValueError, TypeError, KeyError) as err:
        logger.warning("%s: not drawn (%s)", folder / "grid.yaml", err, extra=_MAP)
        return None
