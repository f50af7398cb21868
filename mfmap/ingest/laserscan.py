"""The 2D laser's scans (sensor_msgs/LaserScan) as points, and which way its beams run in time."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from mfmap.errors import DecodeError
from mfmap.ingest.core import LogCore
from mfmap.ingest.decode import decode_laserscan
from mfmap.ingest.series import SeriesReader
from mfmap.types import Extrinsics, Role, Scan2D


class LaserScanReader:
    """A log's 2D laser scans, each beam's time in the order decided once for the log."""

    def __init__(self, core: LogCore, series: SeriesReader,
                 extrinsics: Callable[[], Extrinsics]) -> None:
        self._core = core
        self._series = series
        self._extrinsics = extrinsics
        self.beam_time: str | None = None
        self.report: dict[str, Any] = {}

    def scans(self, start_ns: int | None = None, end_ns: int | None = None) -> Iterator[Scan2D]:
        """2D laser scans in stamp order as points (MissingDataError at the call if none), each
        beam's time in the order `scan2d_beam_time` decided."""
        topic = self._core._require(Role.SCAN2D, "2D laser scanner")
        reverse = self.decide_beam_time() == "reversed"
        guard = self._core._guard(topic)
        records = guard.by_offset(
            self._core._records(topic, start_ns, end_ns, self._core._backend.deserialize),
            lambda r: r.stamp_ns, lambda r: r.log_time_ns)
        scans = guard.forwards(self._core._reorder(records), lambda r: r.stamp_ns)
        where = f"{self._core.path} topic {topic}"
        return self._core._guarded(topic, (decode_laserscan(r.msg, r.stamp_ns, reverse, where)
                                           for r in scans))

    def decide_beam_time(self) -> str:
        """"as_stated" or "reversed": which way the LaserScan's beams run in time (config, else
        checked against the robot's turns, `mfmap.ingest.sweep2d`)."""
        if self.beam_time is not None:
            return self.beam_time
        topic = self._core._require(Role.SCAN2D, "2D laser scanner")
        mode = self._core.config.scan2d_beam_time
        if mode != "auto":
            self.beam_time, self.report = mode, {"topic": topic, "beam_time": mode,
                                                 "decided": "config"}
            return mode
        check = self._check_sweep(topic)
        self.beam_time = "reversed" if check.decision == "reversed" else "as_stated"
        self.report = {"topic": topic, "beam_time": self.beam_time, "decided": "data",
                       "check": check.to_json()}
        if check.decision == "reversed":
            self._core._warn(
                f"{topic}: the LaserScan's beam times run against its sweep (time_increment "
                f"positive, but deskewed so the turning scans overlap {check.residual_stated_m * 100:.1f} "
                f"cm apart against {check.residual_reversed_m * 100:.1f} cm read the other way, "
                f"{check.reason}: the rplidar_ros convention); beam i taken at "
                "(n - 1 - i) * time_increment (ingest.scan2d_beam_time: reversed)")
        elif check.decision == "unknown":
            self.report["note"] = f"beam order not checked: {check.reason}"
        return self.beam_time

    def _check_sweep(self, topic: str) -> Any:
        from mfmap.ingest.sweep2d import (
            PlanarOdometry,
            ScanPair,
            SweepCheck,
            YawTrack,
            check_sweep,
            half_turns,
        )

        first = next(iter(self._core.messages(topic)), None)
        if first is None:
            return SweepCheck("unknown", "no scans")
        if float(first.msg.time_increment) == 0.0:
            return SweepCheck("unknown", "time_increment is 0: the scans carry no beam times")
        to_base = self._extrinsics().get(str(first.msg.header.frame_id))
        laser_to_base = to_base if to_base is not None else np.eye(4)
        imu, odom = self._series.imu(), self._series.odometry()
        if imu is not None and len(imu) > 10:
            imu_to_base = self._extrinsics().get(imu.frame_id)
            rot = np.eye(3) if imu_to_base is None else imu_to_base[:3, :3]
            yaw = YawTrack(imu.stamp_ns, (imu.gyro_rad_s @ rot.T)[:, 2])
        elif odom is not None and len(odom) > 10:
            yaw = YawTrack(odom.stamp_ns, odom.angular_rad_s[:, 2])
        else:
            return SweepCheck("unknown", "no IMU or wheel odometry to check it against; set "
                              "ingest.scan2d_beam_time")
        period = max(int(float(first.msg.scan_time) * 1e9), 0) or int(
            abs(float(first.msg.time_increment)) * len(first.msg.ranges) * 1e9)
        period = max(period, 1_000_000)
        grid = np.arange(self._core.start_ns, self._core.end_ns, 50_000_000, dtype=np.int64)
        times = half_turns(yaw, grid, lambda t: yaw.rate_at(t, period))
        if not times:
            return SweepCheck("unknown", "the robot never turns half a turn fast enough to tell")
        velocity_of = None
        planar = None
        if odom is not None and len(odom) > 1:
            t_odom = odom.stamp_ns.astype(np.float64)
            planar = PlanarOdometry(odom.stamp_ns, odom.xyz, odom.quat_xyzw)

            def velocity_of(stamp_ns: int) -> np.ndarray[Any, Any]:
                return np.array([np.interp(stamp_ns, t_odom, odom.linear_m_s[:, 0]),
                                 np.interp(stamp_ns, t_odom, odom.linear_m_s[:, 1])])

        pairs = []
        for ta, tb in times:
            a = next(iter(self._core.messages(topic, ta, ta + 3 * period)), None)
            b = next(iter(self._core.messages(topic, tb, tb + 3 * period)), None)
            if a is None or b is None or b.stamp_ns <= a.stamp_ns:
                continue
            turn = float(yaw.at(np.array([float(b.stamp_ns)]))[0] - yaw.at(np.array([float(a.stamp_ns)]))[0])
            shift = planar.shift(a.stamp_ns, b.stamp_ns) if planar is not None else np.zeros(2)
            pairs.append(ScanPair(a.msg, a.stamp_ns, b.msg, b.stamp_ns, turn, shift))
        try:
            return check_sweep(pairs, laser_to_base, yaw, velocity_of)
        except DecodeError as err:
            if err.path is not None:
                raise
            raise DecodeError(err.message, f"{self._core.path} topic {topic}") from err

