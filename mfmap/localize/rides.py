"""The height of the cabin through an elevator ride, from the accelerometer.

The barometer in a closed cabin lags the ride (the cabin's air follows the shaft's with a time
constant of up to a second or so), which at 1 m/s puts the scans of a ride tens of centimetres
off in height. The accelerometer does not lag: its vertical specific force, less its value at
rest, integrated twice over the ride with the velocity pinned to zero at both ends (the robot
stands in the cabin before and after), gives the shape of the ride; the map's floor elevations
give its ends.
"""

from __future__ import annotations

import numpy as np

from mfmap.types import F64, I64, ImuSeries

# The robot stands still in the cabin this long before and after the ride as the barometer
# places it: the rest windows for the up direction and the specific force at rest.
REST_S = 0.5


def ride_profile(imu: ImuSeries | None, imu_to_base: F64, start_ns: int, end_ns: int,
                 pad_s: float = 1.0) -> tuple[I64, F64] | None:
    """Stamps and the height change since the ride's start at each, as a share of the whole
    ride's (0 before it, 1 after it), or None without usable IMU data."""
    if imu is None or len(imu) < 20:
        return None
    pad = int(pad_s * 1e9)
    inside = (imu.stamp_ns >= start_ns - pad) & (imu.stamp_ns <= end_ns + pad)
    t_ns = imu.stamp_ns[inside]
    if len(t_ns) < 20:
        return None
    order = np.argsort(t_ns, kind="stable")
    t_ns = t_ns[order]
    accel = (imu.accel_m_s2[inside][order]) @ imu_to_base[:3, :3].T
    t_s = (t_ns - t_ns[0]).astype(np.float64) / 1e9
    rest0 = t_s <= REST_S
    rest1 = t_s >= t_s[-1] - REST_S
    if rest0.sum() < 3 or rest1.sum() < 3:
        return None
    up = accel[rest0].mean(axis=0) + accel[rest1].mean(axis=0)
    norm = float(np.linalg.norm(up))
    if norm <= 0:
        return None
    force = accel @ (up / norm)
    # At rest the force along up is gravity plus the bias, a little different at the two ends.
    g0, g1 = float(force[rest0].mean()), float(force[rest1].mean())
    vertical = force - (g0 + (g1 - g0) * t_s / max(t_s[-1], 1e-9))
    dt = np.diff(t_s)
    velocity = np.concatenate([[0.0], np.cumsum(0.5 * (vertical[1:] + vertical[:-1]) * dt)])
    velocity -= velocity[-1] * t_s / max(t_s[-1], 1e-9)  # zero at both ends
    height = np.concatenate([[0.0], np.cumsum(0.5 * (velocity[1:] + velocity[:-1]) * dt)])
    total = float(height[-1])
    if abs(total) < 0.5:
        return None  # not a ride the accelerometer saw
    return t_ns, height / total
