"""How well a build stacks its floors: each floor's trajectory fitted to the truth on its own.

    python pipelines/floor_stack.py BUILD_DIR SIM_DIR

Per floor, the 2D rigid fit (x, y, yaw; Umeyama without scale) of the build's trajectory on that
floor to the ground truth at the same times; between adjacent floors, how far the two fits
disagree (translation at the upper floor's centroid, yaw). A map whose floors sit exactly above
each other has the same fit on every floor, whatever each floor's own drift: this is the multi-floor precision mapping paper's
inter-floor x, y, yaw error, where `mfmap eval`'s floors.inter* measure it across each ride.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
from pathlib import Path

import numpy as np


def _tum(path: Path) -> tuple[np.ndarray, np.ndarray]:
    data = np.loadtxt(path, ndmin=2)
    return data[:, 0], data[:, 1:4]


def _fit_2d(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and translation taking src (N, 2) onto dst (N, 2), least squares."""
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    u, _, vt = np.linalg.svd((dst - mu_d).T @ (src - mu_s))
    d = np.diag([1.0, np.sign(np.linalg.det(u @ vt))])
    rot = u @ d @ vt
    return rot, mu_d - rot @ mu_s


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("build", type=Path)
    parser.add_argument("sim", type=Path)
    args = parser.parse_args()
    t_est, xyz_est = _tum(args.build / "trajectory.tum")
    t_gt, xyz_gt = _tum(args.sim / "gt_trajectory.tum")
    floors = json.loads((args.sim / "gt_floors.json").read_text())["floors"]
    fits = {}
    for floor in sorted(floors, key=lambda f: f["elevation_m"]):
        on = np.zeros(len(t_est), dtype=bool)
        for t0, t1 in floor["visits"]:
            on |= (t_est >= t0) & (t_est <= t1)
        idx = np.clip(np.searchsorted(t_gt, t_est[on]), 0, len(t_gt) - 1)
        close = np.abs(t_gt[idx] - t_est[on]) < 0.01
        est, gt = xyz_est[on][close, :2], xyz_gt[idx[close], :2]
        rot, trans = _fit_2d(est, gt)
        rms = float(np.sqrt(np.mean(np.sum((est @ rot.T + trans - gt) ** 2, axis=1))))
        fits[floor["id"]] = (rot, trans, est.mean(axis=0))
        print(f"floor {floor['id']}: {len(est)} poses, fit residual RMS {100 * rms:.1f} cm")
    ids = list(fits)
    for lower, upper in itertools.pairwise(ids):
        (r0, t0, _), (r1, t1, centre) = fits[lower], fits[upper]
        d = (r1 @ centre + t1) - (r0 @ centre + t0)
        dyaw = math.degrees(math.atan2(r1[1, 0], r1[0, 0]) - math.atan2(r0[1, 0], r0[0, 0]))
        print(f"floors {lower}-{upper}: dx {100 * abs(d[0]):.1f} cm, dy {100 * abs(d[1]):.1f} cm, "
              f"dyaw {abs(dyaw):.3f} deg")


if __name__ == "__main__":
    main()
