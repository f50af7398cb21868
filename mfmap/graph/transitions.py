"""Heights across the floors stage's transitions: what each measures and the factors they become.

Per transition, its height change from the scale-true sensor (an elevator ride's from the IMU,
mfmap.graph.ride; a stair walk's from the lidar odometry) and from the barometer (a fit on the
raw trace either side, mfmap.floors.levels.level_change), weighed by mfmap.graph.heights.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

import gtsam
import numpy as np

from mfmap.floors.levels import RawTrace, level_change, raw_trace
from mfmap.graph import heights
from mfmap.graph.config import GraphConfig, RobustKernel
from mfmap.graph.factors import (
    FREE_SIGMA,
    LOOSE_TILT_RAD,
    SCALE,
    Builder,
    Fl,
    U,
    X,
    baro_height_factor,
    relative_level,
)
from mfmap.graph.heights import Calibration, Measurement, TransitionHeights
from mfmap.graph.ride import ride_height
from mfmap.types import (
    F64,
    FloorSegmentation,
    ImuSeries,
    Keyframe,
    PoseEdge,
    Transition,
    TransitionKind,
)

logger = logging.getLogger(__name__)

# Model error added (in quadrature) to a barometric level change's own sigma: what the fit cannot
# see, such as a floor kept at a slightly different pressure by its air handling (1 Pa ~ 8.5 cm).
# On the simulator's two-floor, three-floor-revisit and stairs buildings (three seeds each),
# 0.005 / 0.01 / 0.02 m give floor elevation errors of 1.54 / 1.57 / 1.67 cm RMS (2.46 with the
# floors stage's change at 3 cm).
BARO_MODEL_SIGMA_M = 0.01


@dataclass(frozen=True)
class Walk:
    """A stair walk's height change as the lidar odometry measured it: its relative translation
    turned into the world by the mapping stage's pose of the keyframe before it (the frame the
    odometry measured it in; gravity levelling that keyframe must not move the climb)."""

    i: int
    j: int
    sigma_m: float
    height_change_m: float

    @classmethod
    def of(cls, edge: PoseEdge, initial: dict[int, F64], sigma_m: float) -> Walk:
        dz = float((initial[edge.i][:3, :3] @ np.asarray(edge.measured)[:3, 3])[2])
        return cls(edge.i, edge.j, sigma_m, dz)

def _ride_ends(kfs: list[Keyframe], start_ns: int, end_ns: int) -> tuple[Keyframe, Keyframe] | None:
    before = [k for k in kfs if k.stamp_ns <= start_ns]
    after = [k for k in kfs if k.stamp_ns >= end_ns]
    if not before or not after:
        return None
    return before[-1], after[0]


def add_transitions(
    builder: Builder,
    values: Any,
    kfs: list[Keyframe],
    initial: dict[int, F64],
    seg: FloorSegmentation | None,
    config: GraphConfig,
    imu: ImuSeries | None,
    walks: dict[tuple[int, int], Walk],
    scale_prior_sigma: float | None,
) -> tuple[list[dict[str, Any]], Calibration]:
    """Per transition: its height change from the scale-true sensor (an elevator ride's from the
    IMU, a stair walk's from the lidar) and from the barometer, weighed by mfmap.graph.heights and
    added as z-only factors; for elevator rides x, y and yaw held (z free). Separate factors, so
    an x, y, yaw disagreement that the robust kernel turns down does not also turn down the height.
    Returns one report entry per transition and the barometer's calibration."""
    rides: list[dict[str, Any]] = []
    prior = (1.0, config.barometer.scale_sigma if scale_prior_sigma is None else scale_prior_sigma)
    if seg is None:
        seg = FloorSegmentation((), (), np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0),
                                np.zeros(0, dtype=np.int32))
    yaw = math.radians(config.elevator.sigma_yaw_deg)
    sig_xy = config.elevator.sigma_xy_m
    tilt = LOOSE_TILT_RAD
    trace = raw_trace(seg) if config.heights.transition_window_s > 0 and len(seg.stamp_ns) > 0 else None
    measured_heights = _Heights([], {}, {})
    for index, tr in enumerate(seg.transitions):
        ends = _ride_ends(kfs, tr.start_ns, tr.end_ns)
        entry = _report_entry(tr)
        rides.append(entry)
        if ends is None:
            entry["heights"] = "no keyframe before or after the transition"
            continue
        a, b = ends
        entry["keyframes"] = [a.id, b.id]
        measured_heights.keys[index] = height_keys(a, b, config)
        measured_heights.items.append(
            _measure(seg, index, (a, b), config, imu, walks, entry, trace, measured_heights.walk_of)
        )
        if config.ablation.elevator_continuity and tr.kind == TransitionKind.ELEVATOR:
            # The mapping stage holds x, y and yaw through the ride: the initial relative pose
            # is the measurement.
            measured = relative_level(initial[a.id], initial[b.id], tr.height_change_m)
            # Cauchy: when the ride's ends disagree with the floors' registration by many sigma
            # (a keyframe at the cabin door with a wrong pose), the factor lets go instead of
            # bending the floor with a constant (Huber) pull.
            builder.between(
                "elevator", a.id, b.id, measured, [tilt, tilt, yaw, sig_xy, sig_xy, FREE_SIGMA],
                kernel=RobustKernel.CAUCHY,
            )

    calibration = _weigh(builder, values, kfs, measured_heights, walks, prior, config)
    _report_heights(measured_heights.items, rides, calibration)
    return rides, calibration


