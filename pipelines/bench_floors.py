"""Speed of the floors stage: segment a 1-hour, 50 Hz barometer trace (180,000 samples).

The trace is a synthetic walk over five floors by elevator and stairs with 200 Pa/h drift,
door/HVAC steps and spikes. Prints wall time per run (best and median of --repeat), samples per
second, peak memory, and the sliding-mean baseline's time for comparison.

    .venv/bin/python pipelines/bench_floors.py [--hours 1] [--rate 50] [--repeat 5]
"""

from __future__ import annotations

import argparse
import resource
import statistics
import time

from mfmap.floors.config import FilterConfig, FilterMethod, FloorsConfig
from mfmap.floors.segment import segment_pressure
from mfmap.sim.traces import Leg, synthetic_trace


def hour_walk(hours: float) -> list[Leg]:
    """Stays of 2-4 minutes between rides and climbs, cycling over five floors."""
    legs: list[Leg] = []
    total_s = 0.0
    k = 0
    pattern = [("elevator", 4.0), ("stairs", 4.0), ("elevator", 8.0), ("stairs", -4.0), ("elevator", -12.0), ("elevator", 4.0)]
    while total_s < hours * 3600.0 - 300.0:
        stay = 120.0 + 60.0 * (k % 3)
        kind, dh = pattern[k % len(pattern)]
        legs += [Leg("stay", stay), Leg(kind, height_change_m=dh, speed_m_s=0.35)]
        total_s += stay + (abs(dh) / 0.35 if kind == "stairs" else 10.0)
        k += 1
    legs.append(Leg("stay", max(60.0, hours * 3600.0 - total_s)))
    return legs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--hours", type=float, default=1.0)
    parser.add_argument("--rate", type=float, default=50.0)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    trace = synthetic_trace(
        hour_walk(args.hours), rate_hz=args.rate, drift_pa_per_h=200.0, transients=40, spikes=200, seed=0
    )
    n = len(trace.pressure)
    print(f"trace: {n} samples, {trace.times_s[-1] / 3600:.2f} h at {args.rate:g} Hz, "
          f"{len(trace.transitions)} floor changes, {len(trace.elevations)} floors")
    for method in (FilterMethod.RTS, FilterMethod.SLIDING_MEAN):
        cfg = FloorsConfig(filter=FilterConfig(method=method))
        times = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            seg = segment_pressure(trace.pressure, None, cfg)
            times.append(time.perf_counter() - t0)
        best, med = min(times), statistics.median(times)
        print(f"{method.value:12s}: best {best:.3f} s, median {med:.3f} s ({n / med / 1e6:.2f} M samples/s); "
              f"found {len(seg.floors)} floors, {len(seg.transitions)} transitions")
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak RSS of this process: {peak_mb:.0f} MB")


if __name__ == "__main__":
    main()
