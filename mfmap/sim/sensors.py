"""Sensor models: 3D lidar (per-column motion), 2D laser, IMU, wheel odometry, barometer.

Each model turns the ground-truth trajectory into measurements with realistic noise; random draws
come from generators seeded per sensor, consumed in time order, so runs are deterministic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from mfmap.sim.atmosphere import CALM_AIR
from mfmap.sim.boxes import Kind, cast_rays, kinds_of
from mfmap.sim.building import Building
from mfmap.sim.trajectory import DT_S, RATE_HZ, FArr, Trajectory, rotation_matrices
from mfmap.sim.world import World
from mfmap.types import F32, F64

GRAVITY = 9.81


@dataclass(frozen=True)
class LidarSpec:
    beams: int = 16
    columns: int = 1024
    fov_up_deg: float = 15.0
    fov_down_deg: float = -15.0
    rate_hz: int = 10
    range_min_m: float = 0.3
    range_max_m: float = 60.0
    noise_m: float = 0.015
    dropout: float = 0.02  # share of random no-returns
    cabin_spurious: float = 0.3  # share of cabin-wall hits that return a longer, wrong range


@dataclass(frozen=True)
class LaserSpec:
    samples: int = 720
    fov_deg: float = 360.0
    rate_hz: int = 15
    range_min_m: float = 0.15
    range_max_m: float = 25.0
    noise_m: float = 0.015
    dropout: float = 0.01


@dataclass(frozen=True)
class BaroSpec:
    rate_hz: int = 25
    noise_pa: float = 3.0
    quantum_pa: float = 0.5
    drift_pa_per_h: float = 20.0
    transient_floors: tuple[int, ...] = (1,)  # floors where doors/HVAC make pressure steps
    transient_every_s: float = 45.0


@dataclass(frozen=True)
class Mount:
    """Sensor pose in the base frame."""

    frame: str
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]

    @property
    def rotation(self) -> F64:
        return rotation_matrices(np.array([self.rpy]))[0]

    @property
    def matrix(self) -> F64:
        m = np.eye(4)
        m[:3, :3] = self.rotation
        m[:3, 3] = self.xyz
        return m


LIDAR_MOUNT = Mount("lidar", (0.1, 0.0, 0.5), (0.01, -0.015, 0.03))
LASER_MOUNT = Mount("laser", (0.15, 0.0, 0.3), (0.0, 0.0, 0.0))
IMU_MOUNT = Mount("imu", (0.0, 0.05, 0.2), (0.0, 0.0, 0.0))
BARO_MOUNT = Mount("baro", (-0.1, 0.05, 0.3), (0.0, 0.0, 0.0))

# Ouster-like organised layout: x, y, z, pad, intensity, t (ns from the header stamp), ring, pad.
POINT_DTYPE = np.dtype(
    {
        "names": ["x", "y", "z", "intensity", "t", "ring"],
        "formats": ["<f4", "<f4", "<f4", "<f4", "<u4", "<u2"],
        "offsets": [0, 4, 8, 16, 20, 24],
        "itemsize": 32,
    }
)
POINT_FIELDS = (("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 16, 7), ("t", 20, 6), ("ring", 24, 4))


class Scenes:
    """The building's ray-casting scenes with the elevator's moving parts."""

    def __init__(self, building: Building, traj: Trajectory) -> None:
        self.building = building
        self.traj = traj
        self.cabin_kinds = {c: kinds_of(building.cabin_boxes(c)) for c in (True, False)}

    def cast(self, rays: F32, t_s: FArr, t_scan: float) -> tuple[F32, F32, npt.NDArray[np.bool_]]:
        """Ranges (inf on miss), |cos incidence| and whether the ray hit a cabin wall.

        rays: (N, 6) float32 world-frame origins and unit directions, t_s their firing times."""
        open_floor = self.traj.door_open_at(t_scan)
        r, _, n = cast_rays(self.building.scene(open_floor), rays)
        dirs = rays[:, 3:]
        cos = np.abs((n * dirs).sum(axis=1))
        cabin_wall = np.zeros(len(r), dtype=bool)
        xy = rays[:, :2].mean(axis=0)
        center = self.building.shaft_center
        inside = bool(np.all(np.abs(xy - np.array(center)) < self.building.cabin_half_m))
        if open_floor is not None or inside:
            door_closed = open_floor is None
            local = rays.copy()
            local[:, 0] -= center[0]
            local[:, 1] -= center[1]
            local[:, 2] -= self.traj.cabin_z_at(t_s).astype(np.float32)
            rc, ids, nc = cast_rays(self.building.cabin_scene(door_closed), local)
            closer = rc < r
            r[closer] = rc[closer]
            cos[closer] = np.abs((nc[closer] * dirs[closer]).sum(axis=1))
            kinds = self.cabin_kinds[door_closed]
            hit_ids = np.minimum(ids[closer], len(kinds) - 1)
            cabin_wall[closer] = kinds[hit_ids] == Kind.CABIN_WALL
        return r, cos, cabin_wall


class Lidar:
    def __init__(self, spec: LidarSpec, scenes: Scenes, seed: int) -> None:
        self.spec = spec
        self.scenes = scenes
        self.rng = np.random.default_rng([seed, 11])
        elev = np.radians(np.linspace(spec.fov_up_deg, spec.fov_down_deg, spec.beams))  # row 0 = top
        # Columns sweep clockwise seen from above, starting behind the sensor, like an Ouster.
        az = math.pi - 2 * math.pi * np.arange(spec.columns) / spec.columns
        ce = np.cos(elev)[:, None]
        self.dirs = np.stack(
            [ce * np.cos(az)[None], ce * np.sin(az)[None], np.repeat(np.sin(elev)[:, None], spec.columns, 1)],
            axis=-1,
        )  # (beams, columns, 3) in the lidar frame
        self.dirs_cb = np.ascontiguousarray(self.dirs.transpose(1, 2, 0))  # (columns, 3, beams)
        self.col_dt_ns = round(1e9 / spec.rate_hz / spec.columns)
        n = spec.beams * spec.columns
        self.template = np.zeros(n, dtype=POINT_DTYPE)
        offs_ns = np.arange(spec.columns, dtype=np.int64) * self.col_dt_ns
        self.template["t"] = np.broadcast_to(offs_ns[None], (spec.beams, spec.columns)).reshape(n)
        self.template["ring"] = np.repeat(np.arange(spec.beams, dtype=np.uint16), spec.columns)

    def scan(self, t_s: float) -> npt.NDArray[np.void]:
        """One organised scan (beams x columns points) starting at t_s."""
        s = self.spec
        offs_ns = np.arange(s.columns, dtype=np.int64) * self.col_dt_ns
        t_col = t_s + offs_ns / 1e9
        xyz, rpy = self.scenes.traj.interp(t_col)
        rot = rotation_matrices(rpy)  # base -> world per column
        origin = xyz + rot @ np.array(LIDAR_MOUNT.xyz)  # (C, 3)
        rot_l = rot @ LIDAR_MOUNT.rotation
        n = s.beams * s.columns
        grid = np.empty((s.beams, s.columns, 6), dtype=np.float32)
        grid[:, :, :3] = origin[None]
        # (C, 3, 3) @ (C, 3, B) -> (C, 3, B): every beam of a column turned by that column's pose.
        grid[:, :, 3:] = np.matmul(rot_l, self.dirs_cb).transpose(2, 0, 1)
        rays = grid.reshape(n, 6)
        t_ray = np.broadcast_to(t_col[None], (s.beams, s.columns)).reshape(n)
        r, cos, cabin = self.scenes.cast(rays, t_ray, t_s + 0.5 / s.rate_hz)
        rng = self.rng
        spurious = cabin & (rng.random(n) < s.cabin_spurious)
        r = np.where(spurious, r * rng.uniform(1.2, 2.2, n).astype(np.float32), r)
        r = r + rng.normal(0.0, s.noise_m, n).astype(np.float32)
        valid = np.isfinite(r) & (r > s.range_min_m) & (r < s.range_max_m)
        valid &= rng.random(n) >= s.dropout
        valid &= (cos > 0.1) | (rng.random(n) < 0.5)  # grazing returns are weak
        # np.zeros, not template.copy(): a copy of a padded dtype leaves the padding undefined,
        # and the padding bytes go into the log (determinism).
        pts = np.zeros(n, dtype=POINT_DTYPE)
        pts["t"] = self.template["t"]
        pts["ring"] = self.template["ring"]
        d = self.dirs.reshape(n, 3)
        rr = np.where(valid, r, np.nan)
        pts["x"] = d[:, 0] * rr
        pts["y"] = d[:, 1] * rr
        pts["z"] = d[:, 2] * rr
        inten = 40.0 + 160.0 * cos / (1.0 + 0.05 * np.nan_to_num(r, posinf=60.0)) + rng.normal(0, 3, n)
        inten = np.where(cabin, 900.0, inten)  # polished metal
        pts["intensity"] = np.where(valid, np.clip(inten, 0, None), 0.0)
        return pts


class Laser:
    def __init__(self, spec: LaserSpec, scenes: Scenes, seed: int) -> None:
        self.spec = spec
        self.scenes = scenes
        self.rng = np.random.default_rng([seed, 13])
        fov = math.radians(spec.fov_deg)
        self.angle_min = -fov / 2
        self.angle_inc = fov / spec.samples if spec.fov_deg >= 360 else fov / (spec.samples - 1)
        ang = self.angle_min + self.angle_inc * np.arange(spec.samples)
        self.dirs = np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], axis=1)
        self.time_inc_s = 1.0 / spec.rate_hz / spec.samples

    def scan(self, t_s: float) -> tuple[F32, F32]:
        """Ranges (inf for no return) and intensities of one scan starting at t_s."""
        s = self.spec
        t = t_s + np.arange(s.samples) * self.time_inc_s
        xyz, rpy = self.scenes.traj.interp(t)
        rot = rotation_matrices(rpy)
        rays = np.empty((s.samples, 6), dtype=np.float32)
        rays[:, :3] = xyz + rot @ np.array(LASER_MOUNT.xyz)
        rays[:, 3:] = np.einsum("nij,nj->ni", rot @ LASER_MOUNT.rotation, self.dirs)
        r, cos, cabin = self.scenes.cast(rays, t, t_s + 0.5 / s.rate_hz)
        rng = self.rng
        spurious = cabin & (rng.random(s.samples) < 0.3)
        r = np.where(spurious, r * rng.uniform(1.2, 2.2, s.samples).astype(np.float32), r)
        r = r + rng.normal(0.0, s.noise_m, s.samples).astype(np.float32)
        valid = np.isfinite(r) & (r > s.range_min_m) & (r < s.range_max_m)
        valid &= rng.random(s.samples) >= s.dropout
        ranges = np.where(valid, r, np.inf).astype(np.float32)
        inten = np.where(valid, 100.0 * cos + 20.0, 0.0).astype(np.float32)
        return ranges, inten


@dataclass
class Kinematics:
    """Derived ground truth at the 200 Hz ticks [start, start + len): body rates and specific
    force at the IMU. Computed per window (with a 2-tick halo, so the finite differences equal
    those over the whole trajectory) to keep memory flat in log length."""

    start: int
    gyro: F64  # (n, 3) body angular velocity, rad/s
    specific_force: F64  # (n, 3) at the IMU, m/s^2, IMU frame
    v_forward: F64  # (n,) horizontal speed along the heading, m/s
    yaw_rate: F64  # (n,)

    @classmethod
    def of(cls, traj: Trajectory, i0: int = 0, i1: int | None = None) -> Kinematics:
        n_all = len(traj.xyz)
        i1 = n_all if i1 is None else i1
        lo, hi = max(0, i0 - 2), min(n_all, i1 + 2)
        xyz, rpy = traj.xyz[lo:hi], traj.rpy[lo:hi]
        rot = rotation_matrices(rpy)
        dr = np.gradient(rot, DT_S, axis=0)
        w = np.einsum("nji,njk->nik", rot, dr)  # R^T dR/dt, skew-symmetric
        gyro = 0.5 * np.stack([w[:, 2, 1] - w[:, 1, 2], w[:, 0, 2] - w[:, 2, 0], w[:, 1, 0] - w[:, 0, 1]], axis=1)
        p_imu = xyz + rot @ np.array(IMU_MOUNT.xyz)
        acc = np.gradient(np.gradient(p_imu, DT_S, axis=0), DT_S, axis=0)
        acc[:, 2] += GRAVITY
        r_imu = rot @ IMU_MOUNT.rotation
        f = np.einsum("nji,nj->ni", r_imu, acc)
        vel = np.gradient(xyz, DT_S, axis=0)
        yaw = rpy[:, 2]
        v_fwd = vel[:, 0] * np.cos(yaw) + vel[:, 1] * np.sin(yaw)
        cut = slice(i0 - lo, i1 - lo)
        return cls(i0, gyro[cut], f[cut], v_fwd[cut], np.gradient(yaw, DT_S)[cut])


class Imu:
    # White noise per sample at 200 Hz (the accelerometer's: 300 ug/sqrt(Hz) on a datasheet) and
    # the spread of the accelerometer's bias, drawn once per log.
    ACCEL_NOISE_M_S2 = 0.03
    GYRO_NOISE_RAD_S = 0.003
    ACCEL_BIAS_M_S2 = 0.03

    def __init__(self, traj: Trajectory, seed: int) -> None:
        self.traj = traj
        self.rng = np.random.default_rng([seed, 17])
        self.gyro_bias = self.rng.normal(0, 0.002, 3)
        self.acc_bias = self.rng.normal(0, self.ACCEL_BIAS_M_S2, 3)
        self.yaw_drift_rad_s = math.radians(0.3) / 60 * (1 if self.rng.random() < 0.5 else -1)

    def samples(self, kin: Kinematics) -> tuple[F64, F64, F64]:
        """Orientation (x, y, z, w), angular velocity and linear acceleration for kin's ticks."""
        from mfmap.sim.trajectory import quaternions

        n = len(kin.gyro)
        i0, i1 = kin.start, kin.start + n
        rng = self.rng
        self.gyro_bias = self.gyro_bias + rng.normal(0, 2e-5, 3)  # slow random walk per window
        gyro = kin.gyro + self.gyro_bias + rng.normal(0, self.GYRO_NOISE_RAD_S, (n, 3))
        acc = kin.specific_force + self.acc_bias + rng.normal(0, self.ACCEL_NOISE_M_S2, (n, 3))
        rpy = self.traj.rpy[i0:i1].copy()
        rpy[:, :2] += rng.normal(0, math.radians(0.1), (n, 2))
        rpy[:, 2] += self.yaw_drift_rad_s * np.arange(i0, i1) * DT_S
        return quaternions(rpy), gyro, acc


