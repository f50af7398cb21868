"""The building's air as a barometer meets it: temperature, stack effect, zones, doors, cabin,
weather; and the temperature a barometer chip reports.

A real building is not one column of still air at a known temperature:
- the air temperature (0-40 deg C in buildings people work in), its humidity and the local
  gravity set the pressure-to-height scale: about 0.34 % per kelvin;
- the stack effect holds the floors at other pressures than the shafts that join them: with the
  outdoor air colder than the indoor, a floor above the neutral plane is below the shaft's
  pressure, one below it above, by a share of (rho_out - rho_in) * g * (z - z_npl); ventilation
  adds each floor's and each shaft's own offset (a few Pa, that is tens of centimetres);
- the pressure at the sensor moves from one zone's to the next's when it passes a door, and an
  opening or closing door pushes a short pulse of air;
- a closed elevator cabin follows the shaft's pressure with a lag, and a moving cabin adds a
  piston pressure that grows with its speed squared;
- the weather trends and curves over an hour and gusts of wind shake the building's pressure
  over seconds.

`WorldSpec` holds the ranges; `World.draw` draws one building's values from the seed. The
default WorldSpec is the calm building (295 K, dry, standard gravity, no offsets or lags), in
which the barometer is what it always was; `WorldSpec.harsh()` switches everything on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from mfmap.sim.atmosphere import (
    CALM_TEMPERATURE_K,
    G_STANDARD_M_S2,
    KELVIN,
    R_DRY_AIR_J_PER_KG_K,
    AirColumn,
    normal_gravity_m_s2,
    virtual_temperature_k,
)
from mfmap.types import F64

if TYPE_CHECKING:
    from mfmap.sim.building import Building
    from mfmap.sim.trajectory import Trajectory

Range = tuple[float, float]

# The stack effect's pressure on a floor is taken at this height above its slab (a person's
# height: where the doors' leakage is, on average).
_FLOOR_PROBE_M = 1.5


@dataclass(frozen=True)
class TemperatureSpec:
    """The barometer's own temperature output (sensor_msgs/Temperature in its frame): the chip's
    temperature, not the air's. It runs warm from its own electronics (self-heating reached with
    a time constant after power-up), carries a calibration bias, lags the air's changes."""

    rate_hz: int = 5
    self_heating_k: Range = (0.5, 3.0)
    warmup_s: Range = (120.0, 600.0)
    bias_k: Range = (-0.5, 0.5)
    lag_s: Range = (20.0, 90.0)
    noise_k: float = 0.02
    quantum_k: float = 0.01