def _report_entry(tr: Transition) -> dict[str, Any]:
    """A transition's entry in the report, before its heights are measured."""
    return {
        "kind": tr.kind.value,
        "from_floor": tr.from_floor,
        "to_floor": tr.to_floor,
        "start_s": round(tr.start_ns / 1e9, 3),
        "end_s": round(tr.end_ns / 1e9, 3),
        "baro_height_change_m": round(tr.height_change_m, 4),
    }


@dataclass
class _Heights:
    """The transitions with keyframes either side: their measurements, where their height
    factors act (`height_keys`) and, for a stair walk, the lidar's climb across it."""

    items: list[TransitionHeights]
    keys: dict[int, tuple[int, int]]
    walk_of: dict[int, Walk]


def _measure(
    seg: FloorSegmentation,
    index: int,
    ends: tuple[Keyframe, Keyframe],
    config: GraphConfig,
    imu: ImuSeries | None,
    walks: dict[tuple[int, int], Walk],
    entry: dict[str, Any],
    trace: RawTrace | None,
    walk_of: dict[int, Walk],
) -> TransitionHeights:
    """Transition `index`'s height change by the barometer and by the scale-true sensor."""
    tr = seg.transitions[index]
    a, b = ends
    item = TransitionHeights(index, tr.kind, tr.from_floor, tr.to_floor, None, None)
    if config.ablation.transition_height:
        baro_dz, baro_sigma = _transition_height(seg, index, config, entry, trace)
        item.baro = Measurement("barometer", baro_dz, baro_sigma)
    else:
        item.baro_reason = "off"
    if tr.kind == TransitionKind.ELEVATOR:
        item.scale_true, item.scale_true_reason = _imu_height(tr.start_ns, tr.end_ns, imu, config, entry)
    elif not config.ablation.walk_height:
        item.scale_true_reason = "off"
    elif (a.id, b.id) in walks:
        w = walks[(a.id, b.id)]
        item.scale_true = Measurement("lidar", w.height_change_m, w.sigma_m)
        entry["lidar_height_change_m"] = round(w.height_change_m, 4)
        entry["lidar_sigma_m"] = round(w.sigma_m, 4)
        walk_of[index] = w
    else:
        item.scale_true_reason = "the lidar odometry does not run across it"
    return item


def _weigh(
    builder: Builder,
    values: Any,
    kfs: list[Keyframe],
    measured: _Heights,
    walks: dict[tuple[int, int], Walk],
    prior: tuple[float, float],
    config: GraphConfig,
) -> Calibration:
    """Calibrate the barometer on the transitions measured both ways, decide which heights are
    used, and add them as factors; a stair walk with no transition gets the lidar's climb."""
    items, walk_of = measured.items, measured.walk_of
    start_floor = next((k.floor_id for k in kfs if k.floor_id >= 0), 0)
    calibration = heights.calibrate(items, prior, config.barometer.offset_sigma_m)
    heights.decide(items, calibration, start_floor, config.heights.gate_sigma)
    if calibration.usable and calibration.pairs > 0:
        # Again on the measurements kept, and decided again on that calibration.
        calibration = heights.calibrate(items, prior, config.barometer.offset_sigma_m, used_only=True)
        heights.decide(items, calibration, start_floor, config.heights.gate_sigma)
    for text in calibration.warnings:
        logger.warning(text)
    _add_heights(builder, values, items, measured.keys, walk_of, calibration)
    if config.ablation.walk_height:
        # A walk the floors stage has no transition for (no barometer): the lidar's climb alone.
        matched = {(w.i, w.j) for w in walk_of.values()}
        for pair, walk in walks.items():
            if pair not in matched:
                builder.world_dz("walk_z", X(walk.i), X(walk.j), walk.height_change_m, walk.sigma_m, robust=True)
    return calibration


def _report_heights(
    items: list[TransitionHeights], rides: list[dict[str, Any]], calibration: Calibration
) -> None:
    """Each transition's report entry: the heights used, and a warning for a height left out."""
    for item in items:
        entry = rides[item.index]
        entry["heights_used"] = [m.source for m, used in ((item.scale_true, item.use_scale_true),
                                                          (item.baro, item.use_baro)) if m is not None and used]
        entry["heights"] = item.why
        if not entry["heights_used"]:
            logger.warning("%s: no height measurement used (%s); its floors' heights come from the "
                           "others", item.label, item.why)
        elif item.scale_true is not None and not item.use_scale_true:
            logger.warning("%s: the %s's height left out (%s)", item.label, item.scale_true.source, item.why)
        elif item.baro is not None and item.use_scale_true and calibration.usable and not item.use_baro:
            logger.warning("%s: the barometer's height left out (%s)", item.label, item.why)