class WheelOdometry:
    """Pose integrated from noisy forward speed and yaw rate: scale error, slow yaw drift."""

    RATE_HZ = 50

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng([seed, 19])
        self.scale = 1.0 + self.rng.normal(0, 0.02)
        self.yaw_scale = 1.0 + self.rng.normal(0, 0.01)
        self.yaw_bias = self.rng.normal(0, 2e-4)
        self.x = self.y = self.yaw = 0.0

    def step(self, kin: Kinematics, i: int) -> tuple[float, float, float, float, float]:
        """Advance to tick i (every 4th tick, inside kin's window); returns x, y, yaw, v, yaw_rate."""
        dt = 1.0 / self.RATE_HZ
        v_true = float(kin.v_forward[i - kin.start])
        w_true = float(kin.yaw_rate[i - kin.start])
        moving = abs(v_true) > 1e-3 or abs(w_true) > 1e-3
        self.yaw_bias += self.rng.normal(0, 2e-6)
        if moving:
            v = v_true * self.scale + self.rng.normal(0, 0.005)
            w = w_true * self.yaw_scale + self.yaw_bias + self.rng.normal(0, 0.003)
        else:
            v = w = 0.0  # encoders read zero when the wheels stand still
        self.yaw += w * dt
        self.x += v * dt * math.cos(self.yaw)
        self.y += v * dt * math.sin(self.yaw)
        return self.x, self.y, self.yaw, v, w


