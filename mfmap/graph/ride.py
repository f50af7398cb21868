"""Height change across an elevator ride from the IMU's vertical specific force.

The barometer gives a ride's height change to a few centimetres at best (noise, door and HVAC
pressure steps, weather). The accelerometer, integrated twice over the few seconds of the ride,
does better when its errors are pinned down at both ends: the robot stands still in the cabin
before and after the ride, so

- the stationary windows give the up direction (in the IMU frame) and g + bias along it;
- the vertical velocity is zero at both ends of the integration window (zero-velocity update):
  the linear trend that makes v(end) != 0 is removed, which absorbs what is left of the bias;
- while the cabin cruises its acceleration is zero: only the speeding up and the braking are
  integrated, when the heights with and without the cruise agree.

What is left is the white noise integrated twice: over a velocity "bridge" of the whole window
sigma_z = sigma_a sqrt(dt) T^1.5 / sqrt(12) (T the window length), about 1.3 cm for a 7 s ride
with a 0.03 m/s^2 accelerometer at 200 Hz; without the cruise, mostly the cruise speed's error
(that noise over the speeding up and braking) times the cruise's length. On the simulator's
stress rides (3-13 m, 0.5-0.9 m/s^2) that is 0.5-1.7 cm rms: the accelerometer's noise itself, as
the same rides with a noise-free accelerometer come within 0.02 cm. Under 1 cm on nine rides in
ten takes an accelerometer of about 170 ug/sqrt(Hz) against the simulator's 300
(`pipelines/ride_noise.py`).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from mfmap.floors.filters import true_runs
from mfmap.floors.imu import MOTION_M_S2 as CABIN_MOTION_M_S2
from mfmap.floors.imu import SMOOTH_S as CABIN_SMOOTH_S
from mfmap.types import F64, ImuSeries

# The smoothing of the vertical specific force and the threshold that find when the cabin moves
# are the floors stage's, which times the rides with them.
SMOOTH_S = CABIN_SMOOTH_S
MOTION_THRESHOLD_M_S2 = CABIN_MOTION_M_S2
# The cabin starts and stops smoothly: integrate from a little before the first detected
# acceleration to a little after the last.
PAD_S = 0.5
# Stand-still windows before and after the integration window.
STILL_S = 1.0
# Largest gyro rate / |f| spread (m/s^2) in a window that still counts as standing still.
STILL_GYRO_RAD_S = 0.05
STILL_ACCEL_STD_M_S2 = 0.1
# Model error (cabin sway, timing) added to the white-noise sigma.
SIGMA_FLOOR_M = 0.01
# What an accelerometer at rest reads along up, less its bias.
STANDARD_GRAVITY_M_S2 = 9.80665


@dataclass(frozen=True)
class RideHeight:
    """The IMU's height change across one ride, or why there is none (`height_change_m` None)."""

    start_ns: int  # the integration window (or the searched span when skipped)
    end_ns: int
    height_change_m: float | None
    sigma_m: float
    reason: str  # "ok" or why the IMU estimate was skipped
    bias_m_s2: float = 0.0  # specific force along up at rest (gravity + bias) less STANDARD_GRAVITY_M_S2
    legs: int = 0  # cabin moves integrated on their own (a ride with stops counts each leg)
    end_speed_m_s: float = 0.0  # largest velocity left at a leg's end before the zero-velocity update


def _moving_mean(x: F64, n: int) -> F64:
    """Centred mean over n samples (edges padded with the nearest sample), as floors/motion.py."""
    # origin -1: for an even n the window reaches one sample further ahead than behind.
    return np.asarray(ndimage.uniform_filter1d(x, size=max(n, 1), mode="nearest", origin=-1 if n % 2 == 0 else 0))


