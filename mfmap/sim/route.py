"""Routes: motion primitives appended to the robot's pose at 200 Hz, building its `Trajectory`.

`RouteBase` drives on a floor (corners rounded, speed limited by the curvature), turns in place,
waits, stands at checkpoints and rides the elevator; `RouteBuilder` also walks the stairwell's
straight or switch-back flights.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from mfmap.sim.building import Building
from mfmap.sim.spec import StairGeometry
from mfmap.sim.trajectory import DT_S, RATE_HZ, Checkpoint, Trajectory, TransitionEvent
from mfmap.types import F64

YAW_RATE_MAX = 0.6  # rad/s
YAW_ACC_MAX = 1.0  # rad/s^2
ACC_MAX = 0.4  # m/s^2
STAIR_SPEED = 0.35  # m/s along the flight


def time_parametrize(ds: F64, v_limit: F64, acc: float) -> F64:
    """Times at the nodes of a path (spacings `ds`, speed limits per node), starting and ending
    at rest, accelerating at most `acc`. Classic forward/backward pass."""
    n = len(v_limit)
    v = v_limit.copy()
    v[0] = v[-1] = 0.0
    for i in range(1, n):
        v[i] = min(v[i], math.sqrt(v[i - 1] ** 2 + 2 * acc * ds[i - 1]))
    for i in range(n - 2, -1, -1):
        v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2 * acc * ds[i]))
    v_mid = np.maximum((v[:-1] + v[1:]) / 2, 1e-3)
    return np.concatenate([[0.0], np.cumsum(ds / v_mid)])


def profile_1d(distance: float, v_max: float, acc: float) -> F64:
    """Fraction of `distance` covered (0..1) at each 200 Hz tick of a rest-to-rest move."""
    if distance <= 1e-9:
        return np.zeros(0)
    n = max(20, int(distance / 0.002))
    ds = np.full(n, distance / n)
    t = time_parametrize(ds, np.full(n + 1, v_max), acc)
    s = np.linspace(0.0, 1.0, n + 1)
    ticks = np.arange(1, math.ceil(t[-1] / DT_S) + 1) * DT_S
    return np.interp(ticks, t, s)


@dataclass
class RouteBase:
    """A route's state and its moves on a floor and in the elevator; `finish` returns the
    trajectory."""

    building: Building
    floor: int
    rng: np.random.Generator
    v_max: float = 0.8
    xyz: list[F64] = field(default_factory=list)
    rpy: list[F64] = field(default_factory=list)
    checkpoints: list[Checkpoint] = field(default_factory=list)
    transitions: list[TransitionEvent] = field(default_factory=list)
    door_open: list[tuple[float, float, int]] = field(default_factory=list)
    cabin_z: list[tuple[float, float]] = field(default_factory=list)
    visits: list[tuple[int, float, float]] = field(default_factory=list)
    labelled: set[tuple[str, int]] = field(default_factory=set)
    _door_t0: float | None = None
    _visit_t0: float = 0.0

    def __post_init__(self) -> None:
        z = self.building.elevation(self.floor)
        self.xyz.append(np.array([[0.0, 0.0, z]]))
        self.rpy.append(np.zeros((1, 3)))
        self.cabin_z.append((0.0, z))

    # -- state ------------------------------------------------------------------------
    @property
    def t(self) -> float:
        return (sum(len(a) for a in self.xyz) - 1) * DT_S

    @property
    def pos(self) -> F64:
        return self.xyz[-1][-1]

    @property
    def yaw(self) -> float:
        return float(self.rpy[-1][-1, 2])

    def _append(self, xyz: F64, rpy: F64) -> None:
        if len(xyz):
            self.xyz.append(xyz)
            self.rpy.append(rpy)

    # -- primitives -------------------------------------------------------------------
    def wait(self, seconds: float) -> None:
        n = round(seconds / DT_S)
        self._append(np.repeat(self.pos[None], n, 0), np.repeat(self.rpy[-1][-1:], n, 0))

    def turn_to(self, yaw: float) -> None:
        d = (yaw - self.yaw + math.pi) % (2 * math.pi) - math.pi
        if abs(d) < 1e-3:
            return
        frac = profile_1d(abs(d), YAW_RATE_MAX, YAW_ACC_MAX)
        rpy = np.repeat(self.rpy[-1][-1:], len(frac), 0)
        rpy[:, 2] = self.yaw + d * frac
        self._append(np.repeat(self.pos[None], len(frac), 0), rpy)

    def drive(self, *points: tuple[float, float], v_max: float | None = None) -> None:
        """Drive through `points` on the current floor, corners rounded, stopping at the last."""
        v_max = v_max or self.v_max
        poly = np.array([self.pos[:2], *points], dtype=np.float64)
        if np.abs(np.diff(poly, axis=0)).sum() < 1e-3:
            return
        path = smooth_path(poly)
        seg = np.diff(path, axis=0)
        ds = np.linalg.norm(seg, axis=1)
        heading = np.unwrap(np.arctan2(seg[:, 1], seg[:, 0]))
        head0 = float(np.arctan2(*(path[min(30, len(path) - 1)] - path[0])[::-1]))
        self.turn_to(head0)
        # Keep heading continuous with the robot's (unwrapped) yaw.
        heading += round((self.yaw - heading[0]) / (2 * math.pi)) * 2 * math.pi
        kappa = np.abs(np.gradient(heading) / np.maximum(ds, 1e-6))
        kappa = np.convolve(kappa, np.ones(15) / 15, mode="same")
        v_lim = np.minimum(v_max, YAW_RATE_MAX / np.maximum(kappa, 1e-6))
        v_lim = np.concatenate([v_lim, [v_lim[-1]]])
        t = time_parametrize(ds, v_lim, ACC_MAX)
        ticks = np.arange(1, math.ceil(t[-1] / DT_S) + 1) * DT_S
        xy = np.stack([np.interp(ticks, t, path[:, 0]), np.interp(ticks, t, path[:, 1])], axis=1)
        node_heading = np.concatenate([heading, [heading[-1]]])
        yaw = np.interp(ticks, t, node_heading)
        z = np.full(len(ticks), self.pos[2])
        rpy = np.zeros((len(ticks), 3))
        rpy[:, 2] = yaw
        self._append(np.column_stack([xy, z]), rpy)

    def goto(self, xy: tuple[float, float], v_max: float | None = None) -> None:
        """Drive to xy along the building's corridors (both ends on a corridor's centre line)."""
        from mfmap.sim.layout import plan_path

        path = plan_path(self.building.spec.corridors, (float(self.pos[0]), float(self.pos[1])), xy)
        if path:
            self.drive(*path, v_max=v_max)

    def checkpoint(self, label: str, seconds: float = 5.0) -> None:
        """Stand still for `seconds`; the first visit of (label, floor) goes to gt_points.csv."""
        t0 = self.t
        self.wait(seconds)
        key = (label, self.floor)
        if key not in self.labelled:
            self.labelled.add(key)
            x, y, z = (float(v) for v in self.pos)
            self.checkpoints.append(Checkpoint(label, self.floor, x, y, z, t0, self.t))

    def _open_doors(self) -> None:
        self._door_t0 = self.t

    def _close_doors(self, floor: int | None = None) -> None:
        assert self._door_t0 is not None
        self.door_open.append((self._door_t0, self.t, self.floor if floor is None else floor))
        self._door_t0 = None

    def elevator(self, to_floor: int, stops: Sequence[int] = (), stop_s: float = 5.0) -> None:
        """Drive into the elevator from its front, ride to `to_floor`, drive out to its front.
        At each floor of `stops` on the way the cabin halts and its doors open and close for
        `stop_s` while the robot stays inside (someone else's call)."""
        sh = self.building.spec.shaft
        cx, cy = sh.center
        nx, ny = sh.door_normal
        self.drive(sh.front, v_max=0.6)
        self.turn_to(math.atan2(-ny, -nx))
        self._call_cabin()
        self.wait(1.0)
        self._open_doors()
        self.wait(1.0)
        self.drive((cx, cy), v_max=0.5)
        self.turn_to(math.atan2(ny, nx))
        self.wait(1.0)
        self._close_doors()
        self.wait(1.0)
        z0 = self.building.elevation(self.floor)
        z1 = self.building.elevation(to_floor)
        t_start = self.t
        for i, target in enumerate([*stops, to_floor]):
            self._ride_to(self.building.elevation(target))
            if i < len(stops):
                self.wait(1.0)
                self._open_doors()
                self.wait(stop_s)
                self._close_doors(target)
                self.wait(1.0)
        self._transition("elevator", to_floor, t_start, (cx, cy), (cx, cy), z1 - z0)
        self.wait(1.0)
        self._open_doors()
        self.wait(1.0)
        self.drive(sh.front, v_max=0.5)
        self.wait(0.5)
        self._close_doors()

    def _ride_to(self, z1: float) -> None:
        sh = self.building.spec.shaft
        z0 = float(self.pos[2])
        frac = profile_1d(abs(z1 - z0), sh.speed_m_s, sh.acc_m_s2)
        t_start = self.t
        xyz = np.repeat(self.pos[None], len(frac), 0)
        xyz[:, 2] = z0 + (z1 - z0) * frac
        # The cabin floor carries the robot: knots at every tick of the ride.
        self.cabin_z.append((t_start, z0))
        self.cabin_z += [(t_start + (i + 1) * DT_S, float(z)) for i, z in enumerate(xyz[:, 2])]
        self._append(xyz, np.repeat(self.rpy[-1][-1:], len(frac), 0))

    def _call_cabin(self) -> None:
        # An empty cabin comes to the robot's floor while it waits (doors closed, unseen).
        z_here = self.building.elevation(self.floor)
        z_cabin = self.cabin_z[-1][1]
        if abs(z_cabin - z_here) > 1e-6:
            self.cabin_z.append((self.t, z_cabin))
            self.cabin_z.append((self.t + 0.5, z_here))

    def _transition(
        self, kind: str, to_floor: int, t_start: float, xy0: tuple[float, float],
        xy1: tuple[float, float], dz: float,
    ) -> None:
        self.transitions.append(
            TransitionEvent(kind, self.floor, to_floor, t_start, self.t, xy0[0], xy0[1], xy1[0], xy1[1], dz)
        )
        self.visits.append((self.floor, self._visit_t0, t_start))
        self._visit_t0 = self.t
        self.floor = to_floor

    def _draw(self, r: tuple[float, float]) -> float:
        return float(r[0]) if r[1] <= r[0] else float(self.rng.uniform(*r))

    def finish(self, rng: np.random.Generator) -> Trajectory:
        """Pad to whole seconds plus one, add floor-unevenness wobble, return the trajectory."""
        n = sum(len(a) for a in self.xyz)
        pad = (-(n - 1)) % RATE_HZ + RATE_HZ
        self.wait(pad * DT_S)
        self.visits.append((self.floor, self._visit_t0, self.t))
        xyz = np.concatenate(self.xyz)
        rpy = np.concatenate(self.rpy)
        speed = np.linalg.norm(np.gradient(xyz[:, :2], axis=0), axis=1) / DT_S
        moving = np.clip(speed / 0.5, 0, 1)
        for axis in (0, 1):
            noise = smooth_series(rng.normal(0, 1, len(xyz)), 40)
            noise *= np.radians(0.25) / max(float(np.std(noise)), 1e-9)
            rpy[:, axis] += noise * moving
        cabin = [*self.cabin_z, (self.t, self.cabin_z[-1][1])]
        return Trajectory(xyz, rpy, self.checkpoints, self.transitions, self.door_open, cabin, self.visits)


class RouteBuilder(RouteBase):
    """A `RouteBase` that also walks the stairwell: one straight flight up, or switch-back flights up
    or down through the floors between."""

    def stairs_up(self) -> None:
        """Walk up one straight flight of the stairwell from the corridor to the corridor."""
        b = self.building
        st = b.spec.stairwell
        if st.kind != "straight":
            raise ValueError("stairs_up walks straight flights; use stairs() for switch-backs")
        k = self.floor
        if k >= b.n_floors - 1:
            raise ValueError("no floor above")
        geo = b.flights[k]
        tread = st.tread_m
        even = k % 2 == 0
        lane_y = sum(st.lane_a if even else st.lane_b) / 2
        x_land0 = sum(st.doors_x[0]) / 2 if even else sum(st.doors_x[1]) / 2
        x_land1 = sum(st.doors_x[1]) / 2 if even else sum(st.doors_x[0]) / 2
        x0 = st.flight_x0 if even else geo.flight_x1
        x1 = geo.flight_x1 if even else st.flight_x0
        sgn = 1.0 if even else -1.0
        x_start = x0 - sgn * 0.5
        x_end = x1 + sgn * 0.5
        y_out = st.door_wall_y + st.outward * st.approach_m
        y_in = st.door_wall_y - st.outward * 0.8
        self.drive((x_land0, y_out), v_max=0.5)
        self.drive((x_land0, y_in), (x_land0, lane_y), (x_start, lane_y), v_max=0.4)
        self.turn_to(0.0 if even else math.pi)
        # Climb: horizontal motion along the lane, base height on the line through the nosings,
        # the carrier pitched up with the slope and a small bounce on every step.
        length = abs(x_end - x_start)
        frac = profile_1d(length, STAIR_SPEED, 0.3)
        xs = x_start + sgn * length * frac
        rise = b.storey_height(k)
        u = np.clip((sgn * (xs - x0) + 0.5 * tread) / (abs(x1 - x0) + tread), 0, 1)
        z_lin = b.elevation(k) + rise * u
        # Smooth the corners of the z profile over ~0.4 m of travel.
        z = smooth_series(z_lin, max(3, int(0.4 / max(STAIR_SPEED * DT_S, 1e-6))))
        bounce = 0.01 * np.sin(2 * np.pi * np.abs(xs - x0) / tread) * (u > 0) * (u < 1)
        z = z + bounce
        slope = np.gradient(z_lin) / np.maximum(np.abs(np.gradient(xs)), 1e-9)
        pitch = -0.7 * np.arctan(smooth_series(slope, 80))
        t_start = self.t
        xyz = np.column_stack([xs, np.full(len(xs), lane_y), z])
        rpy = np.zeros((len(xs), 3))
        rpy[:, 1] = pitch
        rpy[:, 2] = self.yaw
        self._append(xyz, rpy)
        self._transition("stairs", k + 1, t_start, (x_start, lane_y), (x_end, lane_y), rise)
        self.pos[2] = b.elevation(k + 1)  # exact floor height (pos is a view of the last sample)
        self.rpy[-1][-1, 1] = 0.0
        self.drive((x_land1, y_in), (x_land1, y_out), v_max=0.4)

    def stairs(
        self,
        to_floor: int,
        landing_pause_s: tuple[float, float] = (0.0, 0.0),
        mid_flight_pause_s: tuple[float, float] = (0.0, 0.0),
        mid_flight_pause_share: float = 0.0,
    ) -> None:
        """Walk a switch-back stairwell from this floor's corridor to `to_floor`'s, up or down,
        through the floors between without leaving the stairwell (one transition). On each half
        landing the carrier stands for a time drawn from `landing_pause_s`; on a share
        `mid_flight_pause_share` of the flights it stops halfway for `mid_flight_pause_s`."""
        b = self.building
        st = b.spec.stairwell
        if st.kind != "switchback":
            raise ValueError("stairs() walks switch-back flights; use stairs_up() for straight ones")
        k0 = self.floor
        if not 0 <= to_floor < b.n_floors or to_floor == k0:
            raise ValueError(f"no stairs from floor {k0} to floor {to_floor}")
        sgn = -1.0 if st.reverse else 1.0
        ya, yb = sum(st.lane_a) / 2, sum(st.lane_b) / 2
        x_door = sum(st.doors_x[0]) / 2
        x_start = st.flight_x0 - sgn * 0.4
        y_out = st.door_wall_y + st.outward * st.approach_m
        up = to_floor > k0
        self.drive((x_door, y_out), v_max=0.5)
        self.drive((x_door, ya), v_max=0.4)
        lane0 = ya if up else yb
        if lane0 != ya:
            self.drive((x_door, lane0), v_max=0.3)
        self.drive((x_start, lane0), v_max=0.3)
        t_start = self.t
        xy0 = (x_start, lane0)
        storeys = range(k0, to_floor) if up else range(k0 - 1, to_floor - 1, -1)
        for n, k in enumerate(storeys):
            if n > 0:  # a floor passed through: across its landing to the next flight
                self.drive((x_start, ya if up else yb), v_max=0.3)
            geo = b.flights[k]
            e, h = b.elevation(k), b.storey_height(k)
            far = st.flight_x0 + sgn * geo.run_m
            x_mid = far + sgn * 0.5
            z_mid = e + h / 2
            first = (ya, e, z_mid) if up else (yb, e + h, z_mid)
            second = (yb, z_mid, e + h) if up else (ya, z_mid, e)
            # Lane a rises from the floor landing (x_start side), lane b from the half landing.
            lane_a, lane_b = (st.flight_x0, far), (far, st.flight_x0)
            self._flight(x_start, x_mid, first, lane_a if up else lane_b, geo, mid_flight_pause_s, mid_flight_pause_share)
            self.wait(self._draw(landing_pause_s))
            self.drive((x_mid, second[0]), v_max=0.3)
            self._flight(x_mid, x_start, second, lane_b if up else lane_a, geo, mid_flight_pause_s, mid_flight_pause_share)
        lane1 = yb if up else ya
        self._transition("stairs", to_floor, t_start, xy0, (x_start, lane1), b.elevation(to_floor) - b.elevation(k0))
        self.drive((x_door, lane1), v_max=0.3)
        if lane1 != ya:
            self.drive((x_door, ya), v_max=0.3)
        self.drive((x_door, y_out), v_max=0.4)

    def _flight(
        self,
        x_from: float,
        x_to: float,
        lane: tuple[float, float, float],
        ends: tuple[float, float],
        geo: StairGeometry,
        pause_s: tuple[float, float],
        pause_share: float,
    ) -> None:
        """Carry the robot along one half flight from x_from to x_to in the lane at y = lane[0],
        from height lane[1] to lane[2]; `ends` are the x of the flight's bottom and top risers.
        Height, bounce and pitch are functions of the position, so a pause mid-flight holds them."""
        y, z_from, z_to = lane
        x_low, x_high = ends
        rising = 1.0 if x_high > x_low else -1.0
        tread = self.building.spec.stairwell.tread_m
        self.turn_to(0.0 if x_to > x_from else math.pi)
        length = abs(x_to - x_from)
        s = np.linspace(0.0, length, max(3, int(length / 0.005) + 1))
        xs = x_from + np.sign(x_to - x_from) * s
        z_lo, z_hi = min(z_from, z_to), max(z_from, z_to)
        u = np.clip((rising * (xs - x_low) + 0.5 * tread) / (geo.run_m + tread), 0, 1)
        z_lin = z_lo + (z_hi - z_lo) * u
        ds = float(s[1] - s[0])
        z = smooth_series(z_lin, max(3, int(0.4 / ds)))
        z = z + 0.01 * np.sin(2 * np.pi * np.abs(xs - x_low) / tread) * (u > 0) * (u < 1)
        slope = np.gradient(z_lin) / ds
        pitch = -0.7 * np.arctan(smooth_series(slope, max(3, int(0.14 / ds))))
        stop = pause_share > 0 and self.rng.random() < pause_share
        legs = [(0.0, 0.5 * length), (0.5 * length, length)] if stop else [(0.0, length)]
        for i, (s0, s1) in enumerate(legs):
            if i:
                self.wait(self._draw(pause_s))
            frac = profile_1d(s1 - s0, STAIR_SPEED, 0.3)
            sq = s0 + (s1 - s0) * frac
            xyz = np.column_stack([np.interp(sq, s, xs), np.full(len(sq), y), np.interp(sq, s, z)])
            rpy = np.zeros((len(sq), 3))
            rpy[:, 1] = np.interp(sq, s, pitch)
            rpy[:, 2] = self.yaw
            self._append(xyz, rpy)
        self.pos[2] = z_to  # exact landing height (pos is a view of the last sample)
        self.rpy[-1][-1, 1] = 0.0


def smooth_series(x: F64, width: int) -> F64:
    """Moving average that keeps the ends in place (odd reflection)."""
    if width < 2 or len(x) < 3:
        return x
    half = min(width // 2, len(x) - 1)
    pad_lo = 2 * x[0] - x[half:0:-1]
    pad_hi = 2 * x[-1] - x[-2 : -half - 2 : -1]
    xp = np.concatenate([pad_lo, x, pad_hi])
    kernel = np.ones(2 * half + 1) / (2 * half + 1)
    return np.convolve(xp, kernel, mode="valid")


def smooth_path(poly: F64, step_m: float = 0.01, corner_m: float = 1.2) -> F64:
    """A polyline sampled every `step_m`, corners rounded by a moving average over `corner_m`."""
    keep = np.concatenate([[True], np.linalg.norm(np.diff(poly, axis=0), axis=1) > 1e-6])
    poly = poly[keep]
    if len(poly) < 2:
        return np.repeat(poly, 2, 0)
    seg = np.linalg.norm(np.diff(poly, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    n = max(2, int(s[-1] / step_m) + 1)
    q = np.linspace(0, s[-1], n)
    pts = np.column_stack([np.interp(q, s, poly[:, 0]), np.interp(q, s, poly[:, 1])])
    width = int(corner_m / step_m)
    out = np.column_stack([smooth_series(pts[:, 0], width), smooth_series(pts[:, 1], width)])
    # Re-sample by arc length so the spacing is uniform again after the smoothing.
    seg = np.linalg.norm(np.diff(out, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    n = max(2, int(s[-1] / step_m) + 1)
    q = np.linspace(0, s[-1], n)
    return np.column_stack([np.interp(q, s, out[:, 0]), np.interp(q, s, out[:, 1])])
