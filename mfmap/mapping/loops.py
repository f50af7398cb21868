"""Loop closure on one floor: candidates by position and by a place descriptor, verified by ICP.

The descriptor is a polar occupancy histogram of the keyframe cloud in its own base frame
(Scan Context with point counts in a height band instead of max height, since indoor ceilings
make max height uninformative). It does not depend on the drifted pose, so it finds revisits
whose pose estimates have drifted apart; the column shift of the best match gives a yaw guess.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from mfmap.mapping.config import MappingConfig
from mfmap.mapping.geometry import inverse, yaw_pose, yaw_rad
from mfmap.mapping.registration import (
    IcpTarget,
    Registration,
    downsample,
    icp,
    information,
    to_o3d,
)
from mfmap.mapping.scan2d import Map2D, grid_downsample_2d, icp_2d
from mfmap.types import F32, F64, EdgeKind, Keyframe, PoseEdge

RINGS = 20
SECTORS = 60
MAX_RADIUS_M = 20.0
BAND_M = (0.2, 2.2)  # height band above the base that walls and furniture occupy


def place_descriptor(cloud_base: F32 | F64) -> F64:
    """(RINGS, SECTORS) polar histogram of points in the height band, each column normalised."""
    pts = np.asarray(cloud_base, dtype=np.float64)
    keep = (pts[:, 2] > BAND_M[0]) & (pts[:, 2] < BAND_M[1])
    pts = pts[keep]
    radius = np.hypot(pts[:, 0], pts[:, 1])
    inside = radius < MAX_RADIUS_M
    pts, radius = pts[inside], radius[inside]
    ring = np.minimum((radius / MAX_RADIUS_M * RINGS).astype(int), RINGS - 1)
    angle = np.arctan2(pts[:, 1], pts[:, 0]) + np.pi
    sector = np.minimum((angle / (2 * np.pi) * SECTORS).astype(int), SECTORS - 1)
    desc = np.zeros((RINGS, SECTORS))
    np.add.at(desc, (ring, sector), 1.0)
    return np.log1p(desc)


def ring_key(desc: F64) -> F64:
    return desc.mean(axis=1)


def descriptor_distance(a: F64, b: F64) -> tuple[float, int]:
    """Scan Context distance (1 - mean column cosine) minimised over yaw shifts; (dist, shift).

    All shifts at once: column j of b rolled by s is column (j - s) mod SECTORS of b, so one
    matrix product holds every column pair's dot product.
    """
    sectors = a.shape[1]
    norm_a = np.linalg.norm(a, axis=0)
    norm_b = np.linalg.norm(b, axis=0)
    source = (np.arange(sectors)[None, :] - np.arange(sectors)[:, None]) % sectors  # [shift, j]
    columns = np.arange(sectors)[None, :]
    dots = (a.T @ b)[columns, source]
    norm_rolled = norm_b[source]
    valid = (norm_a[None, :] > 0) & (norm_rolled > 0)
    count = valid.sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        cos = np.where(valid, dots / (norm_a[None, :] * norm_rolled), 0.0)
        dist = 1.0 - cos.sum(axis=1) / count
    dist = np.where(count >= sectors // 4, dist, np.inf)
    shift = int(np.argmin(dist))  # the first of equal minima, as a scan over shifts finds
    if not dist[shift] < 2.0:
        return 2.0, 0
    return float(dist[shift]), shift


def plane_fit(source: F64, target: IcpTarget, transform: F64,
              max_distance_m: float) -> tuple[float, float]:
    """(share of source points near the target, point-to-plane RMSE of those points).

    Point-to-plane, because with a sparse 16-beam lidar point-to-point distances are dominated
    by the gaps between rings, not by misalignment.
    """
    src = source @ transform[:3, :3].T + transform[:3, 3]
    found, idx, _ = target.nearest(src, max_distance_m)
    if len(found) == 0:
        return 0.0, float("inf")
    residual = ((src[found] - target.points[idx]) * target.normals[idx]).sum(axis=1)
    return len(found) / len(src), float(np.sqrt(np.mean(residual**2)))


def line_fit(source: F64, target: Map2D, x: float, y: float, yaw: float,
             max_distance_m: float) -> tuple[float, float, F64]:
    """(share of source points near a target line, their point-to-line RMSE, the 3x3
    information of x, y, yaw those lines give) of the 2D pose (x, y, yaw)."""
    assert target.tree is not None
    c, s = np.cos(yaw), np.sin(yaw)
    moved = source @ np.array([[c, s], [-s, c]]) + [x, y]
    dist, idx = target.tree.query(moved, distance_upper_bound=max_distance_m)
    ok = np.isfinite(dist)
    if not ok.any():
        return 0.0, float("inf"), np.zeros((3, 3))
    n = target.normals[idx[ok]]
    residual = ((moved[ok] - target.points[idx[ok]]) * n).sum(axis=1)
    p = source[ok]
    drot = np.stack([-s * p[:, 0] - c * p[:, 1], c * p[:, 0] - s * p[:, 1]], axis=1)
    jac = np.stack([n[:, 0], n[:, 1], (drot * n).sum(axis=1)], axis=1)
    return float(ok.mean()), float(np.sqrt(np.mean(residual**2))), jac.T @ jac


@dataclass
class LoopStats:
    candidates: int = 0
    accepted: int = 0
    rejected_fitness: int = 0
    rejected_ambiguous: int = 0
    rejected_degenerate: int = 0
    rejected_implausible: int = 0
    rejected_one_way: int = 0


@dataclass(frozen=True)
class LoopCheck:
    accepted: bool
    reason: str
    registration: Registration | None


class LoopCloser:
    """Keeps the keyframes of every floor and proposes verified loop edges, same floor only."""

    def __init__(self, cfg: MappingConfig, group_of: Callable[[Keyframe], int] | None = None,
                 planar: bool = False) -> None:
        """`group_of`: only keyframes of another group are candidates (the parallel chunks' merge,
        whose workers searched the loops within each chunk). `planar`: the keyframes are 2D
        scans (one plane of points), verified by a fit in the plane (`verify_2d`)."""
        self.cfg = cfg
        self.group_of = group_of
        self.planar = planar
        self.stats = LoopStats()
        self._keyframes: dict[int, Keyframe] = {}
        self._desc: dict[int, F64] = {}
        self._keys: dict[int, F64] = {}
        self._rng = np.random.default_rng(cfg.seed)

    def add(self, kf: Keyframe) -> list[PoseEdge]:
        """Register a new keyframe; return the verified loop edges it closes."""
        desc = place_descriptor(kf.cloud)
        edges: list[PoseEdge] = []
        if self.cfg.loops.closure:
            for other_id, guess in self._candidates(kf, desc):
                self.stats.candidates += 1
                verify = self.verify_2d if self.planar else self.verify
                check = verify(self.submap(other_id), kf.cloud, guess)
                if check.accepted and check.registration is not None:
                    # Repeating structure (pillars, doors) aliases by metres; drift does not.
                    odom_rel = inverse(self._keyframes[other_id].pose) @ kf.pose
                    moved = inverse(odom_rel) @ check.registration.transform
                    if float(np.linalg.norm(moved[:3, 3])) > self.cfg.loops.max_correction_m:
                        self.stats.rejected_implausible += 1
                        continue
                    if self.cfg.loops.both_ways and not self._holds_both_ways(
                            other_id, kf, guess, check.registration.transform):
                        self.stats.rejected_one_way += 1
                        continue
                    self.stats.accepted += 1
                    edges.append(self._edge(other_id, kf.id, check.registration))
                    break
                self._count_rejection(check.reason)
        self._keyframes[kf.id] = kf
        self._desc[kf.id] = desc
        self._keys[kf.id] = ring_key(desc)
        return edges

    def _holds_both_ways(self, other_id: int, kf: Keyframe, guess: F64, found: F64) -> bool:
        """Whether the other keyframe's scan, registered the other way round (into the submap
        of kf and the keyframes before it) from the same `guess`, passes the same checks and
        lands within `loops.agreement_m` of `found` (kf in the other's frame). From `found`
        instead, it stayed in the forward fit's minimum.

        Where one place saw furniture the other did not (occluded from where it stood), the
        surplus points pull a point-to-plane fit along the walls they lie near, and the fit
        passes every check one way: on the stress set's stair logs, loops from a turn in place
        to a keyframe 2 m away came out 3-11 cm and 0.3-0.8 deg off, a few sigma, and bent
        the start floor by 2-3 cm. Registered the other way round, the surplus is in the
        target, where nothing pulls on it: those loops failed the overlap check or landed
        2.4-10 cm apart, while 154 right loops (four logs) agreed within 2.9 mm RMS, 1.4 cm
        at worst.
        """
        verify = self.verify_2d if self.planar else self.verify
        back = verify(self.submap(kf.id, kf), self._keyframes[other_id].cloud, inverse(guess))
        if not back.accepted or back.registration is None:
            return False
        apart = float(np.linalg.norm((found @ back.registration.transform)[:3, 3]))
        return apart <= self.cfg.loops.agreement_m

    def submap(self, center_id: int, newest: Keyframe | None = None) -> F64:
        """The keyframe's cloud plus its neighbours of the same visit, in its frame
        (`newest`: a keyframe not yet kept, among them).

        A single sparse scan gives a loop a rotation error of several tenths of a degree;
        a few neighbours (placed by the locally accurate odometry) make the target dense.
        """
        def kept(k: int) -> Keyframe | None:
            return newest if newest is not None and k == newest.id else self._keyframes.get(k)

        center = kept(center_id)
        assert center is not None
        to_center = inverse(center.pose)
        parts = []
        for k in range(center_id - self.cfg.loops.submap_keyframes,
                       center_id + self.cfg.loops.submap_keyframes + 1):
            other = kept(k)
            if other is None or other.visit != center.visit:
                continue
            rel = to_center @ other.pose
            parts.append(np.asarray(other.cloud, dtype=np.float64) @ rel[:3, :3].T + rel[:3, 3])
        return np.concatenate(parts)

    def _count_rejection(self, reason: str) -> None:
        if reason == "fitness":
            self.stats.rejected_fitness += 1
        elif reason == "ambiguous":
            self.stats.rejected_ambiguous += 1
        elif reason == "degenerate":
            self.stats.rejected_degenerate += 1

    def _candidates(self, kf: Keyframe, desc: F64) -> list[tuple[int, F64]]:
        """(keyframe id, initial guess of kf in that keyframe's frame), best first."""
        same_floor = [
            other for other in self._keyframes.values()
            if other.floor_id == kf.floor_id  # never propose a loop between floors
            and (other.visit != kf.visit or kf.id - other.id >= self.cfg.loops.min_separation)
            and (self.group_of is None or self.group_of(other) != self.group_of(kf))
        ]
        if not same_floor:
            return []
        out: list[tuple[int, F64]] = []
        seen: set[int] = set()
        dists = [(float(np.linalg.norm(o.pose[:2, 3] - kf.pose[:2, 3])), o) for o in same_floor]
        dists.sort(key=lambda d: d[0])
        for dist, other in dists[: self.cfg.loops.max_candidates]:
            if dist > self.cfg.loops.radius_m:
                break
            out.append((other.id, inverse(other.pose) @ kf.pose))
            seen.add(other.id)
        key = ring_key(desc)
        by_key = sorted(same_floor, key=lambda o: float(np.linalg.norm(self._keys[o.id] - key)))
        for other in by_key[: 2 * self.cfg.loops.max_candidates]:
            if other.id in seen:
                continue
            dist, shift = descriptor_distance(self._desc[other.id], desc)
            if dist > self.cfg.loops.descriptor_threshold:
                continue
            # kf's sector s matches the other's sector s + shift: kf is yawed by +shift sectors.
            yaw = shift * 2 * np.pi / SECTORS
            out.append((other.id, yaw_pose(yaw)))
            seen.add(other.id)
        return out[: 2 * self.cfg.loops.max_candidates]

    def verify(self, target_points: F32 | F64, source_points: F32 | F64, guess: F64) -> LoopCheck:
        """Align source to target from guess; accept only a good, unambiguous, well-posed match."""
        coarse_voxel, fine_voxel = 0.5, 0.2
        src_c = downsample(source_points, coarse_voxel)
        tgt_c = IcpTarget.estimate(downsample(target_points, coarse_voxel), 3 * coarse_voxel)
        src_f = downsample(source_points, fine_voxel)
        tgt_f = IcpTarget.estimate(downsample(target_points, fine_voxel), 3 * fine_voxel)

        def align(start: F64) -> Registration:
            coarse = icp(src_c, tgt_c, start, 3 * coarse_voxel, coarse_voxel, 40)
            return icp(src_f, tgt_f, coarse.transform, 2 * fine_voxel, fine_voxel, 40)

        best = align(guess)
        if self.cfg.icp.fine_kernel_m > 0:
            # A kernel at the lidar's noise: loops 2-5 m apart went from 1.9-2.3 to 0.5 cm RMS.
            best = icp(src_f, tgt_f, best.transform, 2 * fine_voxel, self.cfg.icp.fine_kernel_m, 40)
        check_distance = 0.25
        fitness, rmse = plane_fit(src_f, tgt_f, best.transform, check_distance)
        result = Registration(best.transform, fitness, rmse)
        if fitness < self.cfg.loops.min_fitness or rmse > self.cfg.loops.max_rmse_m:
            return LoopCheck(False, "fitness", result)
        # Unambiguous: starts perturbed by half a metre and 10 degrees must land on the same answer.
        for _ in range(3):
            offset = yaw_pose(float(self._rng.uniform(-0.17, 0.17)),
                              np.r_[self._rng.uniform(-0.5, 0.5, 2), 0.0])
            other = align(best.transform @ offset)
            moved = float(np.linalg.norm(other.transform[:3, 3] - best.transform[:3, 3]))
            if moved > self.cfg.loops.ambiguity_m:
                return LoopCheck(False, "ambiguous", result)
        info = information(to_o3d(src_f), tgt_f.cloud, check_distance, best.transform)
        eig = np.linalg.eigvalsh(info[3:, 3:])
        if eig[0] <= 0 or eig[0] / eig[-1] < self.cfg.loops.min_information_ratio:
            return LoopCheck(False, "degenerate", result)
        return LoopCheck(True, "ok", result)

    def verify_2d(self, target_points: F32 | F64, source_points: F32 | F64, guess: F64) -> LoopCheck:
        """`verify` for 2D scans: point-to-line ICP in the plane (x, y, yaw), the same gates.

        A 3D point-to-plane fit has nothing to hold on a flat cloud: every normal is vertical,
        and x, y and yaw are unobservable. The lines of the target (its points with a clear
        direction) give the fit, its overlap and RMSE, and the degeneracy check: in a corridor
        the translation along the walls is unconstrained, its information near zero.
        """
        coarse_m, fine_m = 0.1, 0.05
        target = Map2D(fine_m, 1)
        target.add(np.asarray(target_points, dtype=np.float64)[:, :2])
        source = grid_downsample_2d(np.asarray(source_points, dtype=np.float64)[:, :2], fine_m)
        yaw0 = yaw_rad(guess)
        if target.tree is None or len(source) < 10:
            return LoopCheck(False, "fitness", None)

        def align(x: float, y: float, yaw: float) -> tuple[float, float, float]:
            x, y, yaw, _, _ = icp_2d(source, target, x, y, yaw, 10 * coarse_m, 40)
            x, y, yaw, _, _ = icp_2d(source, target, x, y, yaw, 4 * fine_m, 40)
            if self.cfg.icp.fine_kernel_m > 0:
                x, y, yaw, _, _ = icp_2d(source, target, x, y, yaw, 4 * fine_m, 40,
                                         self.cfg.icp.fine_kernel_m)
            return x, y, yaw

        x, y, yaw = align(float(guess[0, 3]), float(guess[1, 3]), yaw0)
        check_distance = 0.25
        fitness, rmse, info = line_fit(source, target, x, y, yaw, check_distance)
        result = Registration(yaw_pose(yaw, np.array([x, y, 0.0])), fitness, rmse)
        if fitness < self.cfg.loops.min_fitness or rmse > self.cfg.loops.max_rmse_m:
            return LoopCheck(False, "fitness", result)
        for _ in range(3):
            dyaw = float(self._rng.uniform(-0.17, 0.17))
            dx, dy = self._rng.uniform(-0.5, 0.5, 2)
            ox, oy, _ = align(x + float(dx), y + float(dy), yaw + dyaw)
            if float(np.hypot(ox - x, oy - y)) > self.cfg.loops.ambiguity_m:
                return LoopCheck(False, "ambiguous", result)
        eig = np.linalg.eigvalsh(info[:2, :2])
        if eig[0] <= 0 or eig[0] / eig[-1] < self.cfg.loops.min_information_ratio:
            return LoopCheck(False, "degenerate", result)
        return LoopCheck(True, "ok", result)

    def _edge(self, i: int, j: int, result: Registration) -> PoseEdge:
        # Far apart, the two clouds overlap less and ICP settles off by more (see the config).
        grow = 1.0 + self.cfg.loops.sigma_growth_per_m * float(np.linalg.norm(result.transform[:3, 3]))
        sig_r = np.radians(self.cfg.loops.sigma_deg) * grow
        sig_t = self.cfg.loops.sigma_m * grow
        info = np.diag([1 / sig_r**2] * 3 + [1 / sig_t**2] * 3)
        return PoseEdge(i, j, result.transform, info, EdgeKind.LOOP, result.fitness)
