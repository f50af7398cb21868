"""Elevator cabins measured from the scans the lidar takes inside them.

During a ride the robot stands in a closed box and its lidar sees little but the cabin's four
walls: the mapping stage trusts no such scan and the floor maps leave them out (their walls are
not part of any floor). The same scans are a measurement of the cabin: its interior, its
position and heading in the world, and - from the scans taken while the doors stand open before
and after the ride - which wall the door is in on each floor. Open-RMF's building map and the
Foxglove scene draw the lift from these figures.

The walls are found as the densest band of returns on each side of the robot, not the nearest
ones: polished cabin walls return a share of their hits at a longer, wrong range, and a closed
door or a handrail adds a few returns in front of a wall.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from mfmap.types import Extrinsics, FloorSegmentation, Role, TransitionKind

if TYPE_CHECKING:
    from mfmap.ingest.source import LogSource

# Sides in the cabin's own frame, as Open-RMF's lift doors name them (LiftDoor.side):
# +y front, -y back, +x right, -x left.
SIDES: tuple[str, ...] = ("right", "left", "front", "back")
_SIDE_AXIS = {"right": (0, 1.0), "left": (0, -1.0), "front": (1, 1.0), "back": (1, -1.0)}

MAX_RANGE_M = 30.0  # through an open door the lidar sees the landing and the corridor beyond
BAND_Z_M = (0.25, 2.0)  # heights above the base that see walls, not the cabin's floor or roof
DOOR_WINDOW_S = 20.0  # before and after a ride the robot stands in the cabin with the doors open
MAX_SCANS_PER_PHASE = 12  # scans read per ride, and per door phase (they all see the same box)
MAX_POINTS_PER_SCAN = 8000  # every k-th return kept: walls 1 m away are sampled far finer than 1 cm
HEADING_POINTS = 40_000  # returns the heading search looks at
INSIDE_M = 0.35  # a scan counts as taken in the cabin this close to the robot's ride position
SAME_SHAFT_M = 1.0  # rides whose positions are this close use the same cabin


@dataclass(frozen=True)
class CabinDoor:
    """A door in one wall of the cabin, in the cabin's frame (origin at the interior centre)."""

    side: str  # one of SIDES
    offset_m: float  # door centre along the wall, from the wall's middle
    width_m: float
    open_share: float  # share of the door-phase returns that left the cabin through it


@dataclass(frozen=True)
class Cabin:
    """One elevator cabin in the world frame, as measured from the scans inside it."""

    x_m: float  # centre of the interior
    y_m: float
    yaw_rad: float  # direction of the cabin's x axis (the side 'width' measures)
    inner_width_m: float  # interior along the cabin's x axis
    inner_depth_m: float  # interior along its y axis
    floors: tuple[int, ...]  # floors the measured rides left from or arrived at
    doors: dict[int, CabinDoor]  # floor -> the door that opened there
    rides: int
    scans: int  # ride scans the walls were measured from
    wall_support: dict[str, int] = field(default_factory=dict)  # side -> returns on that wall


@dataclass
class _Phase:
    """The scans of one stretch of a ride: 'ride' (doors shut) or a floor's door phase."""

    kind: str
    floor: int
    xy: list[np.ndarray] = field(default_factory=list)  # per scan: (N, 2) world x, y
    origin: list[np.ndarray] = field(default_factory=list)  # per scan: sensor x, y in the world


@dataclass
class _Ride:
    start_ns: int
    end_ns: int
    from_floor: int
    to_floor: int
    pose: np.ndarray  # base pose in the cabin at the ride's start (world)
    phases: list[_Phase] = field(default_factory=list)


def _nearest_index(stamps_ns: np.ndarray, stamp_ns: int) -> int:
    i = int(np.clip(np.searchsorted(stamps_ns, stamp_ns), 0, len(stamps_ns) - 1))
    if i > 0 and abs(int(stamps_ns[i - 1]) - stamp_ns) < abs(int(stamps_ns[i]) - stamp_ns):
        i -= 1
    return i


def _spread(stamps: Sequence[int], k: int) -> list[int]:
    """At most k of the stamps, evenly spread (first and last kept)."""
    if len(stamps) <= k:
        return list(stamps)
    idx = np.round(np.linspace(0, len(stamps) - 1, k)).astype(int)
    return [stamps[i] for i in idx]