def _add_heights(
    builder: Builder,
    values: Any,
    items: list[TransitionHeights],
    keys: dict[int, tuple[int, int]],
    walk_of: dict[int, Walk],
    cal: Calibration,
) -> None:
    """The accepted heights as factors: a scale-true one as a world-z change (robust), a
    barometric one through the scale and the two floors' offsets (variables with the
    calibration's priors):  z_b - z_a = s d - (u_b - u_a)."""
    used_baro = [it for it in items if it.use_baro and it.baro is not None]
    if used_baro:
        values.insert(SCALE, cal.scale)
        builder.add("baro_scale", gtsam.PriorFactorDouble(SCALE, cal.scale_prior[0],
                                                           gtsam.noiseModel.Isotropic.Sigma(1, cal.scale_prior[1])),
                    np.eye(1) / cal.scale_prior[1])
        sigma_o = max(cal.offset_sigma_m, 1e-3)
        for f in sorted({f for it in used_baro for f in (it.from_floor, it.to_floor)}):
            values.insert(U(f), 0.0)
            builder.add("baro_offset", gtsam.PriorFactorDouble(U(f), 0.0, gtsam.noiseModel.Isotropic.Sigma(1, sigma_o)),
                        np.eye(1) / sigma_o)
    for it in items:
        key_a, key_b = keys[it.index]
        if it.use_scale_true and it.scale_true is not None:
            kind = "walk_z" if it.index in walk_of else "imu_ride"
            builder.world_dz(kind, key_a, key_b, it.scale_true.height_change_m, it.scale_true.sigma_m,
                             robust=True)
        elif it.scale_true is not None:
            builder.reject("imu_ride" if it.scale_true.source == "imu" else "walk_z")
        if it.use_baro and it.baro is not None:
            sigma = max(cal.scale * it.baro.sigma_m, 1e-4)
            builder.add("transition_z", baro_height_factor(key_a, key_b, U(it.from_floor), U(it.to_floor),
                                                            it.baro.height_change_m, sigma, builder.config),
                        np.eye(1) / sigma)
        elif it.baro is not None:
            builder.reject("transition_z")


def height_keys(a: Keyframe, b: Keyframe, config: GraphConfig) -> tuple[int, int]:
    """Where a transition's height factors act, from its keyframes a (before) and b (after).

    A ground robot stands on the floors at both ends: the height change is between the floors'
    levels, not between two keyframes, which the floors' ties (2 cm each) would let it bend
    locally instead of moving the floor (floor elevations 1.1 cm RMS off against 1.6 cm on the
    keyframes, over the simulator's two-floor, three-floor-revisit and stairs buildings, three
    seeds each). The keyframes where there are no ties.
    """
    if config.ablation.same_floor_height_tie and a.floor_id >= 0 and b.floor_id >= 0 and a.floor_id != b.floor_id:
        return Fl(a.floor_id), Fl(b.floor_id)
    return X(a.id), X(b.id)


def _transition_height(
    seg: FloorSegmentation, index: int, config: GraphConfig, entry: dict[str, Any], trace: RawTrace | None
) -> tuple[float, float]:
    """The barometer's height change across transition `index` and its sigma: the fit on the raw
    trace either side (mfmap.floors.levels.level_change) where it runs, else the floors stage's."""
    tr = seg.transitions[index]
    if config.heights.transition_window_s > 0:
        fit = level_change(seg, index, config.heights.transition_window_s, trace=trace)
        entry["baro_fit"] = fit.reason
        if fit.height_change_m is not None:
            sigma = math.hypot(fit.sigma_m, BARO_MODEL_SIGMA_M)
            entry["baro_height_change_m"] = round(fit.height_change_m, 4)
            entry["baro_sigma_m"] = round(sigma, 4)
            entry["baro_window_s"] = round(fit.window_s, 1)
            entry["floors_height_change_m"] = round(tr.height_change_m, 4)
            return fit.height_change_m, sigma
    entry["baro_sigma_m"] = config.heights.transition_sigma_z_m
    return tr.height_change_m, config.heights.transition_sigma_z_m


def _imu_height(
    start_ns: int,
    end_ns: int,
    imu: ImuSeries | None,
    config: GraphConfig,
    entry: dict[str, Any],
) -> tuple[Measurement | None, str]:
    """The IMU's height change across one ride (mfmap.graph.ride), or why there is none."""
    if not config.ablation.imu_ride_height:
        entry["imu"] = "off"
        return None, "off"
    ride = ride_height(imu, start_ns, end_ns)
    entry["imu"] = ride.reason
    if ride.height_change_m is None:
        return None, ride.reason
    entry["imu_height_change_m"] = round(ride.height_change_m, 4)
    entry["imu_sigma_m"] = round(ride.sigma_m, 4)
    entry["imu_window_s"] = round((ride.end_ns - ride.start_ns) / 1e9, 3)
    entry["imu_bias_m_s2"] = round(ride.bias_m_s2, 4)
    entry["imu_legs"] = ride.legs
    return Measurement("imu", ride.height_change_m, ride.sigma_m), "ok"