class Barometer:
    """Hydrostatic pressure at the sensor (the simulator's own air column) plus weather drift,
    transients, noise, quantisation; and, from the world, the zone the sensor is in (stack
    effect, ventilation, doors, the cabin) and the weather beyond the spec's drift."""

    def __init__(
        self, spec: BaroSpec, traj: Trajectory, p0_pa: float, seed: int, world: World | None = None
    ) -> None:
        self.spec = spec
        self.traj = traj
        self.p0_pa = p0_pa
        self.seed = seed
        self.world = world
        self.air = world.air if world is not None else CALM_AIR
        rng = np.random.default_rng([seed, 23])
        self.rng = rng
        self.drift_sign = 1.0 if rng.random() < 0.5 else -1.0
        self.wander_phase = float(rng.uniform(0, 2 * math.pi))
        self.transients: list[tuple[float, float, float]] = []
        for floor, t0, t1 in traj.floor_visits:
            if floor not in spec.transient_floors:
                continue
            t = t0 + float(rng.exponential(spec.transient_every_s))
            while t < t1 - 2.0:
                dur = float(rng.uniform(2.0, 8.0))
                dp = float(rng.uniform(5.0, 15.0)) * (1 if rng.random() < 0.5 else -1)
                self.transients.append((t, min(t + dur, t1), dp))
                t += dur + float(rng.exponential(spec.transient_every_s))

    def reference(self, t_s: FArr) -> F64:
        """Pressure at world z = 0 in the shaft's air without noise: weather drift, slow wander,
        transients and the world's weather."""
        s = self.spec
        p = self.p0_pa + self.drift_sign * s.drift_pa_per_h * t_s / 3600.0
        p = p + 1.5 * np.sin(2 * math.pi * t_s / 900.0 + self.wander_phase)
        for t0, t1, dp in self.transients:
            # Short ramps: a door or an air handler takes a fraction of a second to change it.
            p = p + dp * np.clip((t_s - t0) / 0.3, 0, 1) * np.clip((t1 - t_s) / 0.3, 0, 1)
        if self.world is not None:
            p = p + self.world.weather_pa(np.asarray(t_s, dtype=np.float64))
        return np.asarray(p, dtype=np.float64)

    def true_height(self, i: F64 | npt.NDArray[np.int64]) -> F64:
        rot = rotation_matrices(self.traj.rpy[i])
        return self.traj.xyz[i, 2] + (rot @ np.array(BARO_MOUNT.xyz))[:, 2]

    def clean(self, ticks: npt.NDArray[np.int64]) -> F64:
        """The pressure at the sensor without the sensor's own noise and quantisation."""
        t = ticks * DT_S
        p = self.air.pressure_pa(self.true_height(ticks), self.reference(t))
        if self.world is not None and len(self.world.offsets):
            p = p + self.world.offsets[ticks]
        return p

    def samples(self, ticks: npt.NDArray[np.int64]) -> F64:
        p = self.clean(ticks)
        p = p + self.rng.normal(0, self.spec.noise_pa, len(ticks))
        return np.round(p / self.spec.quantum_pa) * self.spec.quantum_pa


class Thermometer:
    """The barometer chip's temperature (sensor_msgs/Temperature in the barometer's frame)."""

    def __init__(self, world: World, baro: Barometer, duration_s: int, seed: int) -> None:
        assert world.thermometer is not None
        self.rate_hz = world.thermometer.spec.rate_hz
        self.noise_k = world.thermometer.spec.noise_k
        n = duration_s * self.rate_hz
        t = np.arange(n) / self.rate_hz
        ticks = np.arange(n) * (RATE_HZ // self.rate_hz)
        self.celsius = world.chip_temperature_c(t, baro.true_height(ticks), np.random.default_rng([seed, 43]))


assert RATE_HZ == 200