# The integration window's ends: where the smoothed vertical acceleration falls back into its
# noise (this many sigmas of the smoothed stand-still noise, at least QUIET_MIN_M_S2), plus
# TIGHT_PAD_S. The bridge's noise grows with the window's length to the power 1.5: a pad of
# 0.5 s either side of a 6 s ride adds a quarter to it.
QUIET_SIGMAS = 4.0
QUIET_MIN_M_S2 = 0.015
TIGHT_PAD_S = 0.1
# A cabin that stops inside the window (a stop at a floor where the robot stays in): slower
# than this for at least STOP_S is a stop, and each move either side is integrated on its own,
# with zero velocity at both of its ends. The accelerometer alone cannot tell a stop from a
# cruise; the velocity can (a cabin cruises at 0.5-2.5 m/s).
STOP_SPEED_M_S = 0.05
STOP_S = 1.0
# Left over at a move's end, before the zero-velocity update removes it as a bias: white noise
# leaves millimetres per second; more than this is a bias that changed, lost samples or a
# stand-still that was not one, and the double integral cannot be trusted.
MAX_END_SPEED_M_S = 0.1
# Between speeding up and braking a cabin cruises at the speed its drive holds: its acceleration
# is zero, so the accelerometer's noise there need not be integrated (a 12 m ride in two moves at
# 1.3 m/s: 1.6 cm rms instead of 2.2; one 5.5 m move at 1 m/s, 0.5 m/s^2, with 2 s of speeding
# up and braking each: 1.3 instead of 1.4). A quiet run counts as cruising from this long; the
# height without it must agree within CRUISE_CHECK_SIGMAS of the noise the two do not share, or
# the quiet run hid acceleration (a drift of the cabin's speed) and the whole move is integrated.
MIN_CRUISE_S = 0.5
CRUISE_CHECK_SIGMAS = 4.0


@dataclass(frozen=True)
class _Bridge:
    """One move integrated with zero velocity at both ends."""

    height_m: float
    v: F64  # the corrected velocity at the samples
    end_speed_m_s: float  # the velocity the correction removed at the end
    gain_s2: F64  # the height's change per m/s^2 more at each interval (s^2): its noise's weights


def _bridge(a_up: F64, tr: F64, moving: npt.NDArray[np.bool_] | None = None) -> _Bridge:
    """Height change over one move (trapezoids), zero velocity at both ends.

    Only the intervals touching a `moving` sample (all when None) are integrated: elsewhere the
    cabin stands or cruises at a constant speed, its acceleration is zero, and what the
    accelerometer reads there is its own noise. The velocity left at the end (the bias and the
    noise of the integrated intervals) is taken out in proportion to their time, so a constant
    bias goes exactly, as over the whole window.
    """
    dt = np.diff(tr)
    on = np.ones(dt.shape[0], dtype=bool) if moving is None else moving[1:] | moving[:-1]
    on_s = np.where(on, dt, 0.0)
    total_on_s = max(float(on_s.sum()), 1e-9)
    dv = np.where(on, 0.5 * (a_up[1:] + a_up[:-1]) * dt, 0.0)
    end_speed = float(dv.sum())
    dv -= end_speed * on_s / total_on_s
    v = np.concatenate([[0.0], np.cumsum(dv)])
    # A velocity step in interval k lasts from its middle to the end; the correction takes the
    # on-time weighted mean of that back out.
    remaining_s = float(tr[-1] - tr[0]) - (0.5 * (tr[1:] + tr[:-1]) - tr[0])
    gain = np.where(on, remaining_s - float(np.sum(remaining_s * on_s)) / total_on_s, 0.0) * dt
    return _Bridge(float(np.sum(0.5 * (v[1:] + v[:-1]) * dt)), v, end_speed, gain)


def _moving_samples(active: npt.NDArray[np.bool_], min_still: int) -> npt.NDArray[np.bool_]:
    """Samples where the cabin may accelerate: the `active` ones and quiet gaps shorter than
    `min_still` samples (a short ride's turn from speeding up to braking).

    No pad beyond `active`: its smoothing already reaches half a window (0.1 s) past a step in
    the acceleration, and the ends of a jerk-limited ramp below the threshold (0.02 m/s^2 for
    0.02 s at 1 m/s^3) hold a fraction of a millimetre per second."""
    moving = active.copy()
    for r0, r1 in true_runs(~active):
        if r1 - r0 < min_still and r0 > 0 and r1 < active.shape[0]:
            moving[r0:r1] = True
    return moving


