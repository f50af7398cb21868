"""The small streams: barometer, IMU, odometry and temperature, read as plain rows of numbers.

They are read together in ONE pass over the log (with the transform topics), kept as compact
rows (floats per message) rather than message objects, so an hour of IMU costs tens of MB.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mfmap.errors import DecodeError, MfmapError, MissingDataError
from mfmap.ingest.backend import RawMessage
from mfmap.ingest.core import LogCore
from mfmap.ingest.decode import PressureUnit, pressure_unit, stamp_ns_of
from mfmap.ingest.roles import ROLE_TYPE
from mfmap.ingest.tfread import TfStore
from mfmap.ingest.timecheck import series_order
from mfmap.ingest.wire import parse_stamped_doubles
from mfmap.types import ImuSeries, OdomSeries, PressureSeries, Role, TemperatureSeries

SMALL_ROLES = (Role.BARO, Role.IMU, Role.ODOM)


@dataclass
class Rows:
    """One small stream as plain numbers: a stamp and a row of floats per message."""

    stamps: list[int] = field(default_factory=list)
    values: list[tuple[float, ...]] = field(default_factory=list)
    frame: str = ""
    child: str = ""
    error: MfmapError | None = None

    def add(self, role: Role, msg: Any, stamp_ns: int) -> None:
        """A message from the generic deserialiser."""
        frame = child = ""  # only the first message's are kept
        if not self.stamps:
            header = getattr(msg, "header", None)
            frame = str(header.frame_id) if header is not None else ""
            child = str(getattr(msg, "child_frame_id", ""))
        if role == Role.BARO:
            row: tuple[float, ...] = (float(msg.fluid_pressure),)
        elif role == Role.TEMPERATURE:
            row = (float(msg.temperature),)
        elif role == Role.IMU:
            w, a, q = msg.angular_velocity, msg.linear_acceleration, msg.orientation
            row = (w.x, w.y, w.z, a.x, a.y, a.z, q.x, q.y, q.z, q.w, float(msg.orientation_covariance[0]))
        else:
            p, q = msg.pose.pose.position, msg.pose.pose.orientation
            v, w = msg.twist.twist.linear, msg.twist.twist.angular
            row = (p.x, p.y, p.z, q.x, q.y, q.z, q.w, v.x, v.y, v.z, w.x, w.y, w.z)
        self.add_row(stamp_ns, row, frame, child)

    def add_row(self, stamp_ns: int, row: tuple[float, ...], frame: str, child: str) -> None:
        """A message as a row; the first message's frames are the stream's."""
        if not self.stamps:
            self.frame, self.child = frame, child
        self.stamps.append(stamp_ns)
        self.values.append(row)


# Small streams whose messages are a header (and odometry's child_frame_id) and then only
# float64 fields, read by the direct parser: role -> (number of doubles, has a child frame,
# `Rows.add`'s row from the doubles). sensor_msgs/Imu: orientation (0-3), its covariance (4-12),
# angular velocity (13-15), ..., linear acceleration (25-27); nav_msgs/Odometry: pose (0-6),
# its covariance (7-42), twist (43-48).
_FLAT: dict[Role, tuple[int, bool, Callable[[tuple[float, ...]], tuple[float, ...]]]] = {
    Role.IMU: (37, False, lambda d: (d[13], d[14], d[15], d[25], d[26], d[27], d[0], d[1], d[2], d[3], d[4])),
    Role.BARO: (2, False, lambda d: (d[0],)),
    Role.TEMPERATURE: (2, False, lambda d: (d[0],)),
    Role.ODOM: (85, True, lambda d: d[0:7] + d[43:49]),
}


class SeriesReader:
    """Barometer, IMU, odometry and temperature series of a log, from its one small-stream pass."""

    def __init__(self, core: LogCore, tf: TfStore) -> None:
        self._core = core
        self._tf = tf
        self.rows: dict[Role, Rows] | None = None
        self.temps: dict[str, Rows] = {}
        self.pressure_unit_seen: PressureUnit | None = None

    def read(self) -> dict[Role, Rows]:
        """Barometer, IMU, odometry and /tf_static, read together in ONE pass over the log.

        Kept as compact rows (floats per message), not message objects, so an hour of IMU
        costs tens of MB. A message that cannot be decoded marks its role only; the error is
        raised when that role is asked for.
        """
        if self.rows is not None:
            return self.rows
        topics = {self._core.roles[r]: r for r in SMALL_ROLES if r in self._core.roles}
        out: dict[Role, Rows] = {role: Rows() for role in topics.values()}
        # Every Temperature topic (unless one is chosen): the barometer's is found by its frame.
        temps = self._temperature_topics()
        self.temps = {name: Rows() for name in temps}
        topics.update({name: Role.TEMPERATURE for name in temps})
        direct: dict[str, bool] = {}  # topic -> the direct parser agreed on its first message
        tf_topics = self._tf.topics() if self._tf.read is None and self._tf.pending is None else []
        tf = self._tf.reader()
        for raw in self._core._iter_raw([*topics, *tf_topics], None, None):
            if raw.topic not in topics:
                tf.add(raw)
                continue
            role = topics[raw.topic]
            rows = self.temps[raw.topic] if role == Role.TEMPERATURE else out[role]
            if rows.error is not None:
                continue
            try:
                if role in _FLAT:
                    if raw.topic not in direct:
                        direct[raw.topic] = self._direct_agrees(raw, role)
                    if direct[raw.topic]:
                        rows.add_row(*self._read_direct(raw, role))
                        continue
                msg = self._core._backend.deserialize(raw)
                rows.add(role, msg, stamp_ns_of(msg, raw.log_time_ns))
            except DecodeError as err:
                rows.error = err
            except (AttributeError, TypeError, ValueError, IndexError, struct.error) as err:
                rows.error = DecodeError(
                    f"unexpected {ROLE_TYPE[role]} layout ({err})", f"{self._core.path} topic {raw.topic}"
                )
        self.rows = out
        if tf_topics:
            self._tf.pending = tf
        return out

    def _read_direct(self, raw: RawMessage, role: Role) -> tuple[int, tuple[float, ...], str, str]:
        """One `_FLAT` message by the direct parser: `Rows.add_row`'s stamp, row and frames
        (the log time when the header's stamp is zero, as `stamp_ns_of`)."""
        n_doubles, child_frame, pick = _FLAT[role]
        encoding, data = self._core._backend.serialized(raw)
        stamp_ns, frame, child, doubles = parse_stamped_doubles(data, encoding, n_doubles, child_frame)
        return stamp_ns or int(raw.log_time_ns), pick(doubles), frame, child

    def _direct_agrees(self, raw: RawMessage, role: Role) -> bool:
        """Does the direct parser read this message exactly as the generic deserialiser does?
        (Not for a message type of the same name with other fields: then the generic one.)"""
        try:
            direct, reference = Rows(), Rows()
            direct.add_row(*self._read_direct(raw, role))
            msg = self._core._backend.deserialize(raw)
            reference.add(role, msg, stamp_ns_of(msg, raw.log_time_ns))
        except Exception:  # any failure: the generic path decides (and reports it)
            return False
        return (direct.stamps, direct.values, direct.frame, direct.child) == (
            reference.stamps, reference.values, reference.frame, reference.child)

    def _role_rows(self, role: Role) -> Rows | None:
        rows = self.read().get(role)
        if rows is not None and rows.error is not None:
            raise rows.error
        return rows

    def pressure(self) -> PressureSeries:
        """Barometer trace in Pa, sorted by stamp. hPa/kPa publishers are converted."""
        topic = self._core._require(Role.BARO, "barometer")
        rows = self._role_rows(Role.BARO)
        if rows is None or not rows.stamps:
            raise MissingDataError(f"no barometer messages on {topic}", self._core.path)
        stamps = np.array(rows.stamps, dtype=np.int64)
        values = np.array(rows.values, dtype=np.float64).reshape(-1)
        order = self._series_order(topic, stamps)
        stamps, values = stamps[order], values[order]
        finite = np.isfinite(values)
        if not finite.all():
            self._core._warn(f"{topic}: dropped {int((~finite).sum())} non-finite pressure readings")
            stamps, values = stamps[finite], values[finite]
        if stamps.shape[0] == 0:
            raise DecodeError(f"every barometer reading is NaN or infinite ({len(rows.stamps)} "
                              "messages): the sensor gave no pressure", f"{self._core.path} topic {topic}")
        unit = self._pressure_unit(values, topic)
        self.pressure_unit_seen = unit
        if unit.to_pa != 1.0:
            values = values * unit.to_pa
            self._core._warn(
                f"{topic}: pressure published in {unit.name} (median {np.median(values) / unit.to_pa:.2f}),"
                f" not Pa as sensor_msgs/FluidPressure specifies; converted to Pa"
            )
        return PressureSeries(stamp_ns=stamps, pressure_pa=values, frame_id=rows.frame)

    def _series_order(self, topic: str, stamps: np.ndarray[Any, Any]) -> np.ndarray[Any, Any]:
        """Indices that sort a small stream by header stamp, its inconsistent stamps and
        repeated ones left out (with a warning)."""
        order, check, repeats = series_order(stamps, int(self._core.config.max_gap_s * 1e9))
        where = f"{self._core.path} topic {topic}"
        if check.dropped:
            self._core._warn(check.describe(f"{where} (header stamps)", int(stamps.min()),
                                      self._core.config.max_gap_s))
        if repeats:
            self._core._warn(f"{where}: dropped {repeats} messages stamped like the one before them")
        return order

    def _pressure_unit(self, values: np.ndarray[Any, Any], topic: str) -> PressureUnit:
        fixed = {"Pa": 1.0, "hPa": 100.0, "kPa": 1000.0}
        if self._core.config.pressure_unit != "auto":
            return PressureUnit(self._core.config.pressure_unit, fixed[self._core.config.pressure_unit])
        unit = pressure_unit(values)
        if unit is None:
            raise DecodeError(
                f"barometer readings (median {float(np.median(values)):.3g}) are not a plausible "
                "air pressure in Pa, hPa or kPa; set ingest.pressure_unit",
                f"{self._core.path} topic {topic}",
            )
        return unit

    def _temperature_topics(self) -> list[str]:
        """The chosen Temperature topic when one is set in the config, else every one with messages."""
        if Role.TEMPERATURE.value in self._core.config.topics:
            return [self._core.roles[Role.TEMPERATURE]]
        return sorted(t.name for t in self._core.topics if t.candidate_for == Role.TEMPERATURE and t.count > 0)

    def temperature(self) -> TemperatureSeries | None:
        """The barometer's air temperature: the sensor_msgs/Temperature topic in the barometer's
        frame (most barometer drivers publish one), or the configured one; None when there is
        none. Temperatures of other frames (a CPU, a motor) say nothing about the air."""
        self.read()
        baro = self.first_frame(Role.BARO) if Role.BARO in self._core.roles else None
        chosen = Role.TEMPERATURE.value in self._core.config.topics
        found = []
        for name, rows in sorted(self.temps.items()):
            if rows.error is not None:
                if chosen:
                    raise rows.error
                self._core._warn(f"{name}: {rows.error}; not used for the barometer's scale")
                continue
            if rows.stamps and (chosen or (baro is not None and rows.frame.lstrip("/") == baro.lstrip("/"))):
                found.append((len(rows.stamps), name, rows))
        if not found:
            if self.temps and baro is not None and not chosen:
                frames = ", ".join(f"{n} ('{r.frame}')" for n, r in sorted(self.temps.items()))
                self._core._warn(f"no Temperature topic in the barometer's frame '{baro}' ({frames}): the "
                           "barometer's scale is not taken from a temperature")
            return None
        _, name, rows = max(found, key=lambda f: (f[0], f[1]))
        stamps = np.array(rows.stamps, dtype=np.int64)
        values = np.array(rows.values, dtype=np.float64).reshape(-1)
        order = np.argsort(stamps, kind="stable")
        finite = np.isfinite(values[order])
        return TemperatureSeries(stamps[order][finite], values[order][finite], rows.frame, name)

    def imu(self) -> ImuSeries | None:
        """IMU samples sorted by stamp, or None when the log has no IMU."""
        rows = self._role_rows(Role.IMU)
        if rows is None or not rows.stamps:
            return None
        stamps = np.array(rows.stamps, dtype=np.int64)
        v = np.array(rows.values, dtype=np.float64)
        order = self._series_order(self._core.roles[Role.IMU], stamps)
        v = v[order]
        quat = v[:, 6:10].copy()
        # orientation_covariance[0] == -1 means "no orientation estimate" (sensor_msgs/Imu).
        quat[v[:, 10] == -1.0] = np.nan
        return ImuSeries(
            stamp_ns=stamps[order],
            gyro_rad_s=v[:, 0:3].copy(),
            accel_m_s2=v[:, 3:6].copy(),
            orientation_xyzw=quat,
            frame_id=rows.frame,
        )

    def odometry(self) -> OdomSeries | None:
        """Odometry sorted by stamp, or None when the log has none."""
        rows = self._role_rows(Role.ODOM)
        if rows is None or not rows.stamps:
            return None
        stamps = np.array(rows.stamps, dtype=np.int64)
        order = self._series_order(self._core.roles[Role.ODOM], stamps)
        v = np.array(rows.values, dtype=np.float64)[order]
        return OdomSeries(
            stamp_ns=stamps[order],
            xyz=v[:, 0:3].copy(),
            quat_xyzw=v[:, 3:7].copy(),
            linear_m_s=v[:, 7:10].copy(),
            angular_rad_s=v[:, 10:13].copy(),
            frame_id=rows.frame,
            child_frame_id=rows.child,
        )

    def first_frame(self, role: Role) -> str | None:
        """The frame of a small stream's first message, once the pass has read it."""
        rows = self.rows.get(role) if self.rows is not None else None
        return rows.frame if rows is not None and rows.stamps else None
