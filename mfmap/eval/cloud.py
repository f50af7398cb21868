"""Map vs reference cloud: accuracy, completeness, precision/recall/F-score, per floor."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mfmap.eval.io import PointSet
from mfmap.eval.metrics import threshold_label
from mfmap.types import F32, F64, I64


def nearest_distances_both(a: F32, b: F32) -> tuple[F64, F64]:
    """Exact nearest-neighbour distance a -> b and b -> a, in the input orders.

    scipy's cKDTree on all cores. Each cloud is queried in the leaf order of its own tree
    (`tree.indices`), so consecutive queries land in the same part of the other tree and
    reuse the cache: on this machine that makes a 5M-point query several times faster than in
    file order, at no extra cost since both trees are needed anyway. open3d's
    NearestNeighborSearch was slower here (pipelines/bench_eval.py --o3d prints both).
    """
    from scipy.spatial import cKDTree

    tree_a = cKDTree(a, leafsize=16, balanced_tree=False, compact_nodes=False)
    tree_b = cKDTree(b, leafsize=16, balanced_tree=False, compact_nodes=False)
    out: list[F64] = []
    for points, own, other in ((a, tree_a, tree_b), (b, tree_b, tree_a)):
        order = own.indices
        dist_sorted, _ = other.query(points[order], k=1, workers=-1)
        dist = np.empty(len(points), dtype=np.float64)
        dist[order] = dist_sorted
        out.append(dist)
    return out[0], out[1]


def assign_floors_by_z(z: F32 | F64, elevations_m: dict[int, float], margin_m: float) -> I64:
    """Floor of each point: the highest floor whose elevation is at most margin_m above it."""
    ids = sorted(elevations_m, key=lambda k: elevations_m[k])
    levels = np.array([elevations_m[k] for k in ids]) - margin_m
    slot = np.searchsorted(levels, z, side="right") - 1
    return np.asarray(ids, dtype=np.int64)[np.clip(slot, 0, len(ids) - 1)]


@dataclass(frozen=True)
class CloudDistances:
    map_to_ref_m: F64
    ref_to_map_m: F64
    map_floor: I64 | None
    ref_floor: I64 | None


def cloud_distances(est: PointSet, ref: PointSet, ref_floor: I64 | None) -> CloudDistances:
    """Both nearest-neighbour directions over the whole building."""
    map_to_ref, ref_to_map = nearest_distances_both(est.xyz, ref.xyz)
    return CloudDistances(map_to_ref, ref_to_map, est.floor, ref_floor)


def distance_metrics(map_to_ref: F64, ref_to_map: F64, thresholds_m: list[float]) -> dict[str, float]:
    """Flat metrics for one pair of distance sets (names without the `cloud.` prefix)."""
    m: dict[str, float] = {
        "map_points": float(len(map_to_ref)),
        "ref_points": float(len(ref_to_map)),
    }
    if len(map_to_ref):
        m["accuracy_m"] = float(map_to_ref.mean())
        m["accuracy_median_m"] = float(np.median(map_to_ref))
    if len(ref_to_map):
        m["completeness_m"] = float(ref_to_map.mean())
        m["completeness_median_m"] = float(np.median(ref_to_map))
    for t in thresholds_m:
        label = threshold_label(t)
        # A share over no points is undefined: leave the metric out rather than invent 0 or 1.
        if len(map_to_ref):
            precision = float(np.mean(map_to_ref < t))
            m[f"precision_{label}"] = precision
            m[f"precision_miss_{label}"] = 1.0 - precision
        if len(ref_to_map):
            recall = float(np.mean(ref_to_map < t))
            m[f"recall_{label}"] = recall
            m[f"recall_miss_{label}"] = 1.0 - recall
        if len(map_to_ref) and len(ref_to_map):
            total = precision + recall
            fscore = 2 * precision * recall / total if total > 0 else 0.0
            m[f"fscore_{label}"] = fscore
            m[f"fscore_miss_{label}"] = 1.0 - fscore
    return m


def cloud_metrics(d: CloudDistances, thresholds_m: list[float]) -> dict[str, float]:
    """Overall and per-floor figures. Per floor reuses the building-wide nearest distances,
    split by each point's floor (a slab separates floors, so cross-floor matches are rare)."""
    m = distance_metrics(d.map_to_ref_m, d.ref_to_map_m, thresholds_m)
    floors: set[int] = set()
    if d.map_floor is not None:
        floors |= set(np.unique(d.map_floor).tolist())
    if d.ref_floor is not None:
        floors |= set(np.unique(d.ref_floor).tolist())
    if d.map_floor is None or d.ref_floor is None:
        return m
    for fid in sorted(floors):
        sub = distance_metrics(
            d.map_to_ref_m[d.map_floor == fid], d.ref_to_map_m[d.ref_floor == fid], thresholds_m
        )
        m.update({f"floor{fid}.{k}": v for k, v in sub.items()})
    return m