def _plan(seg: FloorSegmentation, stamps_ns: np.ndarray, poses: np.ndarray) -> tuple[list[_Ride], dict[int, tuple[_Ride, str, int]]]:
    """The rides and, per chosen scan stamp, which ride and phase it belongs to."""
    rides: list[_Ride] = []
    wanted: dict[int, tuple[_Ride, str, int]] = {}
    window = int(DOOR_WINDOW_S * 1e9)
    for tr in seg.transitions:
        if tr.kind != TransitionKind.ELEVATOR:
            continue
        i0 = _nearest_index(stamps_ns, tr.start_ns)
        ride = _Ride(tr.start_ns, tr.end_ns, tr.from_floor, tr.to_floor, poses[i0])
        rides.append(ride)
        at = ride.pose[:2, 3]
        near = np.hypot(poses[:, 0, 3] - at[0], poses[:, 1, 3] - at[1]) < INSIDE_M
        during = (stamps_ns >= tr.start_ns) & (stamps_ns <= tr.end_ns)
        before = (stamps_ns >= tr.start_ns - window) & (stamps_ns < tr.start_ns) & near
        after = (stamps_ns > tr.end_ns) & (stamps_ns <= tr.end_ns + window) & near
        # Only the contiguous stretch in the cabin next to the ride (not an earlier visit).
        for kind, mask, floor in (("ride", during, -1), ("door", before, tr.from_floor),
                                  ("door", after, tr.to_floor)):
            idx = np.flatnonzero(mask)
            if kind == "door" and len(idx):
                idx = _contiguous(idx, at_end=mask is before)
            chosen = _spread([int(s) for s in stamps_ns[idx]], MAX_SCANS_PER_PHASE)
            phase = _Phase(kind, floor)
            ride.phases.append(phase)
            for s in chosen:
                wanted.setdefault(s, (ride, kind, len(ride.phases) - 1))
    return rides, wanted


def _contiguous(idx: np.ndarray, at_end: bool) -> np.ndarray:
    """The run of consecutive indices touching the ride (the last run before, the first after)."""
    breaks = np.flatnonzero(np.diff(idx) > 1)
    if at_end:
        return idx[breaks[-1] + 1:] if len(breaks) else idx
    return idx[:breaks[0] + 1] if len(breaks) else idx


def read_cabin_scans(src: LogSource, seg: FloorSegmentation, stamps_ns: np.ndarray,
                     poses: np.ndarray, extrinsics: Extrinsics) -> list[_Ride]:
    """The chosen scans of every ride, read from the log (only the windows that hold them)."""
    rides, wanted = _plan(seg, stamps_ns, poses)
    planar = Role.LIDAR not in src.roles
    for lo, hi in _windows(wanted):
        if planar:
            scans: Iterator[tuple[int, str, np.ndarray]] = (
                (s.stamp_ns, s.frame_id, np.column_stack([s.xy, np.zeros(len(s.xy))]))
                for s in src.scans2d(lo, hi))
        else:
            scans = ((c.stamp_ns, c.frame_id, c.xyz) for c in src.clouds(lo, hi))
        for stamp_ns, frame_id, xyz in scans:
            hit = wanted.pop(stamp_ns, None)
            if hit is not None:
                _add_scan(hit[0].phases[hit[2]], xyz, extrinsics.get(frame_id),
                          poses[_nearest_index(stamps_ns, stamp_ns)], planar)
    return rides


def _windows(wanted: dict[int, tuple[_Ride, str, int]], max_gap_ns: int = 2_000_000_000) -> list[tuple[int, int]]:
    """Spans of the log to decode: the wanted stamps, split where they are far apart."""
    stamps = sorted(wanted)
    out: list[tuple[int, int]] = []
    for s in stamps:
        if out and s - out[-1][1] <= max_gap_ns:
            out[-1] = (out[-1][0], s)
        else:
            out.append((s, s))
    return out


