"""The logs' stage results in building floors and the building frame, for the usual exports.

Each log keeps its own keyframe ids, segmentation and scans (its maps are made from its own log,
`mfmap.export.scans.accumulate`), with its floors renamed to the building's; the floors.json the
exports write comes from all logs' segmentations at once, and the clouds and grids of a floor
several logs saw are merged.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from mfmap.export.cabin import Cabin
from mfmap.export.mapdata import MapAccumulator
from mfmap.export.write import FloorTrajectory
from mfmap.types import Floor, FloorSegmentation, MappingResult, Transition

# Two logs' measurements of one cabin lie this close; the one measured from more rides is kept.
SAME_CABIN_M = 1.0


def rename_segmentation(seg: FloorSegmentation, floors: dict[int, int],
                        levels_m: dict[int, float], dz_m: float) -> FloorSegmentation:
    """A log's segmentation in building floors (`floors`: log floor -> building floor), its
    elevations the building's and its height trace moved by `dz_m` (log frame -> building)."""
    renamed = tuple(Floor(floors[f.id], levels_m.get(floors[f.id], f.elevation_m + dz_m),
                          f.pressure_pa, f.visits) for f in seg.floors)
    transitions = tuple(dataclasses.replace(t, from_floor=floors.get(t.from_floor, -1),
                                            to_floor=floors.get(t.to_floor, -1))
                        for t in seg.transitions)
    lookup = np.array([floors.get(i, -1) for i in range(max(floors, default=0) + 1)] or [-1])
    of_sample = np.where(seg.floor_of_sample >= 0,
                         lookup[np.clip(seg.floor_of_sample, 0, len(lookup) - 1)], -1)
    return FloorSegmentation(
        floors=tuple(sorted(renamed, key=lambda f: f.id)), transitions=transitions,
        stamp_ns=seg.stamp_ns, height_raw_m=seg.height_raw_m + dz_m,
        height_filtered_m=seg.height_filtered_m + dz_m,
        floor_of_sample=of_sample.astype(np.int32), warnings=seg.warnings)


def merge_segmentations(segs: list[FloorSegmentation]) -> FloorSegmentation:
    """One segmentation of the building from the logs' renamed ones: a floor's visits from every
    log, its pressure from the first log that visited it (pressures of different days are never
    compared), the barometer traces side by side in time."""
    floors: dict[int, Floor] = {}
    for seg in segs:
        for f in seg.floors:
            if f.id in floors:
                old = floors[f.id]
                floors[f.id] = Floor(f.id, old.elevation_m, old.pressure_pa,
                                     tuple(sorted((*old.visits, *f.visits))))
            else:
                floors[f.id] = f
    transitions: list[Transition] = sorted((t for s in segs for t in s.transitions),
                                           key=lambda t: t.start_ns)
    stamps = np.concatenate([s.stamp_ns for s in segs])
    order = np.argsort(stamps, kind="stable")
    return FloorSegmentation(
        floors=tuple(floors[k] for k in sorted(floors)), transitions=tuple(transitions),
        stamp_ns=stamps[order],
        height_raw_m=np.concatenate([s.height_raw_m for s in segs])[order],
        height_filtered_m=np.concatenate([s.height_filtered_m for s in segs])[order],
        floor_of_sample=np.concatenate([s.floor_of_sample for s in segs])[order].astype(np.int32),
        warnings=tuple(w for s in segs for w in s.warnings))


def rename_mapping(mapping: MappingResult, floors: dict[int, int]) -> MappingResult:
    """A log's mapping result with its keyframes on building floors (copies; ids kept)."""
    keyframes = [dataclasses.replace(k, floor_id=floors.get(k.floor_id, -1) if k.floor_id >= 0
                                     else k.floor_id) for k in mapping.keyframes]
    return MappingResult(keyframes, list(mapping.edges), list(mapping.scan_poses),
                         list(mapping.warnings), dict(mapping.stats))


def merge_trajectories(parts: list[FloorTrajectory]) -> FloorTrajectory:
    """The logs' trajectories as one, in time order."""
    stamps = np.concatenate([p.stamps_ns for p in parts])
    order = np.argsort(stamps, kind="stable")
    poses = np.concatenate([p.poses.reshape(-1, 4, 4) for p in parts])
    return FloorTrajectory(stamps[order], poses[order],
                           np.concatenate([p.floor for p in parts])[order].astype(np.int32))


def merge_maps(into: MapAccumulator, other: MapAccumulator) -> None:
    """Another log's clouds and grids into `into`: a floor both saw gets both logs' points,
    obstacle hits and views."""
    for floor_id in other.floor_ids():
        if floor_id not in into.clouds:
            into.clouds[floor_id] = other.clouds[floor_id]
            into.grids[floor_id] = other.grids[floor_id]
            continue
        into.clouds[floor_id].add(other.cloud(floor_id))
        grid, more = into.grids[floor_id], other.grids[floor_id]
        grid._merge()
        more._merge()
        keys = np.concatenate([grid.cell_keys, more.cell_keys])
        hits = np.concatenate([grid.cell_hits, more.cell_hits])
        grid.cell_keys, inverse = np.unique(keys, return_inverse=True)
        grid.cell_hits = np.bincount(inverse, weights=hits).astype(np.int64)
        grid.polygons.extend(more.polygons)
    into.scans += other.scans
    into.images += other.images


def merge_cabins(cabins: list[Cabin]) -> list[Cabin]:
    """One cabin per elevator: measurements from several logs within SAME_CABIN_M are one, the
    one of more rides kept, with the floors all of them served."""
    kept: list[Cabin] = []
    for cabin in sorted(cabins, key=lambda c: -c.rides):
        same = next((i for i, k in enumerate(kept)
                     if math.hypot(k.x_m - cabin.x_m, k.y_m - cabin.y_m) <= SAME_CABIN_M), None)
        if same is None:
            kept.append(cabin)
            continue
        k = kept[same]
        kept[same] = dataclasses.replace(
            k, floors=tuple(sorted({*k.floors, *cabin.floors})),
            doors={**cabin.doors, **k.doors})
    return kept


__all__ = ["merge_cabins", "merge_maps", "merge_segmentations", "merge_trajectories",
           "rename_mapping", "rename_segmentation"]