@dataclass(frozen=True)
class WorldSpec:
    """Ranges (lo, hi) drawn uniformly per log; a range with lo == hi is a fixed value."""

    air_temperature_c: Range = (CALM_TEMPERATURE_K - KELVIN, CALM_TEMPERATURE_K - KELVIN)
    temperature_gradient_k_per_m: Range = (0.0, 0.0)  # warm air rises: > 0 indoors
    relative_humidity: Range = (0.0, 0.0)
    latitude_deg: Range | None = None  # None: standard gravity
    # Stack effect: None is off; else the outdoor minus the indoor temperature.
    outdoor_minus_indoor_k: Range | None = None
    floor_stack_share: Range = (0.1, 0.5)  # share of the stack pressure across a floor's doors
    stair_stack_share: Range = (0.0, 0.15)
    neutral_plane_share: Range = (0.3, 0.7)  # neutral plane's height, share of the building's
    floor_hvac_pa: float = 0.0  # each floor's own offset, uniform in +-this
    shaft_offset_pa: float = 0.0  # the elevator shaft's own offset, uniform in +-this
    stair_offset_pa: Range = (0.0, 0.0)  # the stairwell's pressurisation
    door_mix_s: Range = (0.0, 0.0)  # time constant of the change of zone through a door
    cabin_lag_s: Range = (0.0, 0.0)  # time constant of a closed cabin following the shaft
    piston_pa_s2_per_m2: Range = (0.0, 0.0)  # cabin pressure per (speed * |speed|)
    door_pulse_pa: Range = (0.0, 0.0)  # |pulse| of a door opening or closing
    door_pulse_s: Range = (0.4, 1.5)  # its decay time
    weather_trend_pa_per_h: Range = (0.0, 0.0)  # |trend| on top of BaroSpec's drift
    weather_curvature_pa_per_h2: Range = (0.0, 0.0)
    gust_pa: Range = (0.0, 0.0)  # standard deviation of wind-gust pressure
    gust_s: Range = (3.0, 20.0)  # its correlation time
    temperature_sensor: TemperatureSpec | None = None

    @classmethod
    def harsh(cls) -> WorldSpec:
        """Everything on, over the ranges of real office buildings."""
        return cls(
            air_temperature_c=(0.0, 40.0),
            temperature_gradient_k_per_m=(0.0, 0.25),
            relative_humidity=(0.15, 0.85),
            latitude_deg=(0.0, 65.0),
            outdoor_minus_indoor_k=(-30.0, 12.0),
            floor_hvac_pa=3.0,
            shaft_offset_pa=4.0,
            stair_offset_pa=(0.0, 12.0),
            door_mix_s=(0.3, 1.2),
            cabin_lag_s=(0.2, 1.2),
            piston_pa_s2_per_m2=(0.5, 4.0),
            door_pulse_pa=(1.0, 6.0),
            weather_trend_pa_per_h=(10.0, 120.0),
            weather_curvature_pa_per_h2=(0.0, 40.0),
            gust_pa=(0.2, 1.5),
            temperature_sensor=TemperatureSpec(),
        )

    @property
    def calm(self) -> bool:
        """No zone offsets, lags or pulses: the barometer sees the air column alone."""
        return (
            self.outdoor_minus_indoor_k is None
            and self.floor_hvac_pa == 0.0
            and self.shaft_offset_pa == 0.0
            and self.stair_offset_pa == (0.0, 0.0)
            and self.door_mix_s == (0.0, 0.0)
            and self.cabin_lag_s == (0.0, 0.0)
            and self.piston_pa_s2_per_m2 == (0.0, 0.0)
            and self.door_pulse_pa == (0.0, 0.0)
        )


def _draw(rng: np.random.Generator, r: Range) -> float:
    lo, hi = r
    return float(lo) if hi <= lo else float(rng.uniform(lo, hi))


@dataclass(frozen=True)
class ThermometerState:
    spec: TemperatureSpec
    self_heating_k: float
    warmup_s: float
    bias_k: float
    lag_s: float


