"""mfmap's lidar odometry vs KISS-ICP on the same scans of a simulated log.

Prints, side by side: scans per second, real-time factor, trajectory error against the ground
truth (RMSE and end drift, aligned at the first scan) and peak memory. "loop search" adds
mfmap's loop candidate search and verification (its cost); the trajectory is still the raw
odometry (the loops act in the pose graph). Each system runs in its
own subprocess so peak memory is its own. The scans of the first floor visit (before any
elevator, which KISS-ICP cannot handle) are decoded first; only odometry is timed.

    .venv/bin/python pipelines/bench_odometry.py --scenario two-floor
    .venv/bin/python pipelines/bench_odometry.py --folder work/sim/two-floor --stride 2
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _first_visit(folder: Path) -> tuple[int, int]:
    data = json.loads((folder / "gt_floors.json").read_text())
    visits = sorted((v[0], v[1]) for f in data["floors"] for v in f["visits"])
    return round(visits[0][0] * 1e9), round(visits[0][1] * 1e9)


def _load(folder: Path) -> tuple[list[Any], Any, Any, Any]:
    from mfmap.ingest import open_log

    start_ns, end_ns = _first_visit(folder)
    with open_log(folder / "log.mcap") as src:
        clouds = [c for c in src.clouds() if start_ns <= c.stamp_ns <= end_ns]
        return clouds, src.extrinsics(), src.odometry(), src.imu()


def _errors(folder: Path, stamps: np.ndarray, poses: np.ndarray) -> dict[str, float]:
    from scipy.spatial.transform import Rotation

    from mfmap.eval.odometry import read_tum
    from mfmap.mapping.geometry import PoseInterpolator, inverse

    gt_stamps, gt_poses = read_tum(folder / "gt_trajectory.tum")
    truth = PoseInterpolator(gt_stamps, gt_poses[:, :3, 3],
                             Rotation.from_matrix(gt_poses[:, :3, :3]).as_quat())
    gt = np.array([truth.at(int(s)) for s in stamps])
    align = gt[0] @ inverse(poses[0])
    est = poses[:, :3, 3] @ align[:3, :3].T + align[:3, 3]
    err = np.linalg.norm(est - gt[:, :3, 3], axis=1)
    dist = float(np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1).sum())
    return {"rmse_m": float(np.sqrt(np.mean(err**2))), "max_m": float(err.max()),
            "drift_pct": 100.0 * float(err[-1]) / dist, "distance_m": dist}


class _ListSource:
    """The decoded scans of one visit, served like a LogSource (decoding is not timed)."""

    def __init__(self, clouds: list[Any], odom: Any, imu: Any) -> None:
        from mfmap.types import Role

        self._clouds, self._odom, self._imu = clouds, odom, imu
        self.roles = {Role.LIDAR: "/lidar/points"}

    def clouds(self, start_ns: int | None = None, end_ns: int | None = None) -> Iterator[Any]:
        return iter(self._clouds)

    def scans2d(self, start_ns: int | None = None, end_ns: int | None = None) -> Iterator[Any]:
        return iter([])

    def odometry(self) -> Any:
        return self._odom

    def imu(self) -> Any:
        return self._imu

    def count(self, role: Any) -> int:
        return len(self._clouds)


def run_mfmap(folder: Path, stride: int, loops: bool, prior: str) -> dict[str, float]:
    from mfmap.mapping import map_floors
    from mfmap.mapping.config import LoopsConfig, MappingConfig, MotionConfig, MotionPrior
    from mfmap.mapping.posegraph import scan_trajectory
    from mfmap.types import Floor, FloorSegmentation

    clouds, extrinsics, odom, imu = _load(folder)
    start_ns, end_ns = clouds[0].stamp_ns, clouds[-1].stamp_ns
    seg = FloorSegmentation((Floor(0, 0.0, 0.0, ((start_ns, end_ns),)),), (),
                            np.array([start_ns, end_ns]), np.zeros(2), np.zeros(2),
                            np.zeros(2, dtype=np.int32))
    cfg = MappingConfig(scan_stride=stride, loops=LoopsConfig(closure=loops), motion=MotionConfig(prior=MotionPrior(prior)))
    rss_before = _peak_rss_mb()
    t0 = time.perf_counter()
    result = map_floors(_ListSource(clouds, odom, imu), seg, cfg, extrinsics)
    wall = time.perf_counter() - t0
    stamps, poses = scan_trajectory(result)
    out = _errors(folder, stamps, poses)
    out.update(scans=len(clouds), wall_s=wall, peak_rss_mb=_peak_rss_mb(),
               rss_growth_mb=_peak_rss_mb() - rss_before,
               log_s=(clouds[-1].stamp_ns - clouds[0].stamp_ns) / 1e9)
    return out


def run_kiss(folder: Path) -> dict[str, float]:
    from kiss_icp.config import load_config
    from kiss_icp.kiss_icp import KissICP

    clouds, extrinsics, _, _ = _load(folder)
    lidar_to_base = extrinsics.get(clouds[0].frame_id)
    lidar_to_base = np.eye(4) if lidar_to_base is None else lidar_to_base
    config = load_config(None)
    config.data.max_range = 40.0
    config.data.min_range = 0.4
    config.mapping.voxel_size = 0.4  # max_range / 100, KISS-ICP's own rule
    period_ns = float(np.median(np.diff([c.stamp_ns for c in clouds])))
    frames = [np.asarray(c.xyz, dtype=np.float64) for c in clouds]
    times = [np.asarray(c.t_offset_ns, dtype=np.float64) / period_ns
             if c.t_offset_ns is not None else np.zeros(len(c.xyz)) for c in clouds]
    rss_before = _peak_rss_mb()
    odometry = KissICP(config)
    poses = []
    t0 = time.perf_counter()
    for frame, stamp_frac in zip(frames, times, strict=True):
        odometry.register_frame(frame, stamp_frac)
        poses.append(odometry.last_pose.copy())
    wall = time.perf_counter() - t0
    base_to_lidar = np.linalg.inv(lidar_to_base)
    base_poses = np.array([lidar_to_base @ p @ base_to_lidar for p in poses])
    stamps = np.array([c.stamp_ns for c in clouds], dtype=np.int64)
    out = _errors(folder, stamps, base_poses)
    out.update(scans=len(clouds), wall_s=wall, peak_rss_mb=_peak_rss_mb(),
               rss_growth_mb=_peak_rss_mb() - rss_before,
               log_s=(clouds[-1].stamp_ns - clouds[0].stamp_ns) / 1e9)
    return out


def _child(args: list[str]) -> dict[str, float]:
    done = subprocess.run([sys.executable, __file__, *args], capture_output=True, text=True,
                          check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="two-floor")
    parser.add_argument("--folder", type=Path, default=None, help="an existing simulation")
    parser.add_argument("--stride", type=int, default=1, help="mfmap: register every n-th scan")
    parser.add_argument("--prior", default="auto", help="mfmap motion prior")
    parser.add_argument("--child", choices=["mfmap", "mfmap-loops", "kiss"], default=None)
    args = parser.parse_args()
    folder = args.folder
    if folder is None:
        from mfmap.sim import simulate

        folder = Path(tempfile.gettempdir()) / f"mfmap-bench-{args.scenario}"
        if not (folder / ".complete").exists():
            simulate(args.scenario, folder)
            (folder / ".complete").write_text("ok\n")
    if args.child == "kiss":
        print(json.dumps(run_kiss(folder)))
        return
    if args.child in ("mfmap", "mfmap-loops"):
        print(json.dumps(run_mfmap(folder, args.stride, args.child == "mfmap-loops", args.prior)))
        return
    common = ["--folder", str(folder), "--stride", str(args.stride), "--prior", args.prior]
    rows = {
        "kiss-icp": _child([*common, "--child", "kiss"]),
        f"mfmap (stride {args.stride})": _child([*common, "--child", "mfmap"]),
        f"mfmap + loop search (stride {args.stride})": _child([*common, "--child", "mfmap-loops"]),
    }
    first = next(iter(rows.values()))
    print(f"{folder.name}: first floor visit, {int(first['scans'])} scans, "
          f"{first['log_s']:.0f} s of log, {first['distance_m']:.1f} m travelled")
    print(f"{'system':<34}{'scans/s':>9}{'x real':>8}{'RMSE m':>9}{'max m':>8}"
          f"{'drift %':>9}{'peak MB':>9}{'+MB':>7}")
    for name, r in rows.items():
        rate = r["scans"] / r["wall_s"]
        print(f"{name:<34}{rate:>9.1f}{r['log_s'] / r['wall_s']:>8.1f}{r['rmse_m']:>9.3f}"
              f"{r['max_m']:>8.3f}{r['drift_pct']:>9.3f}{r['peak_rss_mb']:>9.0f}"
              f"{r['rss_growth_mb']:>7.0f}")
    kiss = rows["kiss-icp"]
    ours = rows[f"mfmap (stride {args.stride})"]
    print(f"speed ratio mfmap/kiss-icp: {kiss['wall_s'] / ours['wall_s']:.2f}; "
          f"RMSE ratio mfmap/kiss-icp: {ours['rmse_m'] / kiss['rmse_m']:.2f}")


if __name__ == "__main__":
    main()