def _quiet_ends(active: npt.NDArray[np.bool_], lo: int, hi: int, pad: int) -> tuple[int, int] | None:
    """First and last active sample in [lo, hi), widened by `pad` samples (within [lo, hi))."""
    idx = np.flatnonzero(active[lo:hi])
    if idx.shape[0] == 0:
        return None
    return max(lo, lo + int(idx[0]) - pad), min(hi - 1, lo + int(idx[-1]) + pad)


def ride_height(
    imu: ImuSeries | None,
    start_ns: int,
    end_ns: int,
    search_s: float = 1.5,
) -> RideHeight:
    """The height change of the ride the barometer puts between start_ns and end_ns.

    The cabin's motion is looked for within `search_s` of the barometer's span (its transition
    times are within about a second of the truth). Skipped, with the reason, when there is no
    IMU, no clear ride in the accelerometer, or the robot is not standing still before and after.
    A ride that stops on the way (the robot staying in the cabin) is integrated move by move.
    """
    if imu is None or len(imu) < 10:
        return RideHeight(start_ns, end_ns, None, 0.0, "no IMU")
    span = int(search_s * 1e9)
    samples = _Samples.around(imu, start_ns, end_ns, span)
    if isinstance(samples, str):
        return RideHeight(start_ns, end_ns, None, 0.0, samples)
    found = _cabin_motion(samples, start_ns, end_ns, span)
    if isinstance(found, RideHeight):
        return found
    t0, t1, pre, post, n_smooth = found
    ts, acc, dt_s = samples.ts, samples.acc, samples.dt_s

    along = _along_up(acc, pre | post)
    if isinstance(along, str):
        return RideHeight(t0, t1, None, 0.0, along)
    f_up, g_still, noise = along

    ride = (ts >= t0) & (ts <= t1)
    if float(np.diff(ts[ride]).max(initial=0)) / 1e9 > 0.1:
        return RideHeight(t0, t1, None, 0.0, "IMU samples missing during the ride")
    a_all = f_up - g_still
    # The window hugs the motion: from the first to the last sample whose smoothed acceleration
    # stands out of the stand-still noise, searched within the padded window.
    quiet = max(QUIET_SIGMAS * noise / math.sqrt(n_smooth), QUIET_MIN_M_S2)
    active = np.abs(_moving_mean(a_all, n_smooth)) > quiet
    i_lo, i_hi = int(np.flatnonzero(ride)[0]), int(np.flatnonzero(ride)[-1]) + 1
    pad = round(TIGHT_PAD_S / dt_s)
    ends = _quiet_ends(active, i_lo, i_hi, pad)
    if ends is None:
        return RideHeight(t0, t1, None, 0.0, "no vertical acceleration found")
    a, b = ends
    height, var, worst, legs = _integrate_legs(samples, a_all, active, (a, b), pad, noise)
    start, stop = int(ts[a]), int(ts[b])
    if worst > MAX_END_SPEED_M_S:
        return RideHeight(start, stop, None, 0.0,
                          f"the cabin is not at rest at the end of the integration ({worst:.2f} m/s "
                          "left): the accelerometer's bias changed or samples are missing",
                          bias_m_s2=g_still - STANDARD_GRAVITY_M_S2, legs=legs, end_speed_m_s=worst)
    sigma = math.hypot(math.sqrt(var), SIGMA_FLOOR_M)
    return RideHeight(start, stop, height, sigma, "ok", bias_m_s2=g_still - STANDARD_GRAVITY_M_S2,
                      legs=legs, end_speed_m_s=worst)


