"""Benchmark and accuracy table for `mfmap build` (prints figures; never asserts on time).

    python pipelines/bench_build.py two-floor            # whole-process time, peak memory, RTF
    python pipelines/bench_build.py long --work work/bench
    python pipelines/bench_build.py two-floor --ablations   # accuracy with each ablation off once

Speed: `mfmap build` runs as a child process; wall time and the child's peak RSS
(getrusage(RUSAGE_CHILDREN).ru_maxrss) are the whole process's. Accuracy: `mfmap eval` metrics
against the simulator's ground truth (checkpoint RMSE per floor, inter-floor x/y/yaw/z errors) and
each floor grid's occupied-cell precision/recall against the ground-truth walls within 1 and 2
cells (`mfmap.eval.grids`, the scoring of tests/export).
For the ablations the front stages (floors, mapping) run once and the graph and exports are
redone per variant, since the switches only change the graph.
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
ABLATIONS: dict[str, dict[str, bool]] = {
    "full": {},
    "no barometer factors": {"barometer_factors": False},
    "no barometric transition heights": {"transition_height": False},
    "no elevator continuity": {"elevator_continuity": False},
    "no inter-floor registration": {"inter_floor_registration": False},
    "no IMU ride height": {"imu_ride_height": False},
}


def simulate(scenario: str, work: Path, seed: int) -> Path:
    from mfmap.sim import simulate as run

    folder = work / f"sim-{scenario}-{seed}"
    if not (folder / ".complete").exists():
        run(scenario, folder, fmt="mcap", seed=seed)
        (folder / ".complete").write_text("ok\n")
    return folder


def bench(sim: Path, out: Path) -> dict[str, float]:
    """Time `mfmap build` as a child process; return wall time, peak RSS, real-time factor."""
    shutil.rmtree(out, ignore_errors=True)
    exe = Path(sys.executable).parent / "mfmap"
    started = time.perf_counter()
    proc = subprocess.run([str(exe), "build", str(sim / "log.mcap"), "-o", str(out), "--force"],
                          capture_output=True, text=True)
    wall_s = time.perf_counter() - started
    if proc.returncode != 0:
        raise SystemExit(f"mfmap build failed:\n{proc.stderr}")
    peak_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    report = json.loads((out / "report.json").read_text())
    log_s = float(report["summary"]["log_duration_s"])
    return {"log_s": log_s, "wall_s": wall_s, "peak_rss_mb": peak_mb, "rtf": log_s / wall_s,
            **{f"stage_{k}_s": v for k, v in report["timings_s"].items()}}


def evaluate(out: Path, sim: Path) -> dict[str, Any]:
    from mfmap.eval import evaluate as run_eval

    result = run_eval(out, points=sim / "gt_points.csv", floors=sim / "gt_floors.json",
                      trajectory=sim / "gt_trajectory.tum")
    target = out / "eval.json"
    result.write_json(target)
    return dict(json.loads(target.read_text()))


def ablations(sim: Path, work: Path) -> list[tuple[str, dict[str, Any]]]:
    """Front stages once; graph + exports + eval per ablation."""
    from mfmap import pipeline
    from mfmap.config import MfmapConfig, dump_config
    from mfmap.export.config import CloudSource
    from mfmap.export.files import write_json
    from mfmap.export.write import write_outputs
    from mfmap.ingest import open_log
    from mfmap.mapping import map_floors
    from mfmap.report import BuildReport, ReportSummary

    cfg = MfmapConfig()
    rows = []
    with open_log(sim / "log.mcap", cfg.ingest) as src:
        pressure, seg = pipeline.segment_floors(src, cfg)
        extrinsics = src.extrinsics()
        mapping = map_floors(src, seg, cfg.mapping, extrinsics)
        imu, odom = src.imu(), src.odometry()
        for name, switches in ABLATIONS.items():
            variant = cfg.model_copy(deep=True)
            for key, value in switches.items():
                setattr(variant.graph.ablation, key, value)
            variant.export.cloud.source = CloudSource.KEYFRAMES
            variant.export.html_report = False
            graph = pipeline.optimise(mapping, seg, pressure, imu, extrinsics, variant, pipeline.NullProgress(),
                                     odom=odom)
            trajectory, maps = pipeline.accumulate(src, seg, mapping, graph, extrinsics, variant,
                                                   pipeline.NullProgress())
            out = work / f"ablation-{sim.name}-{name.replace(' ', '-')}"
            shutil.rmtree(out, ignore_errors=True)
            report = BuildReport(str(sim / "log.mcap"), {}, ReportSummary(len(seg.floors), len(seg.transitions), 0.0,
                                 len(mapping.keyframes)), {}, {}, {}, graph.to_json(), list(graph.warnings))
            write_outputs(out, seg, mapping, graph, trajectory, maps, report, dump_config(variant),
                          title=name, html=False)
            write_json(out / "report.json", report.to_json())  # the eval needs a finished build
            rows.append((name, evaluate(out, sim)))
    return rows


def grid_scores(out: Path, sim: Path) -> str:
    """Occupied cells of each floor grid vs the ground-truth walls (as tests/export scores them;
    recall against the walls visible from the true path)."""
    from mfmap.eval.grids import score_build

    lines = []
    for tol in (1, 2):
        for s in score_build(out, sim / "gt_cloud.ply", sim / "gt_floors.json", tolerance_cells=tol,
                             gt_trajectory=sim / "gt_trajectory.tum"):
            lines.append(f"grid.floor{s.floor_id}.tol{tol}_cells: precision {s.precision:.3f} recall {s.recall:.3f}")
    return "  " + "\n  ".join(lines)


def _fmt_eval(ev: dict[str, Any]) -> str:
    metrics = ev.get("metrics", ev)
    keys = sorted(
        k for k in metrics
        if (k.startswith("points.floor") and k.endswith(".rmse_m") and ".z_" not in k)
        or (k.startswith("floors.inter") and not k.startswith("floors.inter."))
        or k == "floors.count_correct"
    )
    return "  " + "\n  ".join(f"{k} = {metrics[k]:.4f}" for k in keys)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenario", nargs="+")
    parser.add_argument("--work", type=Path, default=ROOT / "work" / "bench")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--ablations", action="store_true", help="accuracy table per ablation")
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    for scenario in args.scenario:
        sim = simulate(scenario, args.work, args.seed)
        if args.ablations:
            for name, ev in ablations(sim, args.work):
                print(f"== {scenario} / {name}")
                print(_fmt_eval(ev))
            continue
        out = args.work / f"build-{scenario}-{args.seed}"
        fig = bench(sim, out)
        print(f"{scenario}: log {fig['log_s']:.0f} s, build {fig['wall_s']:.1f} s "
              f"({fig['rtf']:.1f}x real time), peak RSS {fig['peak_rss_mb']:.0f} MB")
        print("  stages: " + ", ".join(f"{k[6:-2]} {v:.1f} s" for k, v in fig.items() if k.startswith("stage_")))
        print(_fmt_eval(evaluate(out, sim)))
        print(grid_scores(out, sim))


if __name__ == "__main__":
    main()
