"""The filters on their own: RTS as IIR filters against the textbook loop, Hampel, pulses."""

from __future__ import annotations

import numpy as np

from mfmap.floors.filters import (
    fit_ramp,
    hampel,
    ramp_profile,
    remove_transients,
    resample_uniform,
    rts_smooth,
    rts_smooth_reference,
    sliding_mean,
)


def test_steady_state_rts_equals_textbook_rts_away_from_the_ends() -> None:
    rng = np.random.default_rng(0)
    dt_s = 0.04
    t = np.arange(3000) * dt_s
    truth = np.clip((t - 40.0) * 1.0, 0.0, 4.0)
    z = truth + rng.normal(0.0, 0.25, t.shape[0])
    fast_h, fast_v = rts_smooth(z, dt_s, 0.25, 0.3)
    ref_h, ref_v = rts_smooth_reference(z, dt_s, 0.25, 0.3)
    inner = slice(250, -250)  # the textbook filter starts from a vague prior, ours in steady state
    assert np.max(np.abs(fast_h - ref_h)[inner]) < 1e-3
    assert np.max(np.abs(fast_v - ref_v)[inner]) < 1e-3
    # And it smooths: residual to the truth far below the 0.25 m sample noise.
    assert float(np.sqrt(np.mean((fast_h - truth)[inner] ** 2))) < 0.08


def test_rts_speed_on_a_steady_climb() -> None:
    rng = np.random.default_rng(1)
    dt_s = 0.1
    t = np.arange(600) * dt_s
    z = np.asarray(0.35 * t + rng.normal(0.0, 0.1, t.shape[0]), dtype=np.float64)
    _, speed = rts_smooth(z, dt_s, 0.1, 0.3)
    assert abs(float(np.mean(speed[100:-100])) - 0.35) < 0.01


def test_sliding_mean_is_a_trailing_mean_shortened_at_the_start() -> None:
    """The LeGO-LOAM elevator paper's baseline filter: each sample the mean of it and the ones
    before it within the window."""
    x = np.arange(10, dtype=np.float64)
    out = sliding_mean(x, 3)
    assert out.tolist() == [0.0, 0.5, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0]


def test_hampel_replaces_exactly_the_spikes() -> None:
    rng = np.random.default_rng(2)
    x = rng.normal(0.0, 0.25, 5000)
    idx = rng.choice(5000, size=20, replace=False)
    spiky = x.copy()
    spiky[idx] += 8.0
    clean, count = hampel(spiky, 25, 4.0)
    assert count == 20
    assert np.max(np.abs(clean[idx])) < 1.0


def test_a_door_pulse_is_removed_and_a_ride_is_left_alone() -> None:
    rng = np.random.default_rng(3)
    dt_s = 0.04
    t = np.arange(int(120 / dt_s)) * dt_s
    ride = np.clip((t - 80.0) * 1.0, 0.0, 4.0)
    pulse = np.where((t >= 30.0) & (t < 34.0), 0.9, 0.0)  # ~10 Pa for 4 s
    z = ride + pulse + rng.normal(0.0, 0.25, t.shape[0])
    clean, count = remove_transients(z, dt_s, 8.0, 1.5)
    assert count == 1
    inside = (t >= 30.5) & (t < 33.5)
    assert abs(float(np.median(clean[inside]))) < 0.1
    # The ride itself passes untouched (monotone signals survive opening and closing).
    around_ride = (t >= 75.0) & (t < 90.0)
    assert np.array_equal(clean[around_ride], z[around_ride])


def test_ramp_profile_and_fit_recover_a_noiseless_ride() -> None:
    tau = np.linspace(0.0, 1.0, 11)
    for corner in (0.0, 0.3, 0.5):
        s = ramp_profile(tau, np.full(tau.shape, corner))
        assert s[0] == 0.0 and abs(s[-1] - 1.0) < 1e-12 and abs(s[5] - 0.5) < 1e-12
        assert np.all(np.diff(s) >= 0)
    t = np.arange(0.0, 30.0, 0.1)
    h = 2.0 + 3.0 * ramp_profile((t - 10.0) / 6.0, np.full(t.shape, 0.3))
    starts = np.array([9.0, 10.0, 11.0, 10.0])
    ends = np.array([16.0, 16.0, 16.0, 17.0])
    corners = np.array([0.3, 0.3, 0.3, 0.3])
    best, before, after, sse = fit_ramp(t, h, starts, ends, corners)
    assert best == 1 and abs(before - 2.0) < 1e-9 and abs(after - 5.0) < 1e-9 and sse < 1e-9


def test_resample_uniform_on_jittered_stamps() -> None:
    rng = np.random.default_rng(4)
    t = np.cumsum(rng.uniform(0.05, 0.15, 500))
    grid = resample_uniform(t, 2.0 * t)
    assert abs(grid.dt_s - float(np.median(np.diff(t)))) < 1e-12
    assert np.allclose(grid.values, 2.0 * grid.times_s)