@dataclass(frozen=True)
class _Samples:
    """The IMU's samples around one ride: stamps, specific force, turn rate, median interval."""

    ts: npt.NDArray[np.int64]
    acc: F64
    gyro: F64
    dt_s: float

    @classmethod
    def around(cls, imu: ImuSeries, start_ns: int, end_ns: int, span: int) -> _Samples | str:
        """The samples within `span` ns of the ride and the stand-stills beyond, or why none."""
        t = imu.stamp_ns
        lo = int(np.searchsorted(t, start_ns - span - int((PAD_S + STILL_S) * 1e9)))
        hi = int(np.searchsorted(t, end_ns + span + int((PAD_S + STILL_S) * 1e9), side="right"))
        if hi - lo < 50:
            return "too few IMU samples around the ride"
        ts = t[lo:hi]
        acc = np.asarray(imu.accel_m_s2[lo:hi], dtype=np.float64)
        gyro = np.asarray(imu.gyro_rad_s[lo:hi], dtype=np.float64)
        dt_s = float(np.median(np.diff(ts))) / 1e9
        if not dt_s > 0:
            return "IMU stamps not increasing"
        return cls(ts, acc, gyro, dt_s)


def _cabin_motion(
    samples: _Samples, start_ns: int, end_ns: int, span: int
) -> tuple[int, int, npt.NDArray[np.bool_], npt.NDArray[np.bool_], int] | RideHeight:
    """The padded span of the cabin's motion (t0, t1), the stand-still windows before and after
    it and the smoothing length in samples; or the skipped RideHeight, with the reason."""
    ts, acc, gyro, dt_s = samples.ts, samples.acc, samples.gyro, samples.dt_s
    # Find the cabin's acceleration and deceleration in the smoothed specific force along up
    # (driving adds vibration to |f| but little along up) inside the searched span.
    inside = (ts >= start_ns - span) & (ts <= end_ns + span)
    up0 = np.median(acc[inside], axis=0)
    up0 /= max(float(np.linalg.norm(up0)), 1e-9)
    norm = np.linalg.norm(acc, axis=1)
    n_smooth = max(1, round(SMOOTH_S / dt_s))
    smooth = _moving_mean(acc @ up0, n_smooth)
    rest = float(np.median(smooth[inside]))
    moving = inside & (np.abs(smooth - rest) > MOTION_THRESHOLD_M_S2)
    if not moving.any():
        return RideHeight(start_ns, end_ns, None, 0.0, "no vertical acceleration found")
    idx = np.flatnonzero(moving)
    t0 = int(ts[idx[0]]) - int(PAD_S * 1e9)
    t1 = int(ts[idx[-1]]) + int(PAD_S * 1e9)
    pre = (ts >= t0 - int(STILL_S * 1e9)) & (ts < t0)
    post = (ts > t1) & (ts <= t1 + int(STILL_S * 1e9))
    need = int(0.5 * STILL_S / dt_s)
    if pre.sum() < need or post.sum() < need:
        return RideHeight(t0, t1, None, 0.0, "IMU does not cover the stand-still before and after")
    for name, win in (("before", pre), ("after", post)):
        if (float(np.linalg.norm(gyro[win], axis=1).mean()) > STILL_GYRO_RAD_S
                or float(norm[win].std()) > STILL_ACCEL_STD_M_S2):
            return RideHeight(t0, t1, None, 0.0, f"robot not standing still {name} the ride")
    return t0, t1, pre, post, n_smooth


def _along_up(acc: F64, still: npt.NDArray[np.bool_]) -> tuple[F64, float, float] | str:
    """The specific force along up, and g + bias along it and its noise at rest; or why not.

    Up in the IMU frame and g + bias along it, from the stand-still windows. The bias is held
    constant over the ride: interpolating between the two windows would add their noise as a
    slope, which the zero-velocity update cannot remove (it removes a constant only).
    """
    up = acc[still].mean(axis=0)
    g_norm = float(np.linalg.norm(up))
    if abs(g_norm - STANDARD_GRAVITY_M_S2) > 0.8:
        # Gravity removed by the driver, or units other than m/s^2: no up to integrate along.
        return f"IMU reads {g_norm:.2f} m/s^2 at rest, not gravity"
    up /= g_norm
    f_up = acc @ up
    g_still = float(f_up[still].mean())
    noise = float(f_up[still].std())
    return f_up, g_still, noise


