"""Factors that hold the floors together: each floor's level, adjacent floors registered on
each other, and weak bridges where nothing else connects two parts of the graph."""

from __future__ import annotations

import functools
import itertools
import logging
import math
from collections.abc import Sequence
from concurrent.futures import Executor
from typing import Any

import gtsam
import numpy as np

from mfmap.floors.nobaro import by_visit
from mfmap.graph.config import GraphConfig
from mfmap.graph.factors import (
    FREE_SIGMA,
    LEVEL_KPA,
    LOOSE_TILT_RAD,
    Builder,
    Fl,
    X,
    relative_level,
    robust_model,
)
from mfmap.graph.interfloor import FloorMatch, register_floors
from mfmap.types import F64, Keyframe

logger = logging.getLogger(__name__)

ABOVE_M = 2.0  # an inter-floor anchor pair's keyframes lie this close in x, y or closer
MIN_PAIRS = 3
SHORT_VISIT = 6  # keyframes: a visit this short gives no inter-floor anchor pair
VISIT_END = 2  # keyframes at each end of a visit (in and at the cabin) given none either


def floor_points(
    keyframes: Sequence[Keyframe],
    poses: dict[int, F64],
    floor_id: int,
    band_m: tuple[float, float],
    floor_z_m: float,
) -> np.ndarray:
    """World points of a floor's keyframes within a height band, z made floor-relative."""
    return floor_points_seen(keyframes, poses, floor_id, band_m, floor_z_m)[0]


def floor_points_seen(
    keyframes: Sequence[Keyframe],
    poses: dict[int, F64],
    floor_id: int,
    band_m: tuple[float, float],
    floor_z_m: float,
) -> tuple[np.ndarray, np.ndarray]:
    """`floor_points`, and per point the direction it was seen from (towards its keyframe's
    base): the side of a wall the robot stood on."""
    chunks, views = [], []
    for kf in keyframes:
        if kf.floor_id != floor_id or len(kf.cloud) == 0:
            continue
        pose = poses[kf.id]
        pts = kf.cloud.astype(np.float64) @ pose[:3, :3].T + pose[:3, 3]
        rel = pts[:, 2] - floor_z_m
        keep = (rel >= band_m[0]) & (rel <= band_m[1])
        sel = pts[keep]
        views.append(pose[:3, 3] - sel)
        sel[:, 2] -= floor_z_m
        chunks.append(sel)
    if not chunks:
        return np.zeros((0, 3)), np.zeros((0, 3))
    return np.concatenate(chunks), np.concatenate(views)


def median_floor_z(keyframes: Sequence[Keyframe], poses: dict[int, F64]) -> dict[int, float]:
    by_floor: dict[int, list[float]] = {}
    for kf in keyframes:
        if kf.floor_id >= 0:
            by_floor.setdefault(kf.floor_id, []).append(float(poses[kf.id][2, 3]))
    return {f: float(np.median(z)) for f, z in sorted(by_floor.items())}


def _components(ids: list[int], links: list[tuple[int, int]]) -> dict[int, int]:
    parent = {i: i for i in ids}

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for a, b in links:
        if a in parent and b in parent:
            ra, rb = find(a), find(b)
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
    return {i: find(i) for i in ids}


def add_height_ties(
    builder: Builder, values: Any, kfs: list[Keyframe], initial: dict[int, F64]
) -> None:
    """Every keyframe of a floor shares that floor's z: a floor level f<id> tied to each.

    A star, not a chain, so the tie does not let z wander from keyframe to keyframe. Each tie is
    a world-z factor (robust; LEVEL_KPA). A BetweenFactorPose3 with only z tight would measure z
    in the floor variable's frame, through SE(3)'s log that mixes rotation into translation: a
    keyframe's tilt times its distance from the floor variable (tens of metres) becomes
    centimetres of height (6 cm off their floor's level for the keyframes of the simulator's
    tiny-2d building).
    """
    sig = builder.config.heights.tie_sigma_m
    model = robust_model(builder.config, gtsam.noiseModel.Isotropic.Sigma(1, sig))
    for kf in kfs:
        if kf.floor_id < 0:
            continue
        if not values.exists(Fl(kf.floor_id)):
            values.insert(Fl(kf.floor_id), -float(initial[kf.id][2, 3]))
        builder.add("height_tie", gtsam.BarometricFactor(X(kf.id), Fl(kf.floor_id), LEVEL_KPA, model), np.eye(1) / sig)


def _visits(kfs: list[Keyframe], floor_id: int) -> list[list[Keyframe]]:
    return by_visit([k for k in kfs if k.floor_id == floor_id])


