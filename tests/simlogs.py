"""The simulated logs the tests read, made before the tests start.

    python -m tests.simlogs [--workers N]

The tests' `sim_run` fixture simulates a log the first time one asks for it (cached in
.cache/sim, or MFMAP_SIM_CACHE). From a cold cache that makes pytest-xdist's workers wait on
each other: both need the same log, one simulates it and the other idles. Made here first, N
logs at a time from the longest down, the simulations keep every core busy and the tests find
them all cached. `make test` runs this before pytest; `sim_run` refuses a log missing from
SIM_LOGS, so the list cannot fall behind the tests.
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

# Longest first, so that the last to finish are short.
SIM_LOGS: tuple[dict[str, Any], ...] = (
    {"scenario": "three-floor-revisit"},
    {"scenario": "two-floor"},
    {"scenario": "stairs"},
    {"scenario": "gen-stairs", "seed": 11},
    {"scenario": "tiny", "duration_scale": 3.0},
    {"scenario": "tiny"},
    {"scenario": "tiny", "seed": 1},
    {"scenario": "tiny", "fmt": "ros1"},
    {"scenario": "tiny", "fmt": "ros2"},
    {"scenario": "tiny-harsh"},
    {"scenario": "tiny-rgbd"},
    {"scenario": "tiny-day1"},
    {"scenario": "tiny-day2"},
    {"scenario": "tiny-day3"},
    {"scenario": "gen-tiny"},
    {"scenario": "gen-tiny", "seed": 2},
    {"scenario": "tiny-2d"},
    {"scenario": "tiny-2d", "fmt": "ros2"},
)


def cache_name(spec: dict[str, Any]) -> str:
    """A log's identity: its folder's name in the cache (the manifest's defaults filled in)."""
    from pipelines.regress.manifest import Simulate
    from pipelines.regress.runner import sim_folder

    return sim_folder(Path(), Simulate.model_validate(spec)).name


@functools.cache
def known() -> frozenset[str]:
    """The cache names of SIM_LOGS."""
    return frozenset(cache_name(s) for s in SIM_LOGS)


def ensure(spec: dict[str, Any]) -> tuple[str, float | None]:
    """Simulate one log into the cache unless it is there (locked against a concurrent run):
    its folder's name and the seconds it took, None when it was there."""
    from pipelines.regress.manifest import DEFAULT_SIM_CACHE, Simulate
    from pipelines.regress.runner import ensure_simulated, is_simulated, sim_folder

    sim = Simulate.model_validate(spec)
    start = time.perf_counter()
    if is_simulated(DEFAULT_SIM_CACHE, sim):
        return sim_folder(DEFAULT_SIM_CACHE, sim).name, None
    folder = ensure_simulated(DEFAULT_SIM_CACHE, sim)
    return folder.name, time.perf_counter() - start


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--workers", type=int, default=len(os.sched_getaffinity(0)),
                   help="logs simulated at once (default: the CPUs this process may use)")
    args = p.parse_args(argv)
    start = time.perf_counter()
    with ProcessPoolExecutor(max(1, args.workers)) as pool:
        made = [(name, s) for name, s in pool.map(ensure, SIM_LOGS) if s is not None]
    for name, seconds in made:
        print(f"simulated {name} in {seconds:.0f} s")
    print(f"{len(SIM_LOGS)} simulated test logs ready ({len(made)} made) in "
          f"{time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