def _integrate_legs(
    samples: _Samples,
    a_all: F64,
    active: npt.NDArray[np.bool_],
    window: tuple[int, int],
    pad: int,
    noise: float,
) -> tuple[float, float, float, int]:
    """The height change over the integration window [a, b], move by move: the summed height,
    its variance, the largest speed left at a move's end, and the moves integrated."""
    ts, dt_s = samples.ts, samples.dt_s
    a, b = window
    tr = (ts[a : b + 1] - ts[a]) / 1e9
    v = _bridge(a_all[a : b + 1], tr).v

    # Stops inside: runs of low speed of at least STOP_S, away from the window's ends; each
    # move between them is integrated with its own zero-velocity ends.
    slow = np.abs(v) < STOP_SPEED_M_S
    cuts = [a]
    for r0, r1 in true_runs(slow):
        if r0 > 0 and r1 < slow.shape[0] and (r1 - r0) * dt_s >= STOP_S:
            cuts.append(a + (r0 + r1) // 2)
    cuts.append(b)
    moving = _moving_samples(active, round(MIN_CRUISE_S / dt_s))
    height, var, worst = 0.0, 0.0, 0.0
    legs = 0
    for c0, c1 in itertools.pairwise(cuts):
        leg = _quiet_ends(active, c0, c1 + 1, pad) if len(cuts) > 2 else (c0, c1)
        if leg is None:
            continue  # a stop's half with no motion in it
        la, lb = leg
        if lb - la < 2:
            continue
        dz, gain, end_speed = _one_move(a_all[la : lb + 1], (ts[la : lb + 1] - ts[la]) / 1e9,
                                        moving[la : lb + 1], noise)
        height += dz
        var += (noise * float(np.linalg.norm(gain))) ** 2
        worst = max(worst, abs(end_speed))
        legs += 1
    return height, var, worst, legs


def _one_move(a_up: F64, tr: F64, moving: npt.NDArray[np.bool_], noise: float) -> tuple[float, F64, float]:
    """One move's height change, its noise's weights and the speed left at its end: its cruise
    left out when the whole window's integral agrees (CRUISE_CHECK_SIGMAS)."""
    whole = _bridge(a_up, tr)
    cruise = _bridge(a_up, tr, moving)
    apart = noise * float(np.linalg.norm(whole.gain_s2 - cruise.gain_s2))
    best = cruise if abs(cruise.height_m - whole.height_m) <= CRUISE_CHECK_SIGMAS * apart + 1e-6 else whole
    return best.height_m, best.gain_s2, whole.end_speed_m_s


# Accelerating, cruising and braking of one ride: bursts of vertical acceleration closer than
# this belong to the same ride (a cabin cruises at ~1 m/s, so a few floors take ~10-20 s).
RIDE_GAP_S = 30.0


def find_rides(imu: ImuSeries | None, min_height_m: float) -> list[RideHeight]:
    """Elevator rides the IMU feels without being told where to look (a log with no barometer).

    Bursts of vertical acceleration are grouped into candidate rides and each is measured with
    `ride_height`; those that stand still at both ends and change height by at least
    `min_height_m` are returned. Driving over bumps makes short bursts, but no stand-still to
    stand-still height change of metres.
    """
    if imu is None or len(imu) < 50:
        return []
    t = imu.stamp_ns
    acc = np.asarray(imu.accel_m_s2, dtype=np.float64)
    dt_s = float(np.median(np.diff(t))) / 1e9
    if not dt_s > 0:
        return []
    up = np.median(acc, axis=0)
    norm = float(np.linalg.norm(up))
    if norm < 1.0:
        return []
    smooth = _moving_mean(acc @ (up / norm), max(1, round(SMOOTH_S / dt_s)))
    moving = np.flatnonzero(np.abs(smooth - float(np.median(smooth))) > MOTION_THRESHOLD_M_S2)
    if len(moving) == 0:
        return []
    breaks = np.flatnonzero(np.diff(t[moving]) > int(RIDE_GAP_S * 1e9))
    firsts = np.concatenate([[0], breaks + 1])
    lasts = np.concatenate([breaks, [len(moving) - 1]])
    rides = []
    for a, b in zip(firsts, lasts, strict=True):
        ride = ride_height(imu, int(t[moving[a]]), int(t[moving[b]]), search_s=0.5)
        if ride.height_change_m is not None and abs(ride.height_change_m) >= min_height_m:
            rides.append(ride)
    return rides
