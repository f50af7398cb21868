"""Benchmark suite: whole-process figures of `mfmap build`, its peers, and scaling with log length.

    python -m pipelines.benchmark [--scenarios two-floor,stairs] [--quick] [--skip-peers]
                                  [--skip-scaling] [--scaling-scenario two-floor]
                                  [--scales 1,2,4] [--out work/benchmark]
                                  [--markdown docs/performance.md]

Every figure is measured on a child process: `mfmap build` (and each peer) runs in a subprocess,
its wall time is taken around it and its peak memory is the child's own `ru_maxrss` from
`os.wait4`, so nothing the benchmark itself holds is counted. Peers on the same input:
- bare MCAP iteration: every record of the file read, nothing decoded (the floor for ingest);
- mfmap's ingest alone: every lidar scan decoded through `open_log().clouds()`, as
  `pipelines/bench_ingest.py --measure decode` does it;
- KISS-ICP odometry on the first floor visit (it cannot ride an elevator), as
  `pipelines/bench_odometry.py --child kiss` runs it. Its scans/s count odometry only, after
  the scans are decoded; mfmap's count the whole build (floors, mapping, graph, exports).
Scaling: the same building at 1x, 2x and 4x log length (`simulate(..., duration_scale=k)`);
time should grow linearly (4x within 4.4x of 1x) and peak memory stay bounded (within 1.5x).
Prints a Markdown table and writes it (and benchmark.json) to the output folder. With
`--markdown FILE` the tables also replace what stands between the markers
`<!-- benchmark:start -->` and `<!-- benchmark:end -->` in FILE (the whole file when it has
none), so a document's figures are refreshed by the command it names.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from mfmap.atomic import write_text_atomic
from pipelines.regress.manifest import DEFAULT_SIM_CACHE, Simulate
from pipelines.regress.runner import SIM_LOG_NAME, ensure_simulated

STANDARD_SCENARIOS = ["two-floor", "three-floor-revisit", "stairs", "single-floor"]
QUICK_SCENARIOS = ["tiny"]
MARKDOWN_START = "<!-- benchmark:start -->"
MARKDOWN_END = "<!-- benchmark:end -->"
# The acceptance figures for scaling.
MAX_TIME_RATIO_4X = 4.4
MAX_MEMORY_RATIO_4X = 1.5

# Bare MCAP iteration: the least any reader of the log must do (runs as its own process).
_MCAP_FLOOR = """
import sys
from mcap.reader import make_reader
n = 0
with open(sys.argv[1], "rb") as f:
    for _schema, _channel, _message in make_reader(f).iter_messages():
        n += 1