def _add_scan(phase: _Phase, xyz: np.ndarray, to_base: np.ndarray | None, pose: np.ndarray,
              planar: bool) -> None:
    pts = np.asarray(xyz, dtype=np.float64)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    sensor = np.zeros(3)
    if to_base is not None:
        pts = pts @ to_base[:3, :3].T + to_base[:3, 3]
        sensor = to_base[:3, 3].copy()
    d = pts[:, :2] - sensor[:2]
    rng2 = np.einsum("ij,ij->i", d, d)
    keep = (rng2 >= 0.4**2) & (rng2 <= MAX_RANGE_M**2)
    if not planar:
        keep &= (pts[:, 2] >= BAND_Z_M[0]) & (pts[:, 2] <= BAND_Z_M[1])
    pts = pts[keep]
    pts = pts[::max(1, -(-pts.shape[0] // MAX_POINTS_PER_SCAN))]
    world = pts @ pose[:3, :3].T + pose[:3, 3]
    phase.xy.append(world[:, :2])
    phase.origin.append((pose[:3, :3] @ sensor + pose[:3, 3])[:2])


# ----- the geometry --------------------------------------------------------------------------


def _rotate(xy: np.ndarray, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.asarray(xy @ np.array([[c, -s], [s, c]]).T)


def _peakiness(local: np.ndarray, bin_m: float = 0.02) -> float:
    """How sharply the points stack up along both axes (walls aligned with them stack up)."""
    score = 0.0
    for axis in (0, 1):
        v = local[:, axis]
        counts = np.bincount(np.floor((v - v.min()) / bin_m).astype(np.int64))
        score += float(np.dot(counts, counts))
    return score


def cabin_heading(xy: np.ndarray, centre: np.ndarray) -> float:
    """Direction of one pair of walls, in [-pi/4, pi/4): the rotation that stacks the returns
    into the sharpest lines along x and y (coarse search, then a fine one)."""
    rel = xy - centre
    best = 0.0
    for step, span in ((math.radians(1.0), math.pi / 4), (math.radians(0.05), math.radians(1.0))):
        angles = np.arange(best - span, best + span, step)
        scores = [_peakiness(_rotate(rel, -a)) for a in angles]
        best = float(angles[int(np.argmax(scores))])
    return (best + math.pi / 4) % (math.pi / 2) - math.pi / 4


def _wall(along: np.ndarray, lo_m: float = 0.3, hi_m: float = 2.5, bin_m: float = 0.01) -> tuple[float, int] | None:
    """Distance to the densest band of returns in `along` (> 0), refined to their mean."""
    v = along[(along > lo_m) & (along < hi_m)]
    if v.shape[0] < 20:
        return None
    counts = np.bincount(np.floor((v - lo_m) / bin_m).astype(np.int64))
    # A 5 cm running sum, so a wall spread over neighbouring bins by noise counts as one band.
    smooth = np.convolve(counts, np.ones(5), mode="same")
    peak = lo_m + (int(np.argmax(smooth)) + 0.5) * bin_m
    band = v[np.abs(v - peak) < 0.04]
    if band.shape[0] < max(50, 0.25 * v.shape[0]):
        return None  # no wall: the returns on this side are spread out (open space)
    return float(band.mean()), int(band.shape[0])


def fit_cabin_box(xy: np.ndarray, robot_xy: np.ndarray) -> tuple[np.ndarray, float, np.ndarray, dict[str, int]] | None:
    """Interior of the box the robot stands in: (centre xy, heading, (width, depth), support).

    `xy` are world x, y of wall-height returns from scans taken inside it with the doors shut.
    """
    if xy.shape[0] < 200:
        return None
    near = xy[np.hypot(*(xy - robot_xy).T) < 2.5]
    if near.shape[0] < 200:
        return None
    yaw = cabin_heading(near[::max(1, -(-near.shape[0] // HEADING_POINTS))], robot_xy)
    local = _rotate(near - robot_xy, -yaw)
    centre = np.zeros(2)
    half = np.array([0.5, 0.5])  # strip half-widths: first pass near the robot only
    walls: dict[str, tuple[float, int]] = {}
    for _ in range(3):
        walls = {}
        for side in SIDES:
            axis, sign = _SIDE_AXIS[side]
            other = 1 - axis
            strip = np.abs(local[:, other] - centre[other]) < half[other]
            found = _wall(sign * (local[strip, axis] - centre[axis]))
            if found is None:
                return None
            walls[side] = (centre[axis] + sign * found[0], found[1])
        size = np.array([walls["right"][0] - walls["left"][0], walls["front"][0] - walls["back"][0]])
        centre = np.array([(walls["right"][0] + walls["left"][0]) / 2,
                           (walls["front"][0] + walls["back"][0]) / 2])
        half = 0.35 * size  # the middle 70 % of each wall (clear of the corners)
    centre_world = robot_xy + _rotate(centre[None, :], yaw)[0]
    return centre_world, yaw, size, {side: n for side, (_, n) in walls.items()}


def door_of(phase: _Phase, centre: np.ndarray, yaw: float, size: np.ndarray) -> CabinDoor | None:
    """The wall whose rays leave the cabin while the doors are open, and the opening's width.

    A ray that ends well beyond a wall went through the door; spurious long returns of
    polished walls cross walls too, but nowhere near as far or as many as the view through an
    open door. The opening's width is the gap in that wall's own returns around where those
    rays crossed it (the rays alone would give the narrower view through the landing's door).
    """
    if not phase.xy:
        return None
    half = size / 2
    scans = [(_rotate(xy - centre, -yaw), _rotate((origin - centre)[None, :], -yaw)[0])
             for xy, origin in zip(phase.xy, phase.origin, strict=True)]
    best: CabinDoor | None = None
    for side in SIDES:
        axis, sign = _SIDE_AXIS[side]
        other = 1 - axis
        crossings: list[np.ndarray] = []
        on_wall: list[np.ndarray] = []
        total = 0
        for local, o in scans:
            depth = sign * local[:, axis]
            # Rays towards this wall (they end beyond the interior's middle on its side).
            towards = depth > 0.3 * half[axis]
            total += int(towards.sum())
            far = towards & (depth > half[axis] + 1.0)
            if far.sum() < 0.05 * max(int(towards.sum()), 1):
                continue  # the doors are shut in this scan (or it sees this wall's spurious returns)
            on_wall.append(local[np.abs(depth - half[axis]) < 0.04, other])
            d = local[far] - o
            t = (sign * half[axis] - o[axis]) / d[:, axis]
            crossings.append(o[other] + t * d[:, other])
        if not crossings or total == 0:
            continue
        cross = np.concatenate(crossings)
        cross = cross[np.abs(cross) < half[other]]
        share = cross.shape[0] / total
        if cross.shape[0] < 30 or share < 0.05:
            continue
        lo, hi = _gap(np.concatenate(on_wall), float(np.median(cross)), float(half[other]))
        door = CabinDoor(side, round((lo + hi) / 2, 3), round(hi - lo, 3), round(share, 3))
        if best is None or door.open_share > best.open_share:
            best = door
    return best


def _gap(along: np.ndarray, inside: float, half: float, bin_m: float = 0.02) -> tuple[float, float]:
    """The empty stretch of a wall's returns (positions `along` it) that holds `inside`."""
    edges = np.arange(-half, half + bin_m, bin_m)
    counts, _ = np.histogram(along, bins=edges)
    empty = counts <= max(1.0, 0.02 * float(np.median(counts)))
    k = int(np.clip(np.searchsorted(edges, inside) - 1, 0, len(counts) - 1))
    if not empty[k]:
        return inside, inside
    a = k
    while a > 0 and empty[a - 1]:
        a -= 1
    b = k
    while b < len(counts) - 1 and empty[b + 1]:
        b += 1
    return float(edges[a]), float(edges[b + 1])


def measure_cabins(rides: list[_Ride]) -> tuple[list[Cabin], list[str]]:
    """One cabin per elevator shaft from the collected scans, with warnings for what is missing."""
    warnings: list[str] = []
    groups: list[list[_Ride]] = []
    for ride in rides:
        for group in groups:
            if np.hypot(*(group[0].pose[:2, 3] - ride.pose[:2, 3])) < SAME_SHAFT_M:
                group.append(ride)
                break
        else:
            groups.append([ride])
    cabins: list[Cabin] = []
    for group in groups:
        robot_xy = np.mean([r.pose[:2, 3] for r in group], axis=0)
        ride_xy = [xy for r in group for p in r.phases if p.kind == "ride" for xy in p.xy]
        floors = tuple(sorted({f for r in group for f in (r.from_floor, r.to_floor)}))
        where = f"the elevator at ({robot_xy[0]:.1f}, {robot_xy[1]:.1f})"
        if not ride_xy:
            warnings.append(f"{where} (floors {list(floors)}): no lidar scan during its rides; "
                            "its cabin is not measured and no lift is exported for it")
            continue
        fit = fit_cabin_box(np.concatenate(ride_xy), robot_xy)
        if fit is None:
            warnings.append(f"{where} (floors {list(floors)}): the scans during its rides show no "
                            "closed box around the robot; no lift is exported for it")
            continue
        centre, yaw, size, support = fit
        doors: dict[int, CabinDoor] = {}
        for floor in floors:
            merged = _Phase("door", floor)
            for r in group:
                for p in r.phases:
                    if p.kind == "door" and p.floor == floor:
                        merged.xy += p.xy
                        merged.origin += p.origin
            door = door_of(merged, centre, yaw, size)
            if door is None:
                warnings.append(f"{where}: no open door seen on floor {floor}; that floor's landing "
                                "is left out of the lift's doors")
            else:
                doors[floor] = door
        cabins.append(Cabin(
            x_m=round(float(centre[0]), 4), y_m=round(float(centre[1]), 4),
            yaw_rad=round(float(yaw), 5),
            inner_width_m=round(float(size[0]), 4), inner_depth_m=round(float(size[1]), 4),
            floors=floors, doors=doors, rides=len(group), scans=len(ride_xy),
            wall_support=support,
        ))
    return cabins, warnings


def measure_from_log(src: LogSource, seg: FloorSegmentation, stamps_ns: np.ndarray,
                     poses: np.ndarray, extrinsics: Extrinsics) -> tuple[list[Cabin], list[str]]:
    """Every elevator's cabin, measured from the log's scans at the optimised poses."""
    if stamps_ns.shape[0] == 0 or not any(tr.kind == TransitionKind.ELEVATOR for tr in seg.transitions):
        return [], []
    return measure_cabins(read_cabin_scans(src, seg, stamps_ns, poses, extrinsics))