@dataclass
class World:
    """One building's air, drawn from a WorldSpec."""

    spec: WorldSpec
    air_temperature_k: float  # dry bulb at world z = 0
    relative_humidity: float
    air: AirColumn
    outdoor_temperature_k: float | None
    stack_pa_per_m: float  # (rho_out - rho_in) * g; > 0 when the outside is colder
    neutral_plane_m: float
    floor_offsets_pa: list[float]  # per building floor: stack and ventilation, from the shaft
    floor_stack_share: float
    stair_stack_share: float
    shaft_offset_pa: float
    stair_offset_pa: float
    door_mix_s: float
    cabin_lag_s: float
    piston_pa_s2_per_m2: float
    door_pulse_s: float
    weather_trend_pa_per_h: float  # signed
    weather_curvature_pa_per_h2: float  # signed
    gust_pa: float
    gust_s: float
    thermometer: ThermometerState | None
    seed: int
    door_pulses: list[tuple[float, float]] = field(default_factory=list)  # (t, signed Pa)
    # Set by `prepare`: the zone offset at every 200 Hz tick, the gusts on a 10 Hz grid.
    offsets: F64 = field(default_factory=lambda: np.zeros(0))
    _gust_t: F64 = field(default_factory=lambda: np.zeros(0))
    _gust_p: F64 = field(default_factory=lambda: np.zeros(0))

    @classmethod
    def draw(cls, spec: WorldSpec, building: Building, p0_pa: float, seed: int) -> World:
        rng = np.random.default_rng([seed, 37])
        t_c = _draw(rng, spec.air_temperature_c)
        t_k = t_c + KELVIN
        rh = _draw(rng, spec.relative_humidity)
        g = normal_gravity_m_s2(_draw(rng, spec.latitude_deg)) if spec.latitude_deg else G_STANDARD_M_S2
        gradient = _draw(rng, spec.temperature_gradient_k_per_m)
        tv = virtual_temperature_k(t_k, rh, p0_pa)
        air = AirColumn(tv, gradient, g)
        elevations = [building.elevation(k) for k in range(building.n_floors)]
        z_lo, z_hi = min(elevations), max(elevations) + building.storey_height(building.n_floors - 1)
        outdoor_k: float | None = None
        stack = 0.0
        f_share = _draw(rng, spec.floor_stack_share)
        s_share = _draw(rng, spec.stair_stack_share)
        npl = z_lo + _draw(rng, spec.neutral_plane_share) * (z_hi - z_lo)
        if spec.outdoor_minus_indoor_k is not None:
            outdoor_k = t_k + _draw(rng, spec.outdoor_minus_indoor_k)
            # Outdoor air taken as moist as the indoor (its virtual temperature shifts alike).
            tv_out = outdoor_k + (tv - t_k)
            stack = g * p0_pa / R_DRY_AIR_J_PER_KG_K * (1.0 / tv_out - 1.0 / tv)
        offsets = []
        for e in elevations:
            hvac = float(rng.uniform(-spec.floor_hvac_pa, spec.floor_hvac_pa)) if spec.floor_hvac_pa else 0.0
            offsets.append(-f_share * stack * (e + _FLOOR_PROBE_M - npl) + hvac)
        shaft = float(rng.uniform(-spec.shaft_offset_pa, spec.shaft_offset_pa)) if spec.shaft_offset_pa else 0.0
        stair = _draw(rng, spec.stair_offset_pa)
        sign = 1.0 if rng.random() < 0.5 else -1.0
        trend = sign * _draw(rng, spec.weather_trend_pa_per_h)
        curv = (1.0 if rng.random() < 0.5 else -1.0) * _draw(rng, spec.weather_curvature_pa_per_h2)
        thermo = None
        if spec.temperature_sensor is not None:
            ts = spec.temperature_sensor
            thermo = ThermometerState(
                ts, _draw(rng, ts.self_heating_k), _draw(rng, ts.warmup_s), _draw(rng, ts.bias_k), _draw(rng, ts.lag_s)
            )
        return cls(
            spec=spec,
            air_temperature_k=t_k,
            relative_humidity=rh,
            air=air,
            outdoor_temperature_k=outdoor_k,
            stack_pa_per_m=stack,
            neutral_plane_m=npl,
            floor_offsets_pa=offsets,
            floor_stack_share=f_share,
            stair_stack_share=s_share,
            shaft_offset_pa=shaft,
            stair_offset_pa=stair,
            door_mix_s=_draw(rng, spec.door_mix_s),
            cabin_lag_s=_draw(rng, spec.cabin_lag_s),
            piston_pa_s2_per_m2=_draw(rng, spec.piston_pa_s2_per_m2),
            door_pulse_s=_draw(rng, spec.door_pulse_s),
            weather_trend_pa_per_h=trend,
            weather_curvature_pa_per_h2=curv,
            gust_pa=_draw(rng, spec.gust_pa),
            gust_s=_draw(rng, spec.gust_s),
            thermometer=thermo,
            seed=seed,
        )

    # -- weather on top of the barometer spec's drift ----------------------------------------
    def weather_pa(self, t_s: F64) -> F64:
        """Trend, curvature and gusts at times t_s (seconds from the start)."""
        h = np.asarray(t_s, dtype=np.float64) / 3600.0
        p = self.weather_trend_pa_per_h * h + self.weather_curvature_pa_per_h2 * h * h
        if self.gust_pa > 0 and len(self._gust_t):
            p = p + np.interp(t_s, self._gust_t, self._gust_p)
        return np.asarray(p, dtype=np.float64)

    def prepare(self, building: Building, traj: Trajectory, baro_height_m: F64) -> None:
        """Everything that depends on the route: the zone offsets at every 200 Hz tick, the door
        pulses, the gusts. `baro_height_m` is the sensor's height at every tick."""
        from mfmap.sim.trajectory import DT_S

        n = len(traj.xyz)
        duration = (n - 1) * DT_S
        rng = np.random.default_rng([self.seed, 41])
        # Gusts: an Ornstein-Uhlenbeck process on a 10 Hz grid (exact discretisation).
        if self.gust_pa > 0:
            dt = 0.1
            m = math.ceil(duration / dt) + 2
            a = math.exp(-dt / self.gust_s)
            w = rng.normal(0.0, self.gust_pa * math.sqrt(1 - a * a), m)
            g = np.empty(m)
            g[0] = rng.normal(0.0, self.gust_pa)
            for i in range(1, m):
                g[i] = a * g[i - 1] + w[i]
            self._gust_t = np.arange(m, dtype=np.float64) * dt
            self._gust_p = g
        self.offsets = np.zeros(n)
        if self.spec.calm:
            return
        zone, floor, door_floor = zones_of(building, traj)
        t = np.arange(n) * DT_S
        ph = self.air.pressure_pa(baro_height_m, 101_325.0)  # hydrostatic part, fixed weather
        target = np.empty(n)
        is_floor = zone == ZONE_FLOOR
        target[is_floor] = np.asarray(self.floor_offsets_pa)[floor[is_floor]]
        is_stair = zone == ZONE_STAIR
        target[is_stair] = self.stair_offset_pa - self.stair_stack_share * self.stack_pa_per_m * (
            baro_height_m[is_stair] - self.neutral_plane_m
        )
        in_cabin = zone == ZONE_CABIN
        open_cabin = in_cabin & (door_floor >= 0)
        closed_cabin = in_cabin & (door_floor < 0)
        target[open_cabin] = np.asarray(self.floor_offsets_pa)[door_floor[open_cabin]]
        vz = np.gradient(traj.xyz[:, 2], DT_S)
        target[closed_cabin] = self.shaft_offset_pa + self.piston_pa_s2_per_m2 * vz[closed_cabin] * np.abs(vz[closed_cabin])
        a_mix = 1.0 - math.exp(-DT_S / self.door_mix_s) if self.door_mix_s > 0 else 1.0
        a_cab = 1.0 - math.exp(-DT_S / self.cabin_lag_s) if self.cabin_lag_s > 0 else 1.0
        x = _relax(target, ph, closed_cabin, a_mix, a_cab)
        # Door pulses: the elevator's doors opening and closing, the stairwell's door passed.
        events = [tt for t0, t1, _ in traj.door_open for tt in (t0, t1)]
        changes = np.flatnonzero((zone[1:] != zone[:-1]) & ((zone[1:] == ZONE_STAIR) | (zone[:-1] == ZONE_STAIR)))
        events += [float(t[i + 1]) for i in changes]
        lo, hi = self.spec.door_pulse_pa
        if hi > 0:
            for t0 in sorted(events):
                amp = float(rng.uniform(lo, hi)) * (1.0 if rng.random() < 0.5 else -1.0)
                self.door_pulses.append((t0, amp))
                i0 = round(t0 / DT_S)
                k = np.arange(max(0, min(n - i0, round(10 * self.door_pulse_s / DT_S)))) * DT_S
                x[i0 : i0 + len(k)] += amp * np.exp(-k / self.door_pulse_s)
        self.offsets = x

    # -- the barometer's temperature output -------------------------------------------------
    def chip_temperature_c(self, t_s: F64, baro_height_m: F64, rng: np.random.Generator) -> F64:
        """What the barometer's thermometer reports at the (uniform, increasing) times t_s."""
        th = self.thermometer
        assert th is not None
        air_c = self.air_temperature_k - KELVIN + self.air.gradient_k_per_m * baro_height_m
        # The chip lags the air (first order, exact for piecewise-constant input per step).
        out = np.empty(len(t_s))
        cur = float(air_c[0]) if len(t_s) else 0.0
        dt = float(t_s[1] - t_s[0]) if len(t_s) > 1 else 1.0
        a = 1.0 - math.exp(-dt / th.lag_s)
        for i, v in enumerate(air_c):
            cur += a * (float(v) - cur)
            out[i] = cur
        heating = th.self_heating_k * (1.0 - np.exp(-t_s / th.warmup_s))
        reading = out + heating + th.bias_k + rng.normal(0.0, th.spec.noise_k, len(t_s))
        return np.asarray(np.round(reading / th.spec.quantum_k) * th.spec.quantum_k, dtype=np.float64)

    def document(self, building: Building) -> dict[str, Any]:
        """The drawn values for gt_floors.json."""
        th = self.thermometer
        return {
            "air_temperature_c": round(self.air_temperature_k - KELVIN, 4),
            "relative_humidity": round(self.relative_humidity, 4),
            "virtual_temperature_k": round(self.air.virtual_temperature_k, 4),
            "temperature_gradient_k_per_m": self.air.gradient_k_per_m,
            "gravity_m_s2": self.air.gravity_m_s2,
            "outdoor_temperature_c": None if self.outdoor_temperature_k is None else round(self.outdoor_temperature_k - KELVIN, 4),
            "stack_pa_per_m": round(self.stack_pa_per_m, 5),
            "neutral_plane_m": round(self.neutral_plane_m, 4),
            "floor_offsets_pa": {str(k): round(v, 4) for k, v in enumerate(self.floor_offsets_pa)},
            "shaft_offset_pa": round(self.shaft_offset_pa, 4),
            "stair_offset_pa": round(self.stair_offset_pa, 4),
            "stair_stack_share": round(self.stair_stack_share, 4),
            "door_mix_s": round(self.door_mix_s, 4),
            "cabin_lag_s": round(self.cabin_lag_s, 4),
            "piston_pa_s2_per_m2": round(self.piston_pa_s2_per_m2, 4),
            "door_pulse_s": round(self.door_pulse_s, 4),
            "weather_trend_pa_per_h": round(self.weather_trend_pa_per_h, 4),
            "weather_curvature_pa_per_h2": round(self.weather_curvature_pa_per_h2, 4),
            "gust_pa": round(self.gust_pa, 4),
            "gust_s": round(self.gust_s, 4),
            "temperature_sensor": None
            if th is None
            else {
                "self_heating_k": round(th.self_heating_k, 4),
                "warmup_s": round(th.warmup_s, 2),
                "bias_k": round(th.bias_k, 4),
                "lag_s": round(th.lag_s, 2),
            },
        }


