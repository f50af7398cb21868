"""Height-trace filters: uniform resampling, Hampel spike rejection, the steady-state RTS smoother
and the LeGO-LOAM elevator paper's sliding mean. Everything is vectorised (scipy.signal / scipy.ndimage), so an hour
at 50 Hz filters in tens of milliseconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import linalg, ndimage, signal

from mfmap.types import F64

MAD_TO_SIGMA = 1.4826
# Cells of the uniform grid per sample at most (a trace with gaps needs a few).
MAX_GRID_PER_SAMPLE = 50
# Half-width of the cluster that is a floor's level (door steps are 0.4 m and more).
LEVEL_MODE_HALF_WIDTH_M = 0.2


@dataclass(frozen=True)
class Grid:
    """A uniform time grid (seconds relative to t0_s) and the trace resampled onto it."""

    t0_s: float
    dt_s: float
    values: F64

    @property
    def times_s(self) -> F64:
        return self.t0_s + self.dt_s * np.arange(self.values.shape[0], dtype=np.float64)


def resample_uniform(times_s: F64, values: F64) -> Grid:
    """Linear interpolation onto a grid at the median sample interval (phones jitter, logs drop)."""
    diffs = np.diff(times_s)
    dt_s = float(np.median(diffs[diffs > 0])) if np.any(diffs > 0) else 1.0
    n = int(np.floor((times_s[-1] - times_s[0]) / dt_s)) + 1
    if n > MAX_GRID_PER_SAMPLE * times_s.shape[0] + 100_000:
        # The grid is sized by the trace's duration: a trace that is mostly gaps must not
        # allocate by its span (a stamp a year ahead once asked for 1.5e9 cells).
        from mfmap.errors import MissingDataError

        raise MissingDataError(
            f"the barometer trace is mostly gaps: {times_s.shape[0]} samples over "
            f"{times_s[-1] - times_s[0]:.0f} s at {dt_s:.3g} s intervals")
    grid_s = times_s[0] + dt_s * np.arange(n, dtype=np.float64)
    return Grid(float(times_s[0]), dt_s, np.interp(grid_s, times_s, values))


def robust_noise_sigma(values: F64, lag: int = 1) -> float:
    """Noise (1 sigma) from the MAD of differences `lag` samples apart; motion barely moves it.

    A phone's barometer wanders (coloured noise): its neighbouring samples agree far better than
    samples a second apart, so the smoother should be tuned on the longer lag.
    """
    if values.shape[0] < lag + 2:
        return 0.0
    d = values[lag:] - values[:-lag]
    return float(MAD_TO_SIGMA * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0))


def hampel(values: F64, half_window: int, threshold_sigma: float) -> tuple[F64, int]:
    """Replace samples further than threshold_sigma robust sigmas from their window median.

    Returns the cleaned values and how many samples were replaced. The sigma is the global
    difference-based noise (a floor of it), so a quiet window does not flag ordinary noise.
    """
    size = 2 * max(1, half_window) + 1
    med = ndimage.median_filter(values, size=size, mode="nearest")
    dev = np.abs(values - med)
    local = MAD_TO_SIGMA * ndimage.median_filter(dev, size=size, mode="nearest")
    sigma = np.maximum(local, robust_noise_sigma(values))
    spikes = dev > threshold_sigma * np.maximum(sigma, 1e-9)
    out = np.where(spikes, med, values)
    return out, int(np.count_nonzero(spikes))


def sliding_mean(values: F64, window: int) -> F64:
    """The filter of the LeGO-LOAM elevator paper: the mean of the last `window` samples (fewer at the start)."""
    csum = np.concatenate(([0.0], np.cumsum(values)))
    idx = np.arange(values.shape[0])
    lo = np.maximum(0, idx + 1 - window)
    return np.asarray((csum[idx + 1] - csum[lo]) / (idx + 1 - lo), dtype=np.float64)


@dataclass(frozen=True)
class SteadyStateGains:
    """Constant-velocity model [height, vertical speed] and its steady-state Kalman/RTS gains."""

    F: F64  # (2, 2) transition
    K: F64  # (2,) Kalman gain
    C: F64  # (2, 2) RTS smoother gain


def steady_state_gains(dt_s: float, noise_m: float, accel_noise_m_s2: float) -> SteadyStateGains:
    """Solve the discrete Riccati equation for a white-noise-acceleration model.

    accel_noise_m_s2 is the acceleration's spectral density as a 1-sigma over 1 s (q = a^2).
    """
    F = np.array([[1.0, dt_s], [0.0, 1.0]])
    q = accel_noise_m_s2**2
    Q = q * np.array([[dt_s**3 / 3.0, dt_s**2 / 2.0], [dt_s**2 / 2.0, dt_s]])
    H = np.array([[1.0, 0.0]])
    R = np.array([[max(noise_m, 1e-6) ** 2]])
    P_pred = linalg.solve_discrete_are(F.T, H.T, Q, R)  # a priori covariance
    S = float((H @ P_pred @ H.T)[0, 0] + R[0, 0])
    K = (P_pred @ H.T)[:, 0] / S
    P_filt = (np.eye(2) - np.outer(K, H[0])) @ P_pred
    C = P_filt @ F.T @ np.linalg.inv(P_pred)
    return SteadyStateGains(F=F, K=K, C=C)


def rts_smooth(values: F64, dt_s: float, noise_m: float, accel_noise_m_s2: float) -> tuple[F64, F64]:
    """Forward Kalman filter + backward RTS pass with steady-state gains, as IIR filters.

    With constant gains both passes are linear time-invariant 2-state recursions, so each state
    is a second-order IIR filter that scipy.signal.lfilter runs in C. Returns (height, speed).
    """
    n = values.shape[0]
    if n < 3:
        return values.copy(), np.zeros(n)
    g = steady_state_gains(dt_s, noise_m, accel_noise_m_s2)
    # Forward: x_k = A x_{k-1} + K z_k with A = (I - K H) F; X = (I - A z^-1)^-1 K Z.
    A = (np.eye(2) - np.outer(g.K, [1.0, 0.0])) @ g.F
    den = np.array([1.0, -(A[0, 0] + A[1, 1]), A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]])
    k1, k2 = g.K
    num_h = np.array([k1, -A[1, 1] * k1 + A[0, 1] * k2])
    num_v = np.array([k2, A[1, 0] * k1 - A[0, 0] * k2])
    z0 = values[0]
    # Start in the steady state of a robot standing at the first sample: no start-up transient.
    fh, _ = signal.lfilter(num_h, den, values, zi=signal.lfilter_zi(num_h, den) * z0)
    fv, _ = signal.lfilter(num_v, den, values, zi=signal.lfilter_zi(num_v, den) * z0)
    # Backward: s_k = C s_{k+1} + (I - C F) f_k, run on the reversed sequence. The last filtered
    # height is subtracted so zero initial conditions are the steady state of standing there.
    C = g.C
    B = np.eye(2) - C @ g.F
    h_end = fh[-1]
    u1 = (B[0, 0] * (fh - h_end) + B[0, 1] * fv)[::-1]
    u2 = (B[1, 0] * (fh - h_end) + B[1, 1] * fv)[::-1]
    dden = np.array([1.0, -(C[0, 0] + C[1, 1]), C[0, 0] * C[1, 1] - C[0, 1] * C[1, 0]])
    sh = signal.lfilter([1.0, -C[1, 1]], dden, u1) + signal.lfilter([0.0, C[0, 1]], dden, u2)
    sv = signal.lfilter([0.0, C[1, 0]], dden, u1) + signal.lfilter([1.0, -C[0, 0]], dden, u2)
    return np.asarray(sh[::-1] + h_end, dtype=np.float64), np.asarray(sv[::-1], dtype=np.float64)


def rts_smooth_reference(
    values: F64, dt_s: float, noise_m: float, accel_noise_m_s2: float
) -> tuple[F64, F64]:
    """The textbook time-varying Kalman + RTS smoother in a Python loop (for tests only: slow)."""
    g = steady_state_gains(dt_s, noise_m, accel_noise_m_s2)
    F = g.F
    q = accel_noise_m_s2**2
    Q = q * np.array([[dt_s**3 / 3.0, dt_s**2 / 2.0], [dt_s**2 / 2.0, dt_s]])
    r = noise_m**2
    n = values.shape[0]
    xf = np.zeros((n, 2))
    Pf = np.zeros((n, 2, 2))
    xp = np.zeros((n, 2))
    Pp = np.zeros((n, 2, 2))
    x = np.array([values[0], 0.0])
    P = np.diag([r, 1.0])
    for k in range(n):
        if k > 0:
            x = F @ x
            P = F @ P @ F.T + Q
        xp[k], Pp[k] = x, P
        s = P[0, 0] + r
        K = P[:, 0] / s
        x = x + K * (values[k] - x[0])
        P = P - np.outer(K, P[0, :])
        xf[k], Pf[k] = x, P
    xs = xf.copy()
    for k in range(n - 2, -1, -1):
        Ck = Pf[k] @ F.T @ np.linalg.inv(Pp[k + 1])
        xs[k] = xf[k] + Ck @ (xs[k + 1] - xp[k + 1])
    return xs[:, 0], xs[:, 1]


def running_median_1s(values: F64, dt_s: float) -> F64:
    """Running median over about one second: noise down, pressure steps kept sharp."""
    size = max(3, round(1.0 / dt_s) | 1)
    return np.asarray(ndimage.median_filter(values, size=size, mode="nearest"), dtype=np.float64)


def step_size(median: F64, dt_s: float) -> F64:
    """Change of a running median over +-0.15 s at every sample (abrupt pressure steps)."""
    edge = max(1, round(0.15 / dt_s))
    padded = np.concatenate((np.full(edge, median[0]), median, np.full(edge, median[-1])))
    return np.asarray(padded[2 * edge :] - padded[: -2 * edge], dtype=np.float64)


def remove_transients(
    values: F64, dt_s: float, max_duration_s: float, max_amplitude_m: float, median: F64 | None = None
) -> tuple[F64, int]:
    """Remove short pressure pulses (a door, the HVAC): an abrupt step, then back, within seconds.

    Grey-scale opening finds positive pulses narrower than its window and closing negative
    ones, while any monotone stretch (a ride, a stair climb with landings) passes exactly. They
    run on an edge-preserving running median, so a pulse's edges stay sharp and the pulse
    (median - opened, or closed - median) can be subtracted from the samples. A candidate must
    stand well above the median's own noise, must jump abruptly at both ends (a short stay
    between a ride and a dip is not a pulse), and must be lower than max_amplitude_m: a short
    visit to another floor is not a transient. Returns the cleaned values and the pulse count.
    """
    n = values.shape[0]
    size = 2 * max(1, round(max_duration_s / dt_s / 2.0)) + 1
    med_size = max(3, round(1.0 / dt_s) | 1)
    if n < 2 * size:
        return values.copy(), 0
    if median is None:
        median = running_median_1s(values, dt_s)
    lagged = median[med_size:] - median[:-med_size]
    sigma = MAD_TO_SIGMA * float(np.median(np.abs(lagged - np.median(lagged)))) / np.sqrt(2.0)

    def erode(x: F64) -> F64:
        return np.asarray(ndimage.minimum_filter1d(x, size, mode="nearest"), dtype=np.float64)

    def dilate(x: F64) -> F64:
        return np.asarray(ndimage.maximum_filter1d(x, size, mode="nearest"), dtype=np.float64)

    edge = max(2, round(0.15 / dt_s))
    flank = max(4, round(1.5 / dt_s))
    gap = max(1, round(0.2 / dt_s))
    # Step size at each sample over +-0.15 s: a pulse's edges jump by about its height, a stair
    # climb or ride moves far less in 0.3 s.
    padded = np.concatenate((np.full(edge, median[0]), median, np.full(edge, median[-1])))
    jump = padded[2 * edge :] - padded[: -2 * edge]
    out = values.copy()
    removed = 0
    check = _PulseCheck(median, jump, sigma, max_amplitude_m, n, edge, flank, gap)
    for pulse in (median - dilate(erode(median)), -(erode(dilate(median)) - median)):
        for i0, i1 in true_runs(np.abs(pulse) > 2.5 * sigma):
            if not check.is_pulse(pulse, i0, i1):
                continue
            lo, hi = max(0, i0 - edge), min(n, i1 + edge)
            out[lo:hi] -= pulse[lo:hi]
            removed += 1
    return out, removed


@dataclass(frozen=True)
class _PulseCheck:
    """Whether a candidate of `remove_transients` is a pulse: high above the running median's
    noise, on level flanks that agree, with abrupt edges, and not a floor's height."""

    median: F64
    jump: F64  # step size of the median at each sample over +-edge samples
    sigma: float  # the median's noise
    max_amplitude_m: float
    n: int  # samples of the trace
    edge: int  # samples
    flank: int
    gap: int

    def is_pulse(self, pulse: F64, i0: int, i1: int) -> bool:
        median, jump, sigma = self.median, self.jump, self.sigma
        n, edge, flank, gap = self.n, self.edge, self.flank, self.gap
        if float(np.max(np.abs(pulse[i0:i1]))) < max(6.0 * sigma, 0.1):
            return False  # noise: most candidates end here, before any median is taken
        # A pulse sits on a level stretch and returns to it: both flanks flat and equal. A
        # stay between a ride and a dip fails this, its ride flank is a slope.
        lo_f, hi_f = i0 - gap - flank, i1 + gap + flank
        if lo_f < 0 or hi_f > n:
            return False
        before = median[lo_f : i0 - gap]
        after = median[i1 + gap : hi_f]
        # Height against the flanks (the opening's own noise floor would inflate it).
        peak = float(np.median(median[i0:i1]) - np.median(np.concatenate((before, after))))
        if abs(peak) < max(6.0 * sigma, 0.1) or abs(peak) > self.max_amplitude_m:
            return False
        half_f = flank // 2
        slope = max(
            abs(float(np.median(before[:half_f]) - np.median(before[half_f:]))),
            abs(float(np.median(after[:half_f]) - np.median(after[half_f:]))),
        )
        step = abs(float(np.median(before) - np.median(after)))
        if slope > 0.3 * abs(peak) or step > 0.4 * abs(peak):
            return False
        half = max(1, (i1 - i0) // 2)
        sign = np.sign(peak)
        rise = float(np.max(sign * jump[max(0, i0 - edge) : i0 + half]))
        fall = float(np.max(-sign * jump[i1 - half : min(n, i1 + edge)]))
        return not min(rise, fall) < 0.35 * abs(peak)


def true_runs(mask: npt.NDArray[np.bool_]) -> list[tuple[int, int]]:
    """(start, end) index pairs, end exclusive, of the runs of True in mask."""
    padded = np.concatenate(([0], mask.astype(np.int8), [0]))
    edges = np.flatnonzero(np.diff(padded))
    return list(zip(edges[0::2].tolist(), edges[1::2].tolist(), strict=True))


def ramp_profile(tau: F64, corner: F64) -> F64:
    """Normalised height 0 -> 1 over tau in [0, 1] with a trapezoidal speed profile.

    corner is the fraction of the move spent accelerating (and again decelerating): 0 is a
    straight ramp (stairs at a steady pace), 0.5 a triangular speed profile (a short ride).
    Both arrays broadcast; corner may be 0.
    """
    tau = np.clip(tau, 0.0, 1.0)
    c = np.maximum(corner, 1e-9)
    v_max = 1.0 / (1.0 - c)
    # Cruise line, bent into parabolas over the first and last `c` of the move.
    early = np.minimum(tau, c)
    late = np.maximum(tau - (1.0 - c), 0.0)
    out = v_max * (early**2 / (2.0 * c) + (tau - early) - late**2 / (2.0 * c))
    return np.asarray(out, dtype=np.float64)


def fit_ramp(
    times_s: F64, values: F64, start_s: F64, end_s: F64, corners: F64
) -> tuple[int, float, float, float]:
    """Least-squares flat-ramp-flat fit over candidate (start, end, corner) triples.

    The two levels are solved in closed form for every candidate, so the search is one
    vectorised pass. Returns the best candidate's index, its levels (before, after) and SSE.
    """
    span = np.maximum(end_s - start_s, 1e-6)
    tau = (times_s[None, :] - start_s[:, None]) / span[:, None]
    s = ramp_profile(tau, corners[:, None])
    u = 1.0 - s
    a11 = np.einsum("ij,ij->i", u, u)
    a12 = np.einsum("ij,ij->i", u, s)
    a22 = np.einsum("ij,ij->i", s, s)
    r1 = u @ values
    r2 = s @ values
    det = np.maximum(a11 * a22 - a12**2, 1e-12)
    a = (a22 * r1 - a12 * r2) / det
    b = (a11 * r2 - a12 * r1) / det
    sse = float(values @ values) - (a * r1 + b * r2)
    best = int(np.argmin(sse))
    return best, float(a[best]), float(b[best]), float(sse[best])


def robust_level(values: F64, half_width_m: float = LEVEL_MODE_HALF_WIDTH_M) -> float:
    """The level a stretch of height samples sits at: the densest +-half_width_m cluster.

    A median is pulled by a door/HVAC step covering part of the window; the densest cluster
    is not, as long as the floor's own level holds the most samples.
    """
    if values.shape[0] < 10:
        return float(np.median(values))
    x = np.sort(values)
    counts = np.searchsorted(x, x + half_width_m, side="right") - np.searchsorted(x, x - half_width_m, side="left")
    centre = x[int(np.argmax(counts))]
    near = x[(x >= centre - half_width_m) & (x <= centre + half_width_m)]
    return float(np.median(near))
