"""How often an elevator ride's IMU height is within 1 cm, per accelerometer noise density.

    python -m pipelines.ride_noise pipelines/manifests/stress.yaml [--draws 200]
        [--densities 300,230,150,100,70] [--seed 0]

Every elevator ride of the manifest's simulated logs (its route rebuilt from the scenario and
seed, no log written) is replayed through `mfmap.graph.ride.ride_height` with the simulator's
noise-free specific force and turn rate at the IMU, a fresh constant bias per draw (as the
simulator draws one per log) and fresh white noise of each density. The estimator sees nothing
else, so what it misses is the accelerometer's noise, not the log's other sensors or the
floors stage's timing (the ride is searched around the truth's span).

Noise density is a datasheet's (one-sided): the per-sample sigma is the density times the square
root of the bandwidth, half the sample rate. The simulator's accelerometer, 0.03 m/s^2 per sample
at 200 Hz, is 306 ug/sqrt(Hz) (Kalibr's `accelerometer_noise_density`, the continuous-time
sigma, is this over sqrt(2)).

Prints, per density: the share of (ride, draw) pairs within 1 cm, the RMS and the 95th
percentile of the error, and per ride the RMS at each density.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mfmap.graph.ride import STANDARD_GRAVITY_M_S2, ride_height
from mfmap.sim.run import scenario_route, start_stamp_ns
from mfmap.sim.scenarios import SCENARIOS
from mfmap.sim.sensors import Imu, Kinematics
from mfmap.sim.trajectory import DT_S
from mfmap.types import ImuSeries
from pipelines.height_figures import RIDE_BAR_M
from pipelines.regress.manifest import ManifestError, load_manifest

# Stand-still kept either side of the truth's ride span (the estimator looks 1.5 s beyond it,
# plus its pad and stand-still windows).
MARGIN_S = 5.0


@dataclass(frozen=True)
class Ride:
    """One elevator ride of a log: its name, true height change and the noise-free IMU."""

    name: str
    height_change_m: float
    stamp_ns: np.ndarray
    specific_force: np.ndarray
    gyro: np.ndarray
    start_ns: int
    end_ns: int


def rides_of(scenario: str, seed: int, duration_scale: float, log: str) -> list[Ride]:
    """The elevator rides of one simulated log, rebuilt from its scenario and seed."""
    _, log_seed, traj = scenario_route(SCENARIOS[scenario], seed, duration_scale)
    t0_ns = start_stamp_ns(log_seed)
    out = []
    for k, tr in enumerate(t for t in traj.transitions if t.kind == "elevator"):
        i0 = max(0, int((tr.t_start_s - MARGIN_S) / DT_S))
        i1 = min(len(traj.xyz), int((tr.t_end_s + MARGIN_S) / DT_S))
        kin = Kinematics.of(traj, i0, i1)
        stamps = t0_ns + np.round(np.arange(i0, i1) * DT_S * 1e9).astype(np.int64)
        out.append(Ride(f"{log} ride {k + 1} (building floors {tr.from_floor} -> {tr.to_floor})", tr.height_change_m,
                        stamps, kin.specific_force, kin.gyro,
                        t0_ns + int(tr.t_start_s * 1e9), t0_ns + int(tr.t_end_s * 1e9)))
    return out


def ride_errors(ride: Ride, density_ug: float, draws: int, rng: np.random.Generator) -> np.ndarray:
    """The IMU height's error (m) over `draws` noise draws at `density_ug` (NaN when skipped)."""
    n = ride.stamp_ns.shape[0]
    sigma = density_ug * 1e-6 * STANDARD_GRAVITY_M_S2 * math.sqrt(0.5 / DT_S)
    nan = np.full((n, 4), np.nan)
    errors = np.empty(draws)
    for d in range(draws):
        acc = ride.specific_force + rng.normal(0, Imu.ACCEL_BIAS_M_S2, 3) + rng.normal(0, sigma, (n, 3))
        gyro = ride.gyro + rng.normal(0, Imu.GYRO_NOISE_RAD_S, (n, 3))
        found = ride_height(ImuSeries(ride.stamp_ns, gyro, acc, nan), ride.start_ns, ride.end_ns)
        h = found.height_change_m
        errors[d] = np.nan if h is None else h - ride.height_change_m
    return errors


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("manifest", type=Path)
    p.add_argument("--draws", type=int, default=200, help="noise draws per ride and density")
    p.add_argument("--densities", default="300,230,150,100,70",
                   help="accelerometer noise densities, ug/sqrt(Hz), comma-separated")
    p.add_argument("--seed", type=int, default=0, help="seed of the noise draws")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    densities = [float(x) for x in args.densities.split(",")]
    try:
        logs = load_manifest(args.manifest, check=False).logs
    except ManifestError as err:
        print(err, file=sys.stderr)
        return 2
    rides: list[Ride] = []
    for log in logs:
        if log.simulate is not None:
            sim = log.simulate
            if sim.scenario not in SCENARIOS:
                print(f"{args.manifest}: log '{log.name}': unknown scenario '{sim.scenario}'", file=sys.stderr)
                return 2
            rides += rides_of(sim.scenario, sim.seed, sim.duration_scale, log.name)
    if not rides:
        print(f"{args.manifest}: no simulated elevator rides", file=sys.stderr)
        return 1
    rng = np.random.default_rng(args.seed)
    table = {d: [ride_errors(r, d, args.draws, rng) for r in rides] for d in densities}
    print(f"{len(rides)} rides, {args.draws} noise draws each (simulator: "
          f"{Imu.ACCEL_NOISE_M_S2 / math.sqrt(0.5 / DT_S) / STANDARD_GRAVITY_M_S2 * 1e6:.0f} ug/sqrt(Hz))\n")
    print("| noise density (ug/sqrt(Hz)) | within 1 cm | RMS (cm) | 95th percentile (cm) | skipped |")
    print("|---|---|---|---|---|")
    for d in densities:
        e = np.concatenate(table[d])
        ok = e[np.isfinite(e)]
        print(f"| {d:.0f} | {np.mean(np.abs(ok) <= RIDE_BAR_M):.0%} | {100 * math.sqrt(np.mean(ok**2)):.2f} "
              f"| {100 * np.percentile(np.abs(ok), 95):.2f} | {e.shape[0] - ok.shape[0]} |")
    print("\n| ride | true change (m) | " + " | ".join(f"RMS at {d:.0f} (cm)" for d in densities) + " |")
    print("|---|---|" + "---|" * len(densities))
    for k, r in enumerate(rides):
        cells = " | ".join(f"{100 * math.sqrt(np.nanmean(table[d][k] ** 2)):.2f}" for d in densities)
        print(f"| {r.name} | {r.height_change_m:+.2f} | {cells} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