def _anchors(kfs: list[Keyframe], lower: int, upper: int) -> tuple[Keyframe, Keyframe]:
    """The middle keyframes of each floor's longest visit.

    The registration's correction is of the floors' clouds as the graph's first pass placed
    them, and its longest visit makes most of a floor's cloud: anchored there, the factor ties what
    was registered. A short visit (back to the start floor by elevator at the end of a log) can
    sit a few tenths of a degree off the rest of its floor, held only by a loop or two: anchored
    there, the floors above followed it (0.3-0.5 degrees on the stress set's stairs logs).
    Not the keyframes at a ride either: those are taken in and at the cabin, where the mapping
    stage's poses are least reliable.
    """

    def middle_of_longest(floor_id: int) -> Keyframe:
        longest = max(_visits(kfs, floor_id), key=len)  # the first of equals
        return longest[len(longest) // 2]

    return middle_of_longest(lower), middle_of_longest(upper)


def _anchor_pairs(kfs: list[Keyframe], initial: dict[int, F64], lower: int, upper: int,
                  correction: F64, count: int) -> list[tuple[Keyframe, Keyframe]]:
    """Up to `count` pairs of keyframes one above the other (within `ABOVE_M` once
    registered), spread over the lower floor's keyframes that have one; `_anchors`' pair
    where fewer than `MIN_PAIRS` such pairs exist (nothing to average), or for `count` 1.

    The registration places one floor's whole cloud on the other's, and a floor's map bends
    a little between loops: gen-stairs-s11's start floor came out turned 0.12 deg at the far
    end of a 26 m corridor, where the middle keyframe of its longest visit is, and its upper
    floors followed that keyframe (0.15-0.19 deg, 4-6 cm at their checkpoints). Shared by
    keyframes across the floor, the factor holds the floors' average pose. One above the
    other, so that a keyframe's local turn does not move its partner by a lever: paired with
    the nearest upper keyframe wherever it was, the `stairs` log's floors (whose routes meet
    only near the stairwell) tied one upper keyframe to eight lower ones 3-20 m away and came
    out turned 0.1 deg more. The ends of visits and short visits are left out, as in `_anchors`.
    """
    if count == 1:
        return [_anchors(kfs, lower, upper)]

    def inside(floor_id: int) -> list[Keyframe]:
        return [k for v in _visits(kfs, floor_id) if len(v) > SHORT_VISIT
                for k in v[VISIT_END:-VISIT_END]]

    ups = inside(upper)
    if not ups:  # only short visits above: nothing away from the cabin to pair with
        return [_anchors(kfs, lower, upper)]
    up_xy = np.array([(correction @ initial[k.id])[:2, 3] for k in ups])
    below: list[tuple[Keyframe, Keyframe]] = []
    for a in inside(lower):
        apart = np.linalg.norm(up_xy - initial[a.id][:2, 3], axis=1)
        if apart.min() <= ABOVE_M:
            below.append((a, ups[int(np.argmin(apart))]))
    pairs: list[tuple[Keyframe, Keyframe]] = []
    taken: set[int] = set()
    for i in range(min(count, len(below))):
        a, b = below[int((i + 0.5) * len(below) / min(count, len(below)))]
        if b.id not in taken:
            taken.add(b.id)
            pairs.append((a, b))
    return pairs if len(pairs) >= MIN_PAIRS else [_anchors(kfs, lower, upper)]


def add_interfloor(
    builder: Builder,
    kfs: list[Keyframe],
    initial: dict[int, F64],
    floor_ids: list[int],
    config: GraphConfig,
    executor: Executor | None = None,
) -> list[FloorMatch]:
    floor_z = median_floor_z(kfs, initial)
    clouds = {
        f: floor_points_seen(kfs, initial, f, config.interfloor.band_m, floor_z[f]) for f in floor_ids
    }
    if any(len(c[0]) < 200 for c in clouds.values()):
        # A 2D scanner's returns all lie at its own height, usually below the band: use them all.
        clouds = {f: floor_points_seen(kfs, initial, f, (-1.0, 3.0), floor_z[f]) for f in floor_ids}
    yaw = math.radians(config.interfloor.sigma_yaw_deg)
    sig_xy = config.interfloor.sigma_xy_m
    tilt = LOOSE_TILT_RAD
    register = functools.partial(
        register_floors,
        voxel_m=config.interfloor.voxel_m,
        min_fitness=config.interfloor.min_fitness,
        ambiguity_ratio=config.interfloor.ambiguity_ratio,
        max_correction_m=config.interfloor.max_correction_m,
        max_correction_deg=config.interfloor.max_correction_deg,
        robust_m=config.interfloor.robust_m,
        seed=config.seed,
    )
    pairs = list(itertools.pairwise(floor_ids))
    if executor is not None and len(pairs) > 1:
        # Each pair on its own (one thread per process, the same seed): the same matches.
        futures = [executor.submit(register, clouds[lower][0], clouds[upper][0], lower, upper,
                                   lower_views=clouds[lower][1], upper_views=clouds[upper][1])
                   for lower, upper in pairs]
        matches = [future.result() for future in futures]
    else:
        matches = [register(clouds[lower][0], clouds[upper][0], lower, upper,
                            lower_views=clouds[lower][1], upper_views=clouds[upper][1])
                   for lower, upper in pairs]
    for (lower, upper), match in zip(pairs, matches, strict=True):
        if not match.accepted:
            builder.reject("interfloor")
            continue
        anchors = _anchor_pairs(kfs, initial, lower, upper, match.correction, config.interfloor.anchors)
        share = math.sqrt(len(anchors))
        for a, b in anchors:
            measured = relative_level(initial[a.id], match.correction @ initial[b.id], None)
            builder.between(
                "interfloor", a.id, b.id, measured,
                [tilt, tilt, yaw * share, sig_xy * share, sig_xy * share, FREE_SIGMA], robust=False,
            )
    return matches


def bridge_components(
    builder: Builder, kfs: list[Keyframe], initial: dict[int, F64]
) -> None:
    """Link parts of the graph nothing else connects, weakly, at their initial relative pose
    (each link with a warning)."""
    ids = [k.id for k in kfs]
    comp = _components(ids, builder.links)
    seen = {comp[ids[0]]}
    for prev, kf in itertools.pairwise(kfs):
        root = comp[kf.id]
        if root in seen:
            continue
        seen.add(root)
        measured = relative_level(initial[prev.id], initial[kf.id], None)
        builder.between("bridge", prev.id, kf.id, measured, [0.1, 0.1, 0.1, 1.0, 1.0, FREE_SIGMA], robust=False)
        logger.warning("keyframes %d and %d had no measurement linking them; bridged weakly at the "
                       "mapping stage's relative pose", prev.id, kf.id)
