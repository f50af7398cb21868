"""The localiser while it tracks: a scan registered against its floor whenever the robot moved
enough, rides and stairs followed, a new visit's floor, a track lost. The registration itself is
mfmap.localize.track."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from mfmap.localize.records import Status
from mfmap.localize.state import (
    NO_WHEELS_INTERVAL_NS,
    RIDE_STILL_SHARE,
    WHEELS_MIN_DEG,
    WHEELS_MIN_M,
    LocalizerState,
)
from mfmap.types import F64, TransitionKind


class Tracking(LocalizerState):
    """Rides, stairs and tracking on a floor."""

    def _transition_scan(self, stamp_ns: int, tr: Any) -> None:
        if self.mode != "track" or self.floor is None or self.anchor is None:
            self._unposed(self.track.add(stamp_ns, self._status_unposed()))
            self.query = None
            return
        self._flush()
        if self.ride_from is None or self.ride_from[1] != tr.start_ns:
            self.ride_from = (self.floor, tr.start_ns, self.anchor[2].copy())
        floor, start_ns, _ = self.ride_from
        # x, y and yaw by the motion prior: the wheels stand still in the cabin, and drive
        # when the barometer (lagging in the cabin) still says the ride goes on.
        _, anchor_ns, anchor_pose = self.anchor
        pose = anchor_pose @ self.prep.delta(anchor_ns, stamp_ns)
        label = -1
        if tr.kind == TransitionKind.ELEVATOR:
            pose[2, 3], label = self._ride_z(tr, floor, stamp_ns)
            status = Status.RIDE
        else:
            pose[2, 3] = (self.map.floors[floor].elevation_m + self._height(stamp_ns)
                          - self._height(start_ns))
            status = Status.STAIRS
        i = self.track.add(stamp_ns, status, pose, label)
        self.anchor = (i, stamp_ns, pose)

    def _ride_z(self, tr: Any, floor: int, stamp_ns: int) -> tuple[float, int]:
        """The base's height in a ride, and its floor while the cabin stands (-1 while it
        moves): the accelerometer's profile between the two floors' elevations, else the
        barometer's height change (and -1 throughout)."""
        from mfmap.localize.rides import ride_profile

        start = self.map.floors[floor].elevation_m
        assert self.chosen is not None
        to = self.chosen.floor_of(tr.to_floor)
        if tr.start_ns not in self.profiles:
            imu = self.src.imu()
            to_base = self.prep.extrinsics.get(imu.frame_id) if imu is not None else None
            self.profiles[tr.start_ns] = ride_profile(
                imu, to_base if to_base is not None else np.eye(4), tr.start_ns, tr.end_ns)
        profile = self.profiles[tr.start_ns]
        if to is None or profile is None:
            return start + self._height(stamp_ns) - self._height(tr.start_ns), -1
        share = float(np.interp(stamp_ns, profile[0], profile[1]))
        # The barometer in the closed cabin lags the ride: before and after the cabin moves
        # (by the accelerometer) the robot stands on a floor, though the barometer's ride goes on.
        label = floor if share < RIDE_STILL_SHARE else to if share > 1.0 - RIDE_STILL_SHARE else -1
        return start + share * (self.map.floors[to].elevation_m - start), label

    def _new_visit(self, visit: int, log_floor: int, stamp_ns: int) -> None:
        """A new visit of the log's segmentation: its map floor, and how to go on."""
        if self.mode == "track":
            self._flush()
        came_tracking = self.mode == "track" and self.visit >= 0 and self.anchor is not None
        self.visit = visit
        self.since_visit = 0
        self.attempt_ns = None
        self.query = None
        self.next_search_ns = 0
        self.retry_s = self.lc.retry_s
        target = self._map_floor(log_floor)
        if target == "ambiguous":
            self.mode, self.floor = "ambiguous", None
            return
        if target is None:
            self.mode, self.floor = "no_floor", None
            return
        assert isinstance(target, int)
        if came_tracking and self.floor is not None and self.ride_from is not None:
            assert self.anchor is not None
            _, start_ns, _ = self.ride_from
            index, anchor_ns, pose = self.anchor
            rides = [tr for tr in self.timeline.transitions
                     if tr.kind == TransitionKind.ELEVATOR and tr.start_ns == start_ns]
            if rides:
                pose = self.motion.level(pose, rides[0].start_ns, rides[0].end_ns)
            else:
                self.wide_next = True  # off the stairs: the climb may have drifted
            pose = pose.copy()
            pose[2, 3] = self.map.floors[target].elevation_m
            self.anchor = (index, anchor_ns, pose)
            self.floor, self.mode = target, "track"
            self.ride_from = None
            return
        self.mode, self.floor = "search", target if self.chosen is not None else None

    def _map_floor(self, log_floor: int) -> int | str | None:
        """The map floor of a log floor: the chosen hypothesis's; before a fix, -1 (search),
        None when no remaining hypothesis gives it one, "ambiguous" when they disagree."""
        if self.chosen is not None:
            return self.chosen.floor_of(log_floor)
        options = {h.floor_of(log_floor) for h in self.tops}
        if options == {None}:
            return None
        if None in options:
            return "ambiguous"
        return -1

    def _track_scan(self, stamp_ns: int, frame_id: str, xyz: np.ndarray,
                    t_offset_ns: np.ndarray | None) -> None:
        from mfmap.localize.track import register

        assert self.floor is not None and self.anchor is not None
        i = self.track.add(stamp_ns, Status.PREDICTED, None, self.floor)
        if not (self.wide_next or self._due(stamp_ns)):
            return
        _, anchor_ns, anchor_pose = self.anchor
        delta = self.prep.delta(anchor_ns, stamp_ns, quick=True)
        predicted = anchor_pose @ delta
        if self.prep.in_cabin(stamp_ns, predicted):
            return
        self.attempt_ns = stamp_ns
        points = self.prep.points(stamp_ns, frame_id, xyz, t_offset_ns, predicted)
        if len(points) < 20:
            return
        floor = self.map.floors[self.floor]
        reg = register(self.prep.thin(points), floor.target, predicted, self.lc.fit_distance_m,
                       self.wide_next, self.lc.icp_tolerance)
        self.wide_next = False
        self.track.fitness[i] = reg.fitness
        if reg.fitness >= self.lc.track_fitness:
            self._fill(i, reg.pose)
            self.track.poses[i] = reg.pose
            self.track.status[i] = Status.TRACKED
            self.anchor = (i, stamp_ns, reg.pose)
            self.bad_since_ns = None
            return
        if self.bad_since_ns is None:
            self.bad_since_ns = stamp_ns
        if stamp_ns - self.bad_since_ns > self.lc.lost_after_s * 1e9:
            self._lose(i)

    def _pending(self, upto: int) -> list[int]:
        """The scans after the anchor, before `upto`, waiting for a pose."""
        assert self.anchor is not None
        return [k for k in range(self.anchor[0] + 1, upto)
                if self.track.status[k] == Status.PREDICTED]

    def _fill(self, i: int, pose: F64) -> None:
        """Pose the scans between the anchor and scan i (registered at `pose`) between the two."""
        from mfmap.localize.track import interpolate

        assert self.anchor is not None
        pending = self._pending(i)
        if not pending:
            return
        _, anchor_ns, anchor_pose = self.anchor
        stamps = np.asarray([self.track.stamps_ns[k] for k in pending], dtype=np.int64)
        span = float(self.track.stamps_ns[i] - anchor_ns)
        shares_t = (stamps - anchor_ns) / span
        shares_path, shares_turn = shares_t, shares_t
        if self.wheels.usable:
            # Shares of the way and of the turn as the wheels saw them: the robot does not move
            # evenly in time between two registrations (it starts, stops, turns in place).
            ends = np.concatenate([[anchor_ns], stamps, [self.track.stamps_ns[i]]])
            along = self.wheels.along(ends)
            if along[-1] - along[0] > WHEELS_MIN_M:
                shares_path = (along[1:-1] - along[0]) / (along[-1] - along[0])
            heading = self.wheels.heading(ends)
            if abs(heading[-1] - heading[0]) > math.radians(WHEELS_MIN_DEG):
                shares_turn = (heading[1:-1] - heading[0]) / (heading[-1] - heading[0])
        for k, p in zip(pending, interpolate(anchor_pose, pose, shares_turn, shares_path), strict=True):
            self.track.poses[k] = p

    def _flush(self) -> None:
        """Pose the scans waiting since the anchor by the motion prior (no registration follows:
        a ride or stairs begin, or the log ends)."""
        if self.anchor is None:
            return
        _, anchor_ns, anchor_pose = self.anchor
        for k in self._pending(len(self.track.status)):
            self.track.poses[k] = anchor_pose @ self.prep.delta(anchor_ns, self.track.stamps_ns[k])

    def _due(self, stamp_ns: int) -> bool:
        """Whether the robot moved, turned or waited enough since the last registration."""
        lc = self.lc
        if self.attempt_ns is None:
            return True
        if stamp_ns - self.attempt_ns >= lc.register_interval_s * 1e9:
            return True
        if not self.wheels.usable:
            return stamp_ns - self.attempt_ns >= NO_WHEELS_INTERVAL_NS
        dist, turn = self.wheels.moved(self.attempt_ns, stamp_ns)
        return dist >= lc.register_distance_m or turn >= lc.register_angle_deg

    def _lose(self, i: int) -> None:
        """The track stopped fitting: the scans since the last good one are not posed."""
        assert self.anchor is not None
        first = self.anchor[0] + 1
        best = 0.0
        for k in range(first, i + 1):
            self.track.status[k] = Status.LOST
            self.track.poses[k] = np.full((4, 4), np.nan)
            if not math.isnan(self.track.fitness[k]):
                best = max(best, self.track.fitness[k])
        self.span_bests[first] = best
        self.mode = "search"
        self.query = None
        self.next_search_ns = 0
        self.retry_s = self.lc.retry_s
        self.anchor = None
        self.bad_since_ns = None
