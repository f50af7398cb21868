"""Wall time and peak memory of a command's whole process tree (the build and its workers).

`ru_maxrss` (what pipelines/benchmark.py reports) is the largest single process; a build's
mapping workers live beside the main process, so the tree's peak is their sum, sampled here with
psutil every 0.2 s:

    .venv/bin/python pipelines/bench_tree.py -- .venv/bin/mfmap build .cache/sim/long-mcap-0/log.mcap -o /tmp/blong --force
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time

import psutil


def tree_rss_bytes(root: psutil.Process) -> int:
    total = 0
    for proc in [root, *root.children(recursive=True)]:
        try:
            total += proc.memory_info().rss
        except (psutil.NoSuchProcess, psutil.AccessDenied):
            continue
    return total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("command", nargs=argparse.REMAINDER, help="the command, after --")
    parser.add_argument("--interval-s", type=float, default=0.2)
    args = parser.parse_args()
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        parser.error("no command given")
    started = time.perf_counter()
    child = subprocess.Popen(command, stdout=subprocess.DEVNULL)
    root = psutil.Process(child.pid)
    peak = 0
    while child.poll() is None:
        try:
            peak = max(peak, tree_rss_bytes(root))
        except psutil.NoSuchProcess:
            break
        time.sleep(args.interval_s)
    wall_s = time.perf_counter() - started
    print(f"exit {child.returncode}, wall {wall_s:.1f} s, peak tree RSS {peak / 2**30:.2f} GiB "
          f"(sampled every {args.interval_s} s)")
    sys.exit(child.returncode)


if __name__ == "__main__":
    main()