print(n)
"""

HERE = Path(__file__).resolve().parent


@dataclass(frozen=True)
class ChildRun:
    """One measured subprocess."""

    wall_s: float
    peak_rss_mb: float
    returncode: int
    stdout: str
    stderr_tail: str
    cpu_s: float = 0.0  # user + system time of the child and the children it reaped

    @property
    def ok(self) -> bool:
        return self.returncode == 0


def run_child(argv: list[str], env: dict[str, str] | None = None) -> ChildRun:
    """Run a command; wall time, the child's own peak RSS (wait4's ru_maxrss) and its CPU time.

    The CPU time (wait4's user + system time) includes the processes the child waited for, such as
    a build's worker pool; unlike the wall time it hardly moves with the machine's other load.

    Linux carries the peak RSS across fork and exec, so the figure is at least this process's RSS
    at spawn: callers keep the measuring process small (this module imports nothing heavy)."""
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        start = time.perf_counter()
        proc = subprocess.Popen(argv, stdout=out, stderr=err, env=env)
        _, status, usage = os.wait4(proc.pid, 0)
        wall_s = time.perf_counter() - start
        proc.returncode = os.waitstatus_to_exitcode(status)  # reaped here, not by Popen
        out.seek(0)
        err.seek(0)
        stdout = out.read().decode(errors="replace")
        stderr = err.read().decode(errors="replace")
    tail = " ".join(stderr.strip().splitlines()[-3:])
    # ru_maxrss is in KiB on Linux.
    return ChildRun(wall_s, usage.ru_maxrss / 1024.0, proc.returncode, stdout, tail,
                    usage.ru_utime + usage.ru_stime)


def _env(threads: int | None) -> dict[str, str]:
    env = dict(os.environ)
    if threads is not None:
        env["OMP_NUM_THREADS"] = str(threads)
    return env


def tum_span_s(path: Path) -> tuple[float, int]:
    """(last - first stamp, line count) of a TUM file."""
    stamps = [float(line.split()[0]) for line in path.read_text().splitlines() if line.strip() and not line.startswith("#")]
    if not stamps:
        return 0.0, 0
    return stamps[-1] - stamps[0], len(stamps)


@dataclass
class BuildFigures:
    """`mfmap build` on one log."""

    label: str
    log: str
    log_duration_s: float
    scans: int
    wall_s: float
    peak_rss_mb: float
    ok: bool
    error: str = ""
    walls_s: list[float] = field(default_factory=list)  # every run's wall time, with --repeat
    cpu_s: float = 0.0  # CPU time of the build and its workers

    @property
    def realtime_factor(self) -> float:
        return self.log_duration_s / self.wall_s if self.wall_s > 0 else 0.0

    @property
    def scans_per_s(self) -> float:
        return self.scans / self.wall_s if self.wall_s > 0 else 0.0


@dataclass
class PeerFigures:
    """A peer on the same input: whole-process figures plus its own count and timing."""

    name: str
    wall_s: float  # whole process
    peak_rss_mb: float
    ok: bool
    items: int = 0  # scans or records the peer went through
    work_s: float = 0.0  # the peer's own timing of the work (no imports, no loading)
    error: str = ""

    @property
    def items_per_s(self) -> float:
        t = self.work_s if self.work_s > 0 else self.wall_s
        return self.items / t if t > 0 else 0.0


@dataclass
class ScenarioFigures:
    build: BuildFigures
    peers: list[PeerFigures] = field(default_factory=list)


def bench_build(label: str, log: Path, gt_trajectory: Path | None, out: Path, threads: int | None) -> BuildFigures:
    """`mfmap build LOG -o OUT --force` as a child process."""
    argv = [sys.executable, "-m", "mfmap.cli", "build", str(log), "-o", str(out), "--force"]
    run = run_child(argv, _env(threads))
    traj = out / "trajectory.tum"
    scans = tum_span_s(traj)[1] if run.ok and traj.exists() else 0  # one pose per lidar scan
    duration = 0.0
    if gt_trajectory is not None and gt_trajectory.exists():
        duration = tum_span_s(gt_trajectory)[0]
    elif run.ok and traj.exists():
        duration = tum_span_s(traj)[0]
    return BuildFigures(
        label, str(log), duration, scans, run.wall_s, run.peak_rss_mb, run.ok,
        "" if run.ok else run.stderr_tail, cpu_s=run.cpu_s,
    )


def bench_build_repeated(label: str, log: Path, gt_trajectory: Path | None, out: Path,
                         threads: int | None, repeat: int) -> BuildFigures:
    """`repeat` builds of one log: the run of median wall time, with every run's wall time and
    the highest peak memory (a shared machine's neighbours move a build's time by 20 % and more
    from one run to the next; the median of a few is the figure to compare)."""
    return median_run([bench_build(label, log, gt_trajectory, out, threads)
                       for _ in range(max(1, repeat))])


def median_run(runs: list[BuildFigures]) -> BuildFigures:
    """The run of median wall time (the lower of the two middle ones), carrying every run's wall
    time and the highest peak memory; the first failed run when any failed."""
    failed = [r for r in runs if not r.ok]
    if failed:
        return failed[0]
    median = sorted(runs, key=lambda r: r.wall_s)[(len(runs) - 1) // 2]
    return replace(median, peak_rss_mb=max(r.peak_rss_mb for r in runs),
                   walls_s=[r.wall_s for r in runs])


def bench_mcap_floor(log: Path) -> PeerFigures:
    """Bare MCAP iteration of the same file (the ingest floor)."""
    run = run_child([sys.executable, "-c", _MCAP_FLOOR, str(log)])
    return PeerFigures(
        "bare MCAP iteration", run.wall_s, run.peak_rss_mb, run.ok, _last_int(run.stdout), error=run.stderr_tail
    )


def _peer(name: str, argv: list[str], env: dict[str, str] | None = None) -> PeerFigures:
    """Run a peer as a child that prints its figures as a JSON line last."""
    run = run_child(argv, env)
    data = _last_json(run.stdout)
    return PeerFigures(
        name,
        run.wall_s,
        run.peak_rss_mb,
        run.ok and bool(data),
        int(data.get("scans", 0)),
        float(data.get("wall_s", 0.0)),
        run.stderr_tail,
    )


def bench_ingest_decode(log: Path) -> PeerFigures:
    """mfmap's ingest decoding every lidar scan (pipelines/bench_ingest.py's decode mode)."""
    argv = [sys.executable, str(HERE / "bench_ingest.py"), "--measure", "decode", "--log", str(log)]
    return _peer("mfmap ingest decode", argv)


def bench_kiss_icp(folder: Path, threads: int | None) -> PeerFigures:
    """KISS-ICP odometry on the first floor visit (pipelines/bench_odometry.py's kiss child)."""
    argv = [sys.executable, str(HERE / "bench_odometry.py"), "--folder", str(folder), "--child", "kiss"]
    return _peer("KISS-ICP odometry", argv, _env(threads))


def _last_json(text: str) -> dict[str, Any]:
    for line in reversed(text.strip().splitlines()):
        try:
            data = json.loads(line)
        except ValueError:
            continue
        if isinstance(data, dict):
            return data
    return {}


def _last_int(text: str) -> int:
    for line in reversed(text.strip().splitlines()):
        try:
            return int(line.strip())
        except ValueError:
            continue
    return 0


def _sim(cache: Path, scenario: str, scale: float = 1.0) -> tuple[Path, Path]:
    folder = ensure_simulated(cache, Simulate(scenario=scenario, duration_scale=scale))
    return folder / SIM_LOG_NAME["mcap"], folder / "gt_trajectory.tum"


# ---------------------------------------------------------------------------------------------
# Markdown


def _wall_cell(b: BuildFigures) -> str:
    if len(b.walls_s) < 2:
        return _f(b.wall_s)
    return f"{_f(b.wall_s)} (median of {len(b.walls_s)}: {_f(min(b.walls_s))}-{_f(max(b.walls_s))})"


def _f(x: float, digits: int = 2) -> str:
    return f"{x:.{digits}f}"


def scenario_table(rows: list[ScenarioFigures]) -> str:
    """mfmap build per scenario, and the peers on the same log as ratios."""
    lines = [
        "| scenario | log s | scans | build s | real-time factor | build CPU s | scans/s | peak MB "
        "| bare MCAP iteration s (MB) | build / bare | ingest decode s (MB) | decode / bare "
        "| KISS-ICP scans/s (MB) | KISS-ICP / build scans/s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        b = row.build
        if not b.ok:
            lines.append(f"| {b.label} | {_f(b.log_duration_s, 1)} | build failed: {_cell(b.error)} |" + " |" * 11)
            continue
        peers = {p.name: p for p in row.peers}
        bare = peers.get("bare MCAP iteration")
        decode = peers.get("mfmap ingest decode")
        kiss = peers.get("KISS-ICP odometry")
        cells = [
            b.label,
            _f(b.log_duration_s, 1),
            str(b.scans),
            _wall_cell(b),
            f"{_f(b.realtime_factor, 1)}x",
            _f(b.cpu_s, 1),
            _f(b.scans_per_s, 1),
            _f(b.peak_rss_mb, 0),
            _peer_cell(bare),
            _ratio(b.wall_s, bare),
            _peer_cell(decode),
            _ratio(decode.wall_s, bare) if decode is not None and decode.ok else "-",
            f"{_f(kiss.items_per_s, 1)} ({_f(kiss.peak_rss_mb, 0)})" if kiss is not None and kiss.ok else _failed_cell(kiss),
            f"{kiss.items_per_s / b.scans_per_s:.1f}x" if kiss is not None and kiss.ok and b.scans_per_s > 0 else "-",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _peer_cell(peer: PeerFigures | None) -> str:
    if peer is None or not peer.ok:
        return _failed_cell(peer)
    return f"{_f(peer.wall_s)} ({_f(peer.peak_rss_mb, 0)})"


def _failed_cell(peer: PeerFigures | None) -> str:
    return "-" if peer is None else f"failed: {_cell(peer.error)[:80]}"


def _ratio(wall_s: float, peer: PeerFigures | None) -> str:
    if peer is None or not peer.ok or peer.wall_s <= 0:
        return "-"
    return f"{wall_s / peer.wall_s:.1f}x"


def _cell(text: str) -> str:
    return " ".join(text.split()).replace("|", "/")


def scaling_table(rows: list[BuildFigures], scales: list[float]) -> tuple[str, dict[str, Any]]:
    """The scaling table and its verdict against the issue's limits."""
    lines = [
        "| log length | log s | log vs 1x | scans | build s | time vs 1x | peak MB | memory vs 1x | scans/s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    base = rows[0] if rows and rows[0].ok else None
    verdict: dict[str, Any] = {}
    for scale, b in zip(scales, rows, strict=True):
        if not b.ok or base is None:
            lines.append(f"| {scale:g}x | {_f(b.log_duration_s, 1)} | | build failed: {_cell(b.error)} |" + " |" * 5)
            continue
        t_ratio = b.wall_s / base.wall_s
        m_ratio = b.peak_rss_mb / base.peak_rss_mb
        log_ratio = b.log_duration_s / base.log_duration_s if base.log_duration_s > 0 else 0.0
        lines.append(
            f"| {scale:g}x | {_f(b.log_duration_s, 1)} | {log_ratio:.2f}x | {b.scans} | {_f(b.wall_s)} "
            f"| {t_ratio:.2f}x | {_f(b.peak_rss_mb, 0)} | {m_ratio:.2f}x | {_f(b.scans_per_s, 1)} |"
        )
        if scale == max(scales):
            verdict = {
                "scale": scale,
                "log_ratio": log_ratio,
                "time_ratio": t_ratio,
                "memory_ratio": m_ratio,
                "time_ok": t_ratio <= MAX_TIME_RATIO_4X * scale / 4.0,
                "memory_ok": m_ratio <= MAX_MEMORY_RATIO_4X,
            }
    text = "\n".join(lines) + "\n"
    if verdict:
        limit_t = MAX_TIME_RATIO_4X * verdict["scale"] / 4.0
        text += (
            f"\nAt {verdict['scale']:g}x: time {verdict['time_ratio']:.2f}x of 1x "
            f"(limit {limit_t:.2f}x: {'PASS' if verdict['time_ok'] else 'FAIL'}), peak memory "
            f"{verdict['memory_ratio']:.2f}x (limit {MAX_MEMORY_RATIO_4X}x: "
            f"{'PASS' if verdict['memory_ok'] else 'FAIL'}). The simulator lengthens a log by "
            f"repeating its route, so the log itself is {verdict['log_ratio']:.2f}x as long; "
            f"time per second of log: {verdict['time_ratio'] / max(verdict['log_ratio'], 1e-9):.2f}x "
            "of 1x.\n"
        )
    return text, verdict


# ---------------------------------------------------------------------------------------------


def _build_json(b: BuildFigures) -> dict[str, Any]:
    data: dict[str, Any] = asdict(b)
    data["realtime_factor"] = b.realtime_factor
    data["scans_per_s"] = b.scans_per_s
    return data


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m pipelines.benchmark", description=__doc__.split("\n\n")[0])
    p.add_argument("--scenarios", default=None, help=f"comma-separated (default {','.join(STANDARD_SCENARIOS)})")
    p.add_argument("--quick", action="store_true", help="small scenario only (tiny), for a smoke run")
    p.add_argument("--skip-peers", action="store_true", help="no KISS-ICP / MCAP iteration runs")
    p.add_argument("--skip-scaling", action="store_true", help="no 1x/2x/4x runs")
    p.add_argument("--scaling-scenario", default=None, help="building for the scaling runs (default two-floor)")
    p.add_argument("--scales", default="1,2,4", help="log length multipliers, first is the reference")
    p.add_argument("--threads", type=int, default=None, help="OMP_NUM_THREADS for the children")
    p.add_argument("--repeat", type=int, default=1,
                   help="builds per scenario; the figures are the median run's (default 1)")
    p.add_argument("--sim-cache", type=Path, default=DEFAULT_SIM_CACHE, help="simulated logs cache")
    p.add_argument("--out", type=Path, default=Path("work") / "benchmark", help="output folder")
    p.add_argument("--markdown", type=Path, default=None, metavar="FILE",
                   help="also write the tables into FILE, between its benchmark markers if it has them")
    return p.parse_args(argv)


def splice_markdown(path: Path, tables: str) -> None:
    """`tables` between the benchmark markers of `path`, or as the whole file without them."""
    block = f"{MARKDOWN_START}\n{tables.strip()}\n{MARKDOWN_END}\n"
    old = path.read_text() if path.exists() else ""
    start, end = old.find(MARKDOWN_START), old.find(MARKDOWN_END)
    if start < 0 or end < start:
        write_text_atomic(path, block)
        return
    rest = old[end + len(MARKDOWN_END):]
    write_text_atomic(path, old[:start] + block + rest.removeprefix("\n"))


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    scenarios = (
        args.scenarios.split(",") if args.scenarios else (QUICK_SCENARIOS if args.quick else STANDARD_SCENARIOS)
    )
    scaling_scenario = args.scaling_scenario or ("tiny" if args.quick else "two-floor")
    scales = [float(s) for s in args.scales.split(",")]
    out: Path = args.out
    builds = out / "builds"
    started = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())

    rows: list[ScenarioFigures] = []
    for name in scenarios:
        print(f"benchmark: {name}", file=sys.stderr, flush=True)
        log, gt = _sim(args.sim_cache, name)
        row = ScenarioFigures(bench_build_repeated(name, log, gt, builds / name, args.threads,
                                                  args.repeat))
        if not args.skip_peers:
            row.peers.append(bench_mcap_floor(log))
            row.peers.append(bench_ingest_decode(log))
            row.peers.append(bench_kiss_icp(log.parent, args.threads))
        rows.append(row)

    scaling: list[BuildFigures] = []
    if not args.skip_scaling:
        for scale in scales:
            print(f"benchmark: scaling {scaling_scenario} x{scale:g}", file=sys.stderr, flush=True)
            log, gt = _sim(args.sim_cache, scaling_scenario, scale)
            label = f"{scaling_scenario} x{scale:g}"
            scaling.append(bench_build(label, log, gt, builds / f"{scaling_scenario}-x{scale:g}", args.threads))

    import platform

    cpus = os.cpu_count()
    command = f"python -m pipelines.benchmark {' '.join(argv if argv is not None else sys.argv[1:])}".rstrip()
    machine = f"{platform.machine()} with {cpus} CPUs, Python {platform.python_version()}"
    legend = (
        "Whole-process figures of each child: wall time, peak RSS (`ru_maxrss`); real-time factor = "
        "log duration / wall time; build CPU s = user + system time of the build and its workers "
        "(of the median run with `--repeat`)."
    )
    text = [
        "## Performance",
        "",
        f"Made by `{command}` on {started}, {machine}. {legend}",
        "",
        scenario_table(rows),
    ]
    verdict: dict[str, Any] = {}
    if scaling:
        table, verdict = scaling_table(scaling, scales)
        text += [f"### Scaling: `{scaling_scenario}` at {', '.join(f'{s:g}x' for s in scales)} log length", "", table]
    markdown = "\n".join(text)
    sys.stdout.write(markdown)
    write_text_atomic(out / "benchmark.md", markdown)
    if args.markdown is not None:
        # The command and the machine, not the time of the run: a document states what it is.
        from pipelines.regress.machine import machine_fingerprint

        where = f"`{machine_fingerprint()}` with {cpus} CPUs"
        splice_markdown(args.markdown, "\n".join([f"Made by `{command}` on {where}. {legend}",
                                                  "", *text[4:]]))
        print(f"written: {args.markdown}", file=sys.stderr)
    data = {
        "started": started,
        "cpus": cpus,
        "scenarios": [
            {"build": _build_json(r.build), "peers": [asdict(p) for p in r.peers]} for r in rows
        ],
        "scaling": [{**asdict(b), "scale": s} for s, b in zip(scales, scaling, strict=False)],
        "scaling_verdict": verdict,
    }
    write_text_atomic(out / "benchmark.json", json.dumps(data, indent=2) + "\n")
    print(f"written: {out / 'benchmark.md'}, {out / 'benchmark.json'}", file=sys.stderr)
    failed = any(not r.build.ok for r in rows) or any(not b.ok for b in scaling)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
