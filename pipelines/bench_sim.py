"""Simulator benchmark: minutes of log per minute of wall time, and peak memory, per scenario.

Each run is a fresh subprocess (so each peak RSS is its own) writing into --dir (deleted after
unless --keep). Prints wall and CPU time, log minutes per wall minute, log size and peak RSS; with
several --scale values the same building and route are repeated so memory can be compared across
log lengths (flat = written as it goes).

    .venv/bin/python pipelines/bench_sim.py                                  # two-floor and long
    .venv/bin/python pipelines/bench_sim.py --scenario two-floor --scale 1 2 4
    .venv/bin/python -m pipelines.bench_sim --manifest pipelines/manifests/stress.yaml --cache

With --manifest, the manifest's simulated logs (scenario, seed, format); with --cache they are
written into the simulator cache as the regression runner writes them (kept, so a following
`python -m pipelines.regression` run reuses them) and a log already there is regenerated.

Target: the 30-minute `long` log in under 5 minutes of wall time on a 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

_CHILD = """
import json, resource, sys, time
from pathlib import Path
from mfmap.sim import simulate, source_digest
scenario, out, fmt, scale, seed = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4]), int(sys.argv[5])
cache = sys.argv[6] == "cache"
t0 = time.perf_counter()
res = simulate(scenario, out, fmt=fmt, duration_scale=scale, seed=seed)
wall = time.perf_counter() - t0
if cache:  # the regression runner's and the tests' marker of a complete, current log
    (Path(out) / ".complete").write_text(source_digest() + "\\n")
ru = resource.getrusage(resource.RUSAGE_SELF)
print(json.dumps({
    "wall_s": wall, "cpu_s": ru.ru_utime + ru.ru_stime, "peak_mb": ru.ru_maxrss / 1024.0,
    "log_s": res.duration_s, "log_mb": res.log_bytes / 1e6,
    "scans": res.message_counts.get("/lidar/points", res.message_counts.get("/scan", 0)),
}))
"""


def run_one(scenario: str, out: Path, fmt: str, scale: float, seed: int = 0, cache: bool = False) -> dict[str, Any]:
    proc = subprocess.run(
        [sys.executable, "-c", _CHILD, scenario, str(out), fmt, str(scale), str(seed), "cache" if cache else "-"],
        capture_output=True,
        text=True,
        check=False,
    )
    if proc.returncode != 0:
        raise SystemExit(f"{scenario} x{scale}: failed\n{proc.stderr}")
    result: dict[str, Any] = json.loads(proc.stdout.strip().splitlines()[-1])
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenario", nargs="+", default=["two-floor", "long"])
    parser.add_argument("--scale", nargs="+", type=float, default=[1.0])
    parser.add_argument("--format", default="mcap", choices=["mcap", "ros1", "ros2"])
    parser.add_argument("--dir", type=Path, default=None, help="work folder (default: a temp dir)")
    parser.add_argument("--keep", action="store_true", help="keep the logs")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--manifest", type=Path, default=None, help="the simulated logs of a regression manifest")
    parser.add_argument("--cache", action="store_true", help="with --manifest: write into the simulator cache")
    args = parser.parse_args()
    base = args.dir or Path(tempfile.mkdtemp(prefix="bench_sim_"))
    runs: list[tuple[str, str, float, int, str]] = []  # (row name, scenario, scale, seed, format)
    if args.manifest is not None:
        from pipelines.regress.manifest import load_manifest

        manifest = load_manifest(args.manifest)
        for entry in manifest.logs:
            if entry.simulate is not None:
                sim = entry.simulate
                runs.append((entry.name, sim.scenario, sim.duration_scale, sim.seed, sim.fmt))
    else:
        runs = [(s, s, scale, args.seed, args.format) for s in args.scenario for scale in args.scale]
    print(f"{'log':<20}{'scale':>6}{'log min':>9}{'wall s':>9}{'cpu s':>9}{'log/wall':>10}{'scans/s':>9}{'log MB':>9}{'peak MB':>9}")
    try:
        for name, scenario, scale, seed, fmt in runs:
            cache = args.cache and args.manifest is not None
            if cache:
                from pipelines.regress.manifest import Simulate
                from pipelines.regress.runner import sim_folder

                sim = Simulate(scenario=scenario, seed=seed, fmt=fmt, duration_scale=scale)
                out = sim_folder(manifest.sim_cache_dir(), sim)
                shutil.rmtree(out, ignore_errors=True)
            else:
                out = base / f"{name}-x{scale:g}"
            r = run_one(scenario, out, fmt, scale, seed, cache)
            ratio = r["log_s"] / r["wall_s"]
            print(
                f"{name:<20}{scale:>6g}{r['log_s'] / 60:>9.1f}{r['wall_s']:>9.1f}{r['cpu_s']:>9.1f}"
                f"{ratio:>10.2f}{r['scans'] / r['wall_s']:>9.1f}{r['log_mb']:>9.0f}{r['peak_mb']:>9.0f}",
                flush=True,
            )
            if not args.keep and not cache:
                shutil.rmtree(out, ignore_errors=True)
    finally:
        if args.dir is None and not args.keep:
            shutil.rmtree(base, ignore_errors=True)
    print("log/wall = minutes of log per minute of wall time; target for long: >= 6 (30 min in 5 min)")


if __name__ == "__main__":
    main()
