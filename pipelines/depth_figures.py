"""Figures of the depth camera on the corridor-rgbd scenario (docs/depth.md).

    nice .venv/bin/python -m pipelines.depth_figures [--work DIR] [--seed N]

Simulates the scenario, builds it with the camera and without (camera.enabled false), and
prints: floors found, checkpoint RMSE per floor, the cloud's mean distance to the true
surfaces, the colours' agreement with the surfaces' paint, and the grids' recall of the
occupied cells of the corridor (and of its tables and shelves alone) against the truth.
Then the 3D lidar painted by a colour camera: tiny-rgbd without its depth topics, built, its
points' colours against their surfaces' paint.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

BAND_M = (0.1, 1.8)  # the build's default grid band (export.grid.band_m)
CORRIDOR = (0.0, 13.0, -1.0, 1.0)  # the stretch the robot walks (x0, x1, y0, y1)


def _build(log: Path, out: Path, camera: bool) -> float:
    import time

    cfg = out.parent / f"{out.name}.yaml"
    cfg.write_text(f"camera:\n  enabled: {'true' if camera else 'false'}\n")
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "mfmap.cli", "build", str(log), "-o", str(out),
                          "--config", str(cfg), "--force"], capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"build failed: {res.stderr.strip()[-2000:]}")
    return time.perf_counter() - t0


def _truth(seed: int, scenario: str = "corridor-rgbd") -> tuple[Any, list[Any], Any]:
    from mfmap.sim.scenarios import SCENARIOS, building_for

    building = building_for(SCENARIOS[scenario], seed)
    boxes = building.static_boxes() + [building.landing_door(k) for k in range(building.n_floors)]
    from mfmap.sim.boxes import make_scene

    return building, boxes, make_scene(boxes)


def cloud_figures(build: Path, boxes: list[Any], scene: Any) -> dict[str, float]:
    """Mean distance of map.ply's points to the true surfaces; colour agreement."""
    import open3d as o3d

    from mfmap.export.files import read_ply
    from mfmap.sim.camera import box_colours

    ply = read_ply(build / "map.ply")
    xyz = np.column_stack([ply["x"], ply["y"], ply["z"]]).astype(np.float32)
    tensor: Any = o3d.core.Tensor  # (as mfmap.sim.boxes does: open3d's stubs want a dtype)
    ans = scene.compute_closest_points(tensor(xyz))
    closest = ans["points"].numpy()
    dist = np.linalg.norm(closest - xyz, axis=1)
    out = {"points": float(len(xyz)), "mean_dist_m": float(dist.mean()),
           "median_dist_m": float(np.median(dist)), "within_5cm": float(np.mean(dist <= 0.05))}
    if "red" in ply:
        rgb = np.column_stack([ply["red"], ply["green"], ply["blue"]]).astype(int)
        paint = box_colours(boxes)[ans["primitive_ids"].numpy() // 12].astype(int)
        err = np.abs(rgb - paint).max(axis=1)
        # Mid grey: a point no camera saw nor any coloured point near it (a far lidar return).
        grey = np.all(rgb == 128, axis=1)
        out["uncoloured_share"] = float(np.mean(grey))
        out["colour_within_40"] = float(np.mean(err[~grey] <= 40))
        out["colour_median_err"] = float(np.median(err[~grey]))
        out["mean_dist_coloured_m"] = float(dist[~grey].mean())
    return out


def truth_cells(building: Any, floor_id: int, resolution_m: float, fixtures_only: bool) -> set[tuple[int, int]]:
    """Grid cells of the corridor that a surface occupies in the height band of a floor."""
    from mfmap.sim.boxes import Kind

    e = building.floors[floor_id].elevation_m
    cells: set[tuple[int, int]] = set()
    x0c, x1c, y0c, y1c = CORRIDOR
    for box in building.floors[floor_id].boxes:
        if fixtures_only and box.kind != Kind.FURNITURE:
            continue
        lo, hi = np.array(box.lo), np.array(box.hi)
        if hi[2] - e < BAND_M[0] or lo[2] - e > BAND_M[1] or box.kind == Kind.SLAB:
            continue
        # The box's footprint clipped to the corridor widened by a wall's thickness.
        bx0, bx1 = max(lo[0], x0c - 0.1), min(hi[0], x1c + 0.1)
        by0, by1 = max(lo[1], y0c - 0.1), min(hi[1], y1c + 0.1)
        if bx0 >= bx1 or by0 >= by1:
            continue
        # Only the faces the corridor sees: a box inside the corridor whole, a wall its face.
        for ix in range(int(np.floor(bx0 / resolution_m)), int(np.floor(bx1 / resolution_m)) + 1):
            for iy in range(int(np.floor(by0 / resolution_m)), int(np.floor(by1 / resolution_m)) + 1):
                cx, cy = (ix + 0.5) * resolution_m, (iy + 0.5) * resolution_m
                if y0c - 0.06 <= cy <= y1c + 0.06 and x0c <= cx <= x1c:
                    cells.add((ix, iy))
    return cells


def grid_cells(build: Path, floor_id: int) -> tuple[set[tuple[int, int]], float]:
    import yaml

    meta = yaml.safe_load((build / "floors" / str(floor_id) / "grid.yaml").read_text())
    raw = (build / "floors" / str(floor_id) / "grid.pgm").read_bytes()
    parts = raw.split(maxsplit=4)
    w, h = int(parts[1]), int(parts[2])
    img = np.frombuffer(parts[4], dtype=np.uint8, count=w * h).reshape(h, w)
    res = float(meta["resolution"])
    ox, oy = float(meta["origin"][0]), float(meta["origin"][1])
    rows, cols = np.nonzero(img == 0)
    ix = np.floor((ox + (cols + 0.5) * res) / res).astype(int)
    iy = np.floor((oy + (h - 1 - rows + 0.5) * res) / res).astype(int)
    return set(zip(ix.tolist(), iy.tolist(), strict=True)), res


def recall(truth: set[tuple[int, int]], est: set[tuple[int, int]], tol: int = 1) -> float:
    if not truth:
        return float("nan")
    hit = sum(1 for (x, y) in truth
              if any((x + dx, y + dy) in est for dx in range(-tol, tol + 1) for dy in range(-tol, tol + 1)))
    return hit / len(truth)


def _without_depth(src: Path, dst: Path) -> None:
    """The log without its depth camera's topics (a 3D lidar and a colour camera remain),
    rewritten by mcap's Writer."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with src.open("rb") as fin, dst.open("wb") as fout:
        reader = make_reader(fin)
        writer = Writer(fout)
        writer.start(profile="ros2", library="depth_figures")
        schemas: dict[int, int] = {}
        channels: dict[str, int] = {}
        for schema, channel, message in reader.iter_messages():
            if channel.topic.startswith("/camera/depth/"):
                continue
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.topic not in channels:
                channels[channel.topic] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas.get(channel.schema_id, 0), channel.metadata)
            writer.add_message(channels[channel.topic], message.log_time, message.data, message.publish_time)
        writer.finish()


def _corridor_row(sim_dir: Path, out: Path, camera: bool, truth: tuple[Any, list[Any], Any]) -> dict[str, Any]:
    from mfmap.eval.api import evaluate

    building, boxes, scene = truth
    build_s = _build(sim_dir / "log.mcap", out, camera)
    ev = evaluate(out, points=sim_dir / "gt_points.csv", floors=sim_dir / "gt_floors.json")
    report = json.loads((out / "report.json").read_text())
    row: dict[str, Any] = {"build_s": build_s, "floors": len(json.loads((out / "floors.json").read_text())["floors"]),
                           "depth_images": report["counts"].get("depth_images", 0)}
    row["rmse"] = {k: v for k, v in ev.metrics.items() if "rmse" in k and "floor" in k}
    row["floor_metrics"] = {k: v for k, v in ev.metrics.items() if k.startswith("floors.")}
    row["cloud"] = cloud_figures(out, boxes, scene)
    rec_all, rec_fix = {}, {}
    for f in range(building.n_floors):
        est, res = grid_cells(out, f)
        rec_all[f] = recall(truth_cells(building, f, res, False), est)
        rec_fix[f] = recall(truth_cells(building, f, res, True), est)
    row["grid_recall_corridor"] = rec_all
    row["grid_recall_furniture"] = rec_fix
    return row


def _painted_lidar_row(work: Path, seed: int) -> dict[str, Any]:
    from mfmap.sim.run import simulate

    sim_dir = work / f"sim_tiny_rgbd{seed}"
    if not (sim_dir / "log.mcap").exists():
        simulate("tiny-rgbd", sim_dir, seed=seed)
    log = work / f"tiny_rgbd_colour_only{seed}.mcap"
    if not log.exists():
        _without_depth(sim_dir / "log.mcap", log)
    out = work / f"build_lidar_painted{seed}"
    build_s = _build(log, out, True)
    _, boxes, scene = _truth(seed, "tiny-rgbd")
    return {"build_s": build_s, "cloud": cloud_figures(out, boxes, scene)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--work", type=Path, default=Path(".cache/depth_figures"))
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    import time

    from mfmap.sim.run import simulate

    work = args.work
    work.mkdir(parents=True, exist_ok=True)
    sim_dir = work / f"sim{args.seed}"
    t0 = time.perf_counter()
    if not (sim_dir / "log.mcap").exists():
        simulate("corridor-rgbd", sim_dir, seed=args.seed)
    sim_s = time.perf_counter() - t0
    truth = _truth(args.seed)
    rows: dict[str, Any] = {}
    for camera in (True, False):
        name = "camera" if camera else "no_camera"
        rows[name] = _corridor_row(sim_dir, work / f"build_{name}{args.seed}", camera, truth)
    rows["lidar_painted"] = _painted_lidar_row(work, args.seed)
    print(json.dumps({"simulate_s": sim_s, **rows}, indent=1, default=float))


if __name__ == "__main__":
    main()
