"""The build's floors against ground-truth floors (the multi-floor precision mapping paper, Tables 1 and 2)."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from mfmap.eval.io import FloorsFile, TransitionInfo, TumTrajectory
from mfmap.eval.trajectory import pose_at

# Each true transition with the estimated one matched to it, if any.
Matched = list[tuple[TransitionInfo, TransitionInfo | None]]


def match_floors(est: FloorsFile, gt: FloorsFile) -> dict[int, int]:
    """Estimated floor id -> ground-truth floor id, pairing by elevation (least total error)."""
    from scipy.optimize import linear_sum_assignment

    e_elev = np.array([f.elevation_m for f in est.floors])
    g_elev = np.array([f.elevation_m for f in gt.floors])
    cost = np.abs(e_elev[:, None] - g_elev[None, :])
    rows, cols = linear_sum_assignment(cost)
    return {est.floors[r].id: gt.floors[c].id for r, c in zip(rows, cols, strict=True)}


def _overlap(a0: float, a1: float, b0: float, b1: float) -> float:
    return max(0.0, min(a1, b1) - max(a0, b0))


def time_correct_share(est: FloorsFile, gt: FloorsFile, mapping: dict[int, int]) -> float | None:
    """Share of the ground-truth visit time during which the build is on the right floor."""
    total = sum(b - a for f in gt.floors for a, b in f.visits_s)
    if total <= 0:
        return None
    right = 0.0
    for ef in est.floors:
        gid = mapping.get(ef.id)
        if gid is None:
            continue
        gf = next(f for f in gt.floors if f.id == gid)
        right += sum(_overlap(a, b, c, d) for a, b in gf.visits_s for c, d in ef.visits_s)
    return right / total


def match_transitions(
    est: FloorsFile, gt: FloorsFile, mapping: dict[int, int], tolerance_s: float
) -> list[tuple[TransitionInfo, TransitionInfo | None]]:
    """Each ground-truth transition with the estimated one between the same floors nearest in time."""
    used: set[int] = set()
    out: list[tuple[TransitionInfo, TransitionInfo | None]] = []
    for g in gt.transitions:
        g_mid = (g.t_start_s + g.t_end_s) / 2
        best: tuple[float, int] | None = None
        for i, e in enumerate(est.transitions):
            if i in used or mapping.get(e.from_id) != g.from_id or mapping.get(e.to_id) != g.to_id:
                continue
            gap = abs((e.t_start_s + e.t_end_s) / 2 - g_mid)
            overlaps = _overlap(e.t_start_s, e.t_end_s, g.t_start_s, g.t_end_s) > 0
            if (overlaps or gap <= tolerance_s) and (best is None or gap < best[0]):
                best = (gap, i)
        if best is None:
            out.append((g, None))
        else:
            used.add(best[1])
            out.append((g, est.transitions[best[1]]))
    return out


def _wrap_deg(angle_rad: float) -> float:
    return math.degrees((angle_rad + math.pi) % (2 * math.pi) - math.pi)


@dataclass
class RideError:
    """One matched ride between adjacent floors, oriented lower floor -> upper floor."""

    lower: int
    upper: int
    kind: str
    t_start_s: float
    t_end_s: float
    dt_start_s: float | None
    dt_end_s: float | None
    dx_m: float | None = None
    dy_m: float | None = None
    dyaw_deg: float | None = None


@dataclass
class FloorsComparison:
    metrics: dict[str, float] = field(default_factory=dict)
    floors: list[dict[str, object]] = field(default_factory=list)
    pairs: list[dict[str, object]] = field(default_factory=list)
    rides: list[RideError] = field(default_factory=list)


def _ride_error(
    g: TransitionInfo,
    e: TransitionInfo,
    lower: int,
    est_traj: TumTrajectory | None,
    gt_traj: TumTrajectory | None,
) -> RideError:
    sign = 1.0 if g.from_id == lower else -1.0  # orient every ride lower -> upper
    ride = RideError(
        lower,
        g.to_id if g.from_id == lower else g.from_id,
        g.kind,
        g.t_start_s,
        g.t_end_s,
        e.t_start_s - g.t_start_s,
        e.t_end_s - g.t_end_s,
    )
    if est_traj is not None and gt_traj is not None:
        # Both trajectories at the ground-truth ride times: the same instants on both sides, so
        # a transition detected a little early or late does not count as a placement error.
        e0, eyaw0 = pose_at(est_traj, g.t_start_s)
        e1, eyaw1 = pose_at(est_traj, g.t_end_s)
        g0, gyaw0 = pose_at(gt_traj, g.t_start_s)
        g1, gyaw1 = pose_at(gt_traj, g.t_end_s)
        ride.dx_m = sign * float((e1[0] - e0[0]) - (g1[0] - g0[0]))
        ride.dy_m = sign * float((e1[1] - e0[1]) - (g1[1] - g0[1]))
        ride.dyaw_deg = sign * _wrap_deg((eyaw1 - eyaw0) - (gyaw1 - gyaw0))
    elif None not in (g.xy_start, g.xy_end, e.xy_start, e.xy_end):
        # Without trajectories: where each floors file says the ride started and ended.
        assert g.xy_start and g.xy_end and e.xy_start and e.xy_end
        ride.dx_m = sign * ((e.xy_end[0] - e.xy_start[0]) - (g.xy_end[0] - g.xy_start[0]))
        ride.dy_m = sign * ((e.xy_end[1] - e.xy_start[1]) - (g.xy_end[1] - g.xy_start[1]))
    return ride


def compare_floors(
    est: FloorsFile,
    gt: FloorsFile,
    tolerance_s: float,
    est_traj: TumTrajectory | None = None,
    gt_traj: TumTrajectory | None = None,
) -> FloorsComparison:
    """Floor count, time on the right floor, elevation errors, inter-floor errors at connectors."""
    out = FloorsComparison()
    m = out.metrics
    mapping = match_floors(est, gt)
    to_est = {g: e for e, g in mapping.items()}
    m["count_gt"] = float(len(gt.floors))
    m["count_est"] = float(len(est.floors))
    m["count_correct"] = float(len(gt.floors) == len(est.floors))
    m["count_error"] = float(abs(len(gt.floors) - len(est.floors)))
    m["unmatched_floors"] = float(len(gt.floors) - len(to_est))
    share = time_correct_share(est, gt, mapping)
    if share is not None:
        m["time_correct_share"] = share
        m["time_wrong_share"] = 1.0 - share

    _elevation_errors(out, est, gt, to_est)
    matched = match_transitions(est, gt, mapping, tolerance_s)
    _transition_errors(m, est, gt, matched)
    _inter_floor_errors(out, est, gt, matched, to_est, est_traj, gt_traj)
    return out


def _elevation_errors(out: FloorsComparison, est: FloorsFile, gt: FloorsFile, to_est: dict[int, int]) -> None:
    """Each true floor's row and its matched floor's elevation error."""
    m = out.metrics
    errors: list[float] = []
    for gf in gt.floors:
        row: dict[str, object] = {"id": gf.id, "gt_elevation_m": gf.elevation_m}
        eid = to_est.get(gf.id)
        if eid is not None:
            signed = est.elevation(eid) - gf.elevation_m
            row.update({"est_id": eid, "est_elevation_m": est.elevation(eid), "error_m": signed})
            m[f"floor{gf.id}.elevation_error_m"] = abs(signed)
            errors.append(signed)
        out.floors.append(row)
    if errors:
        m["elevation_error_max_m"] = float(np.max(np.abs(errors)))
        m["elevation_error_rmse_m"] = float(np.sqrt(np.mean(np.square(errors))))


def _transition_errors(m: dict[str, float], est: FloorsFile, gt: FloorsFile, matched: Matched) -> None:
    """Missed and extra transitions, and the largest start or end time error of the matched."""
    m["transitions_gt"] = float(len(gt.transitions))
    m["transitions_missed"] = float(sum(e is None for _, e in matched))
    m["transitions_extra"] = float(len(est.transitions) - sum(e is not None for _, e in matched))
    dts = [
        abs(d)
        for g, e in matched
        if e is not None
        for d in (e.t_start_s - g.t_start_s, e.t_end_s - g.t_end_s)
    ]
    if dts:
        m["transition_time_error_max_s"] = float(max(dts))


def _inter_floor_errors(
    out: FloorsComparison,
    est: FloorsFile,
    gt: FloorsFile,
    matched: Matched,
    to_est: dict[int, int],
    est_traj: TumTrajectory | None,
    gt_traj: TumTrajectory | None,
) -> None:
    """Per pair of adjacent true floors: the rides' plan errors and the height error between them."""
    m = out.metrics
    order = sorted(gt.floors, key=lambda f: f.elevation_m)
    sums: dict[str, list[float]] = {"dx_m": [], "dy_m": [], "dyaw_deg": [], "dz_m": [], "dz_pct": []}
    for lo, hi in itertools.pairwise(order):
        name = f"inter{lo.id}_{hi.id}"
        pair: dict[str, object] = {"lower": lo.id, "upper": hi.id}
        rides = [
            _ride_error(g, e, lo.id, est_traj, gt_traj)
            for g, e in matched
            if e is not None and {g.from_id, g.to_id} == {lo.id, hi.id}
        ]
        out.rides += rides
        pair["rides"] = len(rides)
        for key in ("dx_m", "dy_m", "dyaw_deg"):
            values = [abs(v) for r in rides if (v := getattr(r, key)) is not None]
            if values:
                m[f"{name}.{key}"] = float(np.mean(values))
                pair[key] = m[f"{name}.{key}"]
                sums[key].append(m[f"{name}.{key}"])
        if lo.id in to_est and hi.id in to_est:
            gt_dz = hi.elevation_m - lo.elevation_m
            est_dz = est.elevation(to_est[hi.id]) - est.elevation(to_est[lo.id])
            m[f"{name}.dz_m"] = abs(est_dz - gt_dz)
            pair.update({"gt_dz_m": gt_dz, "est_dz_m": est_dz, "dz_m": m[f"{name}.dz_m"]})
            sums["dz_m"].append(m[f"{name}.dz_m"])
            if abs(gt_dz) > 0:
                m[f"{name}.dz_pct"] = 100.0 * abs(est_dz - gt_dz) / abs(gt_dz)
                pair["dz_pct"] = m[f"{name}.dz_pct"]
                sums["dz_pct"].append(m[f"{name}.dz_pct"])
        out.pairs.append(pair)
    for key, values in sums.items():
        if values:
            m[f"inter.{key}"] = float(np.mean(values))
