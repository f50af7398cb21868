"""Benchmark `mfmap eval --cloud`: an N-point map against an N-point reference (default 5M each).

Prints wall time per step, peak memory and rates; with --o3d also the open3d KD-tree on the same
data, the peer the brief names. Run:
    .venv/bin/python pipelines/bench_eval.py [--points 5000000] [--o3d]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import tempfile
import time
from pathlib import Path

import numpy as np
import numpy.typing as npt

from mfmap.eval import evaluate
from mfmap.eval.io import write_ply

F32 = npt.NDArray[np.float32]


def building_surfaces(n: int, rng: np.random.Generator, floors: int = 2, height_m: float = 4.0) -> tuple[F32, npt.NDArray[np.int32]]:
    """Points on the slabs, outer walls and a few inner walls of a 40 x 20 m building."""
    size = np.array([40.0, 20.0, 3.0])
    floor = rng.integers(0, floors, n).astype(np.int32)
    xyz = rng.uniform(0, 1, (n, 3)) * size
    face = rng.integers(0, 5, n)  # 0 slab, 1 ceiling, 2 x-walls, 3 y-walls, 4 inner walls
    xyz[face == 0, 2] = 0.0
    xyz[face == 1, 2] = size[2]
    xyz[face == 2, 0] = rng.integers(0, 2, int((face == 2).sum())) * size[0]
    xyz[face == 3, 1] = rng.integers(0, 2, int((face == 3).sum())) * size[1]
    xyz[face == 4, 0] = rng.integers(1, 8, int((face == 4).sum())) * 5.0
    xyz[:, 2] += floor * height_m
    return xyz.astype(np.float32), floor


def _cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--points", type=int, default=5_000_000, help="points in map and reference")
    parser.add_argument("--o3d", action="store_true", help="also time open3d NearestNeighborSearch")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    n = args.points
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "build"
        out.mkdir()
        ref_xyz, _ = building_surfaces(n, rng)
        map_xyz, map_floor = building_surfaces(n, rng)
        map_xyz += rng.normal(0, 0.01, map_xyz.shape).astype(np.float32)
        write_ply(out / "map.ply", map_xyz, map_floor)
        write_ply(Path(tmp) / "ref.ply", ref_xyz)
        floors = {"floors": [{"id": 0, "elevation_m": 0.0, "visits": []},
                             {"id": 1, "elevation_m": 4.0, "visits": []}], "transitions": []}  # fmt: skip
        (out / "floors.json").write_text(json.dumps(floors))
        (out / "report.json").write_text("{}")
        load = os.getloadavg()[0]
        start, cpu_start = time.perf_counter(), _cpu_s()
        result = evaluate(out, cloud=Path(tmp) / "ref.ply")
        wall_s, cpu_s = time.perf_counter() - start, _cpu_s() - cpu_start
        m = result.metrics
        print(f"map {n:,} points vs reference {n:,} points")
        print(f"mfmap eval --cloud wall time: {wall_s:.1f} s (read both PLY, 2 KD-trees, 2 queries, per floor)")
        print(f"CPU time (user + sys, all threads): {cpu_s:.1f} s; {os.cpu_count()} cores, "
              f"load average before the run {load:.1f} (other jobs share the cores)")  # fmt: skip
        print(f"rate: {2 * n / wall_s / 1e6:.2f} M nearest-neighbour queries/s")
        print(f"peak RSS: {_peak_mb():.0f} MB")
        print(f"accuracy {m['cloud.accuracy_m']:.4f} m, completeness {m['cloud.completeness_m']:.4f} m, "
              f"F@5cm {m['cloud.fscore_5cm']:.3f}")  # fmt: skip
        if args.o3d:
            import open3d as o3d
            from scipy.spatial import cKDTree

            # One direction each, the same work: build a tree on the reference, query the map
            # in the map tree's leaf order (what mfmap does).
            order = cKDTree(map_xyz, leafsize=16, balanced_tree=False, compact_nodes=False).indices
            query = np.ascontiguousarray(map_xyz[order])
            start = time.perf_counter()
            tree = cKDTree(ref_xyz, leafsize=16, balanced_tree=False, compact_nodes=False)
            d_scipy, _ = tree.query(query, k=1, workers=-1)
            scipy_s = time.perf_counter() - start
            del tree
            start = time.perf_counter()
            nns = o3d.core.nns.NearestNeighborSearch(o3d.core.Tensor.from_numpy(ref_xyz))
            nns.knn_index()
            _, d2 = nns.knn_search(o3d.core.Tensor.from_numpy(query), 1)
            o3d_s = time.perf_counter() - start
            same = np.allclose(np.sqrt(d2.numpy()[:, 0]), d_scipy, atol=1e-5)
            print(f"one direction: scipy cKDTree {scipy_s:.1f} s, open3d NearestNeighborSearch "
                  f"{o3d_s:.1f} s (ratio open3d/scipy {o3d_s / scipy_s:.2f}; same distances: {same})")  # fmt: skip

if __name__ == "__main__":
    main()
