"""Benchmark and accuracy of `mfmap localize` (prints figures; never asserts on time).

    python -m pipelines.bench_localize                       # office3-day4 in office3-day3's map
    python -m pipelines.bench_localize --map tiny-day1 --log tiny-day2 --foreign gen-tiny
    python -m pipelines.bench_localize --repeat 3 --work work/bench_localize

The map is the simulator's log `--map` built by `mfmap build` (once; kept in --work); `--log`,
another day's log of the same building, is localised in it without a hint, `--repeat` times,
each `mfmap localize` a child process: wall time and CPU time (user + system, wait4's, which
the machine's other load hardly moves), their real-time factors, and the peak RSS. Accuracy
against the simulator's ground truth (`mfmap.localize.score`): APE RMSE of the posed scans (all
of them, rides included), the share of time on the right floor, the first fix, the posed and
the wrongly posed shares. `--foreign` is a log of another building, localised in the same map:
it should be posed nowhere.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
from pathlib import Path
from typing import Any

from pipelines.benchmark import ChildRun, run_child

ROOT = Path(__file__).resolve().parent.parent
# The paper's figure for its localisation on the third floor ("3D Multi-floor Precision Mapping
# and Localization for Indoor Autonomous Robots": mean square error 0.116 m, 0.01 s a scan).
PAPER_ERROR_M = 0.116


def _sim(cache: Path, scenario: str, seed: int) -> Path:
    from pipelines.regress.manifest import Simulate
    from pipelines.regress.runner import ensure_simulated

    return ensure_simulated(cache, Simulate(scenario=scenario, seed=seed))


def _mfmap() -> str:
    return str(Path(sys.executable).parent / "mfmap")


def build_map(sim: Path, work: Path) -> tuple[Path, ChildRun | None]:
    """The map of a simulated log, built once per simulator version (its digest)."""
    out = work / f"map-{sim.name}"
    digest = (sim / ".complete").read_text().strip()
    stamp = work / f"map-{sim.name}.digest"
    if out.is_dir() and stamp.exists() and stamp.read_text().strip() == digest:
        return out, None
    run = run_child([_mfmap(), "build", str(sim / "log.mcap"), "-o", str(out), "--force"])
    if not run.ok:
        raise SystemExit(f"mfmap build failed: {run.stderr_tail}")
    stamp.write_text(digest + "\n")
    return out, run


def localize_runs(log: Path, map_dir: Path, out: Path, repeat: int) -> list[ChildRun]:
    runs = []
    for _ in range(repeat):
        shutil.rmtree(out, ignore_errors=True)
        run = run_child([_mfmap(), "localize", str(log), "--map", str(map_dir), "-o", str(out)])
        if not run.ok:
            raise SystemExit(f"mfmap localize failed: {run.stderr_tail}")
        runs.append(run)
    return runs


def figures(sim: Path, out: Path, runs: list[ChildRun], foreign: bool = False) -> dict[str, Any]:
    from mfmap.localize.score import score_localization

    report = json.loads((out / "report.json").read_text())
    duration = float(report["log_duration_s"])
    wall = statistics.median(r.wall_s for r in runs)
    cpu = statistics.median(r.cpu_s for r in runs)
    metrics = score_localization(out, None if foreign else sim / "gt_trajectory.tum",
                                 None if foreign else sim / "gt_floors.json", foreign=foreign)
    return {
        "log": sim.name,
        "log_s": duration,
        "scans": int(report["scans"]),
        "wall_s": wall,
        "cpu_s": cpu,
        "wall_runs_s": [round(r.wall_s, 2) for r in runs],
        "realtime_factor": duration / wall,
        "cpu_realtime_factor": duration / cpu,
        "peak_rss_mb": max(r.peak_rss_mb for r in runs),
        "cpu_by_stage_s": report.get("cpu_timings_s", {}),
        "registered": int(report["registered"]),
        "metrics": metrics,
        "not_localised": report["not_localised"],
    }


def _f(value: float | None, digits: int = 3) -> str:
    if value is None or value != value:
        return "-"
    return f"{value:.{digits}f}"


def table(main: dict[str, Any], foreign: dict[str, Any] | None) -> str:
    m = main["metrics"]
    lines = [
        f"## `mfmap localize` {main['log']} ({main['log_s']:.0f} s, {main['scans']} scans)",
        "",
        "| figure | value | bar |",
        "|---|---:|---|",
        f"| trajectory APE RMSE (all posed scans) | {_f(m.get('trajectory.ape_rmse_m'), 4)} m | "
        f"<= 0.05 m (the paper: {PAPER_ERROR_M} m) |",
        f"| position error median / 95th percentile | {_f(m.get('localize.pos_median_m'), 4)} / "
        f"{_f(m.get('localize.pos_p95_m'), 4)} m | |",
        f"| APE max | {_f(m.get('trajectory.ape_max_m'), 4)} m | |",
        f"| xy RMSE / z RMSE (z: the map's floor elevations) | {_f(m.get('trajectory.xy_rmse_m'), 4)} "
        f"/ {_f(m.get('trajectory.z_rmse_m'), 4)} m | |",
        f"| yaw error median / 95th percentile | {_f(m.get('localize.yaw_median_deg'), 2)} / "
        f"{_f(m.get('localize.yaw_p95_deg'), 2)} deg | |",
        f"| rotation RMSE | {_f(m.get('trajectory.rot_rmse_deg'), 2)} deg | |",
        f"| time on the right floor | {100 * m.get('floors.time_correct_share', float('nan')):.2f} % "
        "| >= 99 % |",
        f"| first global fix (no hint) | {_f(m.get('localize.first_fix_s'), 1)} s | <= 10 s |",
        f"| scans posed | {100 * m['localize.localised_share']:.2f} % | |",
        f"| scans posed wrongly (> 0.5 m) | {100 * m.get('localize.wrong_share', 0.0):.2f} % | 0 |",
        f"| wall time (median of {len(main['wall_runs_s'])}: {main['wall_runs_s']}) | "
        f"{main['wall_s']:.1f} s = {main['realtime_factor']:.1f}x real time | >= 20x |",
        f"| CPU time | {main['cpu_s']:.1f} s = {main['cpu_realtime_factor']:.1f}x real time | |",
        f"| registered scans | {main['registered']} | |",
        f"| peak RSS | {main['peak_rss_mb']:.0f} MB | |",
        "",
        "CPU by stage [s]: " + ", ".join(f"{k} {v:.2f}" for k, v in main["cpu_by_stage_s"].items()),
    ]
    if foreign is not None:
        fm = foreign["metrics"]
        best = max((s["best_fitness"] for s in foreign["not_localised"]), default=0.0)
        lines += [
            "",
            f"## another building: {foreign['log']} ({foreign['log_s']:.0f} s) in the same map",
            "",
            "| figure | value | bar |",
            "|---|---:|---|",
            f"| scans posed | {100 * fm['localize.localised_share']:.2f} % | 0 (not localised "
            "throughout) |",
            f"| spans not localised | {len(foreign['not_localised'])} (best fitness {best:.2f}) | |",
            f"| searches | {fm['localize.searches']:.0f} | |",
            f"| wall / CPU time | {foreign['wall_s']:.1f} s / {foreign['cpu_s']:.1f} s | |",
        ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pipelines.bench_localize",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--map", default="office3-day3", help="scenario whose build is the map")
    parser.add_argument("--log", default="office3-day4", help="scenario localised in it")
    parser.add_argument("--foreign", default="gen-tiny",
                        help="a log of another building ('' for none)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeat", type=int, default=1, help="localize runs (median)")
    parser.add_argument("--work", type=Path, default=ROOT / "work" / "bench_localize")
    parser.add_argument("--sim-cache", type=Path, default=ROOT / ".cache" / "sim")
    args = parser.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    map_sim = _sim(args.sim_cache, args.map, args.seed)
    log_sim = _sim(args.sim_cache, args.log, args.seed)
    map_dir, built = build_map(map_sim, args.work)
    if built is not None:
        print(f"built the map {map_dir} in {built.wall_s:.1f} s ({built.cpu_s:.1f} s of CPU)")
    out = args.work / f"localize-{log_sim.name}"
    main_fig = figures(log_sim, out, localize_runs(log_sim / "log.mcap", map_dir, out, args.repeat))
    foreign_fig = None
    if args.foreign:
        foreign_sim = _sim(args.sim_cache, args.foreign, args.seed)
        fout = args.work / f"localize-{foreign_sim.name}"
        foreign_fig = figures(foreign_sim, fout, localize_runs(foreign_sim / "log.mcap", map_dir,
                                                               fout, 1), foreign=True)
    print(table(main_fig, foreign_fig))
    (args.work / "results.json").write_text(json.dumps({"log": main_fig, "foreign": foreign_fig},
                                                       indent=2, default=float) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
