"""Cross-check mfmap's trajectory APE against evo (an independent implementation) on the same files.

    .venv/bin/python pipelines/crosscheck_evo.py EST.tum GT.tum [--max-diff 0.01]
    .venv/bin/python pipelines/crosscheck_evo.py            # a synthetic noisy pair, seeded

Prints both figures and their difference for: no alignment and SE(3) alignment, translation
RMSE (m) and rotation-angle RMSE (deg). Exit 1 when any differs by more than 1e-6.
"""

from __future__ import annotations

import argparse
import copy
import sys
import tempfile
from pathlib import Path

import numpy as np


def _synthetic(folder: Path) -> tuple[Path, Path]:
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(0)
    n = 4000
    t = 1.7e9 + 0.05 * np.arange(n)
    s = np.linspace(0, 6 * np.pi, n)
    xyz = np.stack([8 * np.cos(s), 5 * np.sin(s), 0.1 * s], axis=1)
    rot = Rotation.from_euler("zyx", np.stack([s, 0.05 * np.sin(3 * s), 0.03 * np.cos(s)], 1))
    idx = np.arange(0, n, 2)
    t_est = t[idx] + rng.uniform(-0.02, 0.02, len(idx))
    xyz_est = xyz[idx] + rng.normal(0, 0.05, (len(idx), 3)) + 0.0005 * np.arange(len(idx))[:, None]
    rot_est = Rotation.from_rotvec(rng.normal(0, 0.02, (len(idx), 3))) * rot[idx]
    paths = []
    for name, tt, p, r in (("est.tum", t_est, xyz_est, rot_est), ("gt.tum", t, xyz, rot)):
        rows = np.column_stack([tt, p, r.as_quat()])
        np.savetxt(folder / name, rows, fmt="%.9f")
        paths.append(folder / name)
    return paths[0], paths[1]


def main() -> int:
    from evo.core import metrics, sync
    from evo.tools import file_interface

    from mfmap.eval.io import read_tum
    from mfmap.eval.trajectory import ape_metrics, pose_errors

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("est", nargs="?", type=Path)
    parser.add_argument("gt", nargs="?", type=Path)
    parser.add_argument("--max-diff", type=float, default=0.01)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        est_path, gt_path = (args.est, args.gt) if args.est and args.gt else _synthetic(Path(tmp))
        ours = {
            align: ape_metrics(pose_errors(read_tum(est_path), read_tum(gt_path), args.max_diff, align))
            for align in ("none", "se3")
        }
        ref = file_interface.read_tum_trajectory_file(str(gt_path))
        est = file_interface.read_tum_trajectory_file(str(est_path))
        ref, est = sync.associate_trajectories(ref, est, max_diff=args.max_diff)
        aligned = copy.deepcopy(est)
        aligned.align(ref, correct_scale=False)

    def evo_rmse(relation: metrics.PoseRelation, traj: object) -> float:
        ape = metrics.APE(relation)
        ape.process_data((ref, traj))
        return float(ape.get_statistic(metrics.StatisticsType.rmse))

    worst = 0.0
    print(f"{'figure':<34}{'mfmap':>14}{'evo':>14}{'|diff|':>12}")
    for align, traj in (("none", est), ("se3", aligned)):
        for key, relation in (
            ("ape_rmse_m", metrics.PoseRelation.translation_part),
            ("rot_rmse_deg", metrics.PoseRelation.rotation_angle_deg),
        ):
            mine, theirs = ours[align][key], evo_rmse(relation, traj)
            worst = max(worst, abs(mine - theirs))
            print(f"{align + ' ' + key:<34}{mine:>14.9f}{theirs:>14.9f}{abs(mine - theirs):>12.2e}")
    print(f"pairs: mfmap {ours['none']['pairs']:.0f}, evo {ref.num_poses}; largest difference {worst:.2e}")
    return 0 if worst <= 1e-6 and ours["none"]["pairs"] == ref.num_poses else 1


if __name__ == "__main__":
    sys.exit(main())