ZONE_FLOOR, ZONE_STAIR, ZONE_CABIN = 0, 1, 2


def zones_of(
    building: Building, traj: Trajectory
) -> tuple[npt.NDArray[np.int8], npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """Per 200 Hz tick: the zone whose air the robot is in, the floor (nearest elevation), and
    the floor whose landing doors are open while the robot is in the cabin (-1: closed)."""
    from mfmap.sim.trajectory import DT_S

    xy = traj.xyz[:, :2]
    cx, cy = building.shaft_center
    half = building.cabin_half_m
    in_cabin = (np.abs(xy[:, 0] - cx) < half) & (np.abs(xy[:, 1] - cy) < half)
    x0, x1, y0, y1 = building.stair_rect
    in_stair = (xy[:, 0] > x0) & (xy[:, 0] < x1) & (xy[:, 1] > y0) & (xy[:, 1] < y1)
    zone = np.full(len(xy), ZONE_FLOOR, dtype=np.int8)
    zone[in_stair] = ZONE_STAIR
    zone[in_cabin] = ZONE_CABIN
    floor = building.floor_index_of_heights(traj.xyz[:, 2])
    door = np.full(len(xy), -1, dtype=np.int64)
    for t0, t1, k in traj.door_open:
        i0, i1 = round(t0 / DT_S), round(t1 / DT_S)
        door[i0:i1] = k
    return zone, floor, door


def _relax(target: F64, ph: F64, lag_whole: npt.NDArray[np.bool_], a_mix: float, a_cab: float) -> F64:
    """The pressure offset the sensor sees: `target` followed with the door-mixing gain; where
    `lag_whole` (a closed cabin) the whole pressure (hydrostatic `ph` + offset) lags the
    target with the cabin's gain, so a moving cabin's pressure trails its height."""
    n = len(target)
    x = np.empty(n)
    cur = float(target[0]) if n else 0.0
    tl, phl, lag = target.tolist(), ph.tolist(), lag_whole.tolist()
    prev_ph = phl[0] if n else 0.0
    for i in range(n):
        if lag[i]:
            p_prev = prev_ph + cur
            p = p_prev + a_cab * (phl[i] + tl[i] - p_prev)
            cur = p - phl[i]
        else:
            cur += a_mix * (tl[i] - cur)
        x[i] = cur
        prev_ph = phl[i]
    return x
