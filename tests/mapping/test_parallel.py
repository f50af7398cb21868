"""Mapping the runs of visits between elevator rides and stair walks in parallel processes
(`workers`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from mfmap.eval.odometry import read_tum, visit_errors
from mfmap.ingest import open_log
from mfmap.mapping import map_floors
from mfmap.mapping.chunks import STAIRS_PRIME_NS, plan_chunks
from mfmap.mapping.config import MappingConfig
from mfmap.mapping.geometry import inverse, yaw_rad
from mfmap.mapping.posegraph import optimize_all_visits, scan_trajectory
from mfmap.mapping.timeline import Timeline
from mfmap.types import FloorSegmentation, MappingResult, Role

SegFn = Callable[[Path], FloorSegmentation]


def _run(folder: Path, seg: FloorSegmentation, workers: int) -> MappingResult:
    with open_log(folder / "log.mcap") as src:
        return map_floors(src, seg, MappingConfig(workers=workers), src.extrinsics())


def test_chunks_split_at_elevator_rides_and_stair_walks(sim_run: Callable[..., Path],
                                                        gt_floors: SegFn) -> None:
    seg = gt_floors(sim_run("tiny"))  # floor 0, elevator, floor 1
    chunks = plan_chunks(Timeline(seg))
    visits = seg.visits()
    assert [c.first_visit for c in chunks] == [0, 1]
    assert chunks[0].start_ns is None and chunks[1].end_ns is None
    assert chunks[0].end_ns == visits[1][1] and chunks[1].start_ns == visits[1][1] + 1
    assert not any(c.after_stairs or c.stop_in_visit is not None for c in chunks)
    # Stairs: floor 0, walk, floor 1, walk, floor 2. With `split_at_stairs` a chunk starts on
    # each walk's last half second (its motion primed there) and the one before maps on into the
    # next visit.
    seg = gt_floors(sim_run("stairs"))
    walks = seg.transitions
    visits = seg.visits()
    assert [c.first_visit for c in plan_chunks(Timeline(seg))] == [0]  # split_at_stairs is off
    chunks = plan_chunks(Timeline(seg), stairs=True)
    assert [(c.first_visit, c.after_stairs, c.stop_in_visit) for c in chunks] == [
        (0, False, 1), (1, True, 2), (2, True, None)]
    for k in (1, 2):
        assert chunks[k].start_ns == walks[k - 1].end_ns - STAIRS_PRIME_NS
        assert chunks[k - 1].end_ns == visits[k][1] + 5_000_000_000


def test_a_scan_at_the_rides_end_stays_on_the_ride(sim_run: Callable[..., Path],
                                                   gt_floors: SegFn) -> None:
    """A scan stamped exactly at a ride's end (three-floor-revisit seed 1's ride down) belongs
    to the ride, and so to the chunk before it: started with the next chunk it was posed from
    that chunk's held pose as if the whole ride lay ahead, 7.4 m below the floor it reached."""
    folder = sim_run("tiny")  # floor 0, elevator up 3.5 m, floor 1
    seg = gt_floors(folder)
    ride = seg.transitions[0]
    with open_log(folder / "log.mcap") as src:
        lidar = np.array([c.stamp_ns for c in src.clouds()], dtype=np.int64)
    end_ns = int(lidar[np.argmin(np.abs(lidar - ride.end_ns))])
    floors = tuple(replace(f, visits=tuple((end_ns, e) if s == ride.end_ns else (s, e)
                                           for s, e in f.visits)) for f in seg.floors)
    seg = replace(seg, floors=floors, transitions=(replace(ride, end_ns=end_ns),))
    assert Timeline(seg).at(end_ns).kind == "ride"
    chunks = plan_chunks(Timeline(seg))
    assert chunks[0].end_ns == end_ns and chunks[1].start_ns == end_ns + 1
    result = _run(folder, seg, 2)
    # Posed, as every ride scan, off the last keyframe before the ride (visit 0). Off visit 1's
    # first keyframe, the pose was that chunk's start plus the ride's whole height change: right
    # here only because tiny rides up from elevation 0.
    visit = {kf.id: kf.visit for kf in result.keyframes}
    assert [visit[sp.keyframe] for sp in result.scan_poses if sp.stamp_ns == end_ns] == [0]
    stamps, poses = scan_trajectory(result)
    at_end = int(np.flatnonzero(stamps == end_ns)[0])
    # Up the whole ride (3.5 m) and level with the next scan, on the floor reached.
    assert abs(poses[at_end][2, 3] - 3.5) < 0.05
    assert abs(poses[at_end][2, 3] - poses[at_end + 1][2, 3]) < 0.05


def test_two_workers_are_reproducible_and_as_accurate(sim_run: Callable[..., Path],
                                                      gt_floors: SegFn) -> None:
    folder = sim_run("tiny")
    seg = gt_floors(folder)
    first, second = _run(folder, seg, 2), _run(folder, seg, 2)
    assert first.stats["chunks"] == 2
    assert len(first.keyframes) == len(second.keyframes) > 20
    for a, b in zip(first.keyframes, second.keyframes, strict=True):
        assert a.id == b.id and np.array_equal(a.pose, b.pose)
    assert [(e.i, e.j, e.kind) for e in first.edges] == [(e.i, e.j, e.kind) for e in second.edges]
    assert [sp.stamp_ns for sp in first.scan_poses] == [sp.stamp_ns for sp in second.scan_poses]
    # Every scan posed once, on a keyframe of its own visit's numbering; one odometry edge per
    # consecutive keyframe pair of a visit, none across the ride; the loops of visit 0 found.
    with open_log(folder / "log.mcap") as src:
        assert len(first.scan_poses) == src.count(Role.LIDAR)
    odometry = [e for e in first.edges if e.kind == "odometry"]
    assert len(odometry) == len(first.keyframes) - 2
    assert first.stats["loop_edges"] >= 3
    stamps, poses = read_tum(folder / "gt_trajectory.tum")
    closed = visit_errors(first, seg.visits(), stamps, poses,
                          optimize_all_visits(first, height_tie_sigma_m=0.02))
    assert len(closed) == 2
    for e in closed:
        assert e.rmse_m < 0.05, e
    # The second visit is chained on the pose held through the ride: its scans are where one
    # process puts them (the first registered scans differ by the stride phase, so compare
    # the poses of the same scans).
    one = _run(folder, seg, 1)
    stamps_par, poses_par = scan_trajectory(first)
    stamps_one, poses_one = scan_trajectory(one)
    assert np.array_equal(stamps_par, stamps_one)
    start_1 = seg.visits()[1][1]
    first_scans = np.flatnonzero(stamps_par >= start_1)[:50]
    for k in first_scans:
        diff = inverse(poses_one[k]) @ poses_par[k]
        assert np.linalg.norm(diff[:3, 3]) < 0.03
        assert abs(np.degrees(yaw_rad(diff))) < 0.2
    assert abs(poses_par[first_scans[0]][2, 3] - 3.5) < 0.05
