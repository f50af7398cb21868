"""Which heights place the floors (mfmap.graph.heights): the barometer's scale and offsets
calibrated on the scale-true heights, and disagreements settled by the others."""

from __future__ import annotations

import numpy as np
import pytest

from mfmap.graph.heights import Measurement, TransitionHeights, calibrate, decide
from mfmap.types import TransitionKind

ELEVATOR, STAIRS = TransitionKind.ELEVATOR, TransitionKind.STAIRS


def _ride(index: int, a: int, b: int, true_m: float, baro_m: float | None, imu_m: float | None,
          kind: TransitionKind = ELEVATOR, sigma_m: float = 0.012) -> TransitionHeights:
    del true_m  # the truth, for the reader
    source = "imu" if kind == ELEVATOR else "lidar"
    return TransitionHeights(
        index, kind, a, b,
        None if baro_m is None else Measurement("barometer", baro_m, 0.012),
        None if imu_m is None else Measurement(source, imu_m, sigma_m),
    )


def _building(scale: float, offsets_m: dict[int, float], seed: int = 0) -> list[TransitionHeights]:
    """Floors 0, 1, 2 at 0, 5.5 and 9.0 m (a lobby under offices), six rides, a barometer whose
    metres are 1 / scale of true ones and whose floors sit `offsets_m` off."""
    rng = np.random.default_rng(seed)
    z = {0: 0.0, 1: 5.5, 2: 9.0}
    route = [(0, 1), (1, 2), (2, 0), (0, 2), (2, 1), (1, 0)]
    out = []
    for k, (a, b) in enumerate(route):
        true = z[b] - z[a]
        baro = true / scale + offsets_m.get(b, 0.0) - offsets_m.get(a, 0.0) + rng.normal(0, 0.01)
        out.append(_ride(k, a, b, true, baro, true + rng.normal(0, 0.01)))
    return out


def test_scale_and_offsets_come_from_the_rides() -> None:
    """A 35 deg C building read at the assumed 22 deg C: 4.4 % short; the IMU's rides say so."""
    items = _building(1.044, {})
    cal = calibrate(items, (1.0, 0.04), 0.2)
    assert cal.scale == pytest.approx(1.044, abs=0.003)
    assert cal.scale_sigma < 0.01
    assert cal.offset_sigma_m < 0.08  # nothing beyond the noise: the weak prior gives way
    assert cal.usable and cal.pairs == 6
    # With offsets of 30 cm the spread shows in the residuals and the scale still comes out.
    items = _building(1.044, {1: 0.3, 2: -0.25})
    cal = calibrate(items, (1.0, 0.04), 0.2)
    assert cal.scale == pytest.approx(1.044, abs=0.02)
    assert 0.12 < cal.offset_sigma_m < 0.4


def test_without_scale_true_heights_the_barometer_keeps_the_prior() -> None:
    items = [_ride(0, 0, 1, 4.0, 3.9, None), _ride(1, 1, 0, -4.0, -3.9, None)]
    items[0].scale_true_reason = items[1].scale_true_reason = "no IMU"
    cal = calibrate(items, (1.0, 0.04), 0.2)
    assert (cal.scale, cal.scale_sigma, cal.offset_sigma_m, cal.pairs) == (1.0, 0.04, 0.2, 0)
    decide(items, cal, 0)
    assert all(it.use_baro and not it.use_scale_true for it in items)
    # The honest sigma: its noise, 4 % of 3.9 m and two floors' offsets.
    assert cal.baro_sigma_m(items[0]) == pytest.approx(np.sqrt(0.012**2 + (3.9 * 0.04) ** 2 + 2 * 0.2**2), rel=1e-6)
    assert items[0].why.startswith("no scale-true height (no IMU); barometer +3.900 +- 0.")


def test_a_sealed_barometer_is_left_out_with_a_warning() -> None:
    """A barometer in a sealed enclosure sees a third of every height change."""
    items = [_ride(k, a, b, t, t / 3.0, t + 0.003)
             for k, (a, b, t) in enumerate([(0, 1, 4.0), (1, 2, 4.0), (2, 0, -8.0)])]
    cal = calibrate(items, (1.0, 0.04), 0.2)
    assert not cal.usable
    assert len(cal.warnings) == 1
    assert "ride 0->1 +4.00 m (imu) against +1.33 m" in cal.warnings[0]
    assert "ride 2->0 -8.00 m (imu) against -2.67 m" in cal.warnings[0]
    decide(items, cal, 0)
    assert all(it.use_scale_true and not it.use_baro for it in items)
    assert "barometer left out: it disagrees with every scale-true height" in items[0].why
    # A building at 45 deg C is still a building: 1.08 is within what the air allows.
    warm = [_ride(k, a, b, t, t / 1.08, t) for k, (a, b, t) in enumerate([(0, 1, 4.0), (1, 0, -4.0)])]
    assert calibrate(warm, (1.0, 0.04), 0.2).usable


def test_a_pressure_step_at_one_ride_leaves_its_barometric_height_out() -> None:
    """Three rides; at one a door's pressure step put the barometer's level 1 m off. The other
    two rides agree with their barometric heights, so the floors' offsets are small and that
    height is a step: left out, the scale untouched."""
    items = [_ride(0, 0, 1, 4.0, 4.0, 4.0), _ride(1, 1, 2, 4.0, 3.0, 4.0), _ride(2, 2, 0, -8.0, -8.0, -8.0)]
    cal = calibrate(items, (1.0, 0.04), 0.2)
    assert cal.scale == pytest.approx(1.0, abs=0.01)  # a robust mean: pulled a little
    assert cal.offset_sigma_m < 0.15
    decide(items, cal, 0)
    assert [(it.use_scale_true, it.use_baro) for it in items] == [(True, True), (True, False), (True, True)]
    assert items[1].why.startswith("imu +4.000 +- 0.012 m; barometer left out: differs from the other heights "
                                   "of floors 1/2 by -")
    assert calibrate(items, (1.0, 0.04), 0.2, used_only=True).scale == pytest.approx(1.0, abs=0.001)
    # One ride alone, 40 cm apart: as far as anything can tell, a floor held at another pressure.
    items = [_ride(0, 0, 1, 4.0, 3.6, 4.0)]
    decide(items, calibrate(items, (1.0, 0.04), 0.2), 0)
    assert items[0].use_scale_true and items[0].use_baro


def test_the_others_outvote_a_bad_ride() -> None:
    """Floors 0 and 1 by elevator twice and by stairs once, one ride's IMU 40 cm off: the walk
    and the other ride agree, so that ride's IMU is what is left out, not a barometer."""
    items = [
        _ride(0, 0, 1, 4.0, 4.01, 4.0),
        _ride(1, 1, 0, -4.0, -3.99, -3.6),  # the bad IMU
        _ride(2, 0, 1, 4.0, 4.0, 4.03, kind=STAIRS, sigma_m=0.05),
    ]
    cal = calibrate(items, (1.0, 0.04), 0.2)
    decide(items, cal, 0)
    assert [(it.use_scale_true, it.use_baro) for it in items] == [(True, True), (False, True), (True, True)]
    assert items[1].why.startswith("imu left out: differs from the other heights of floors 1/0")
    # The calibration on the kept heights: the bad ride does not pull the scale.
    cal = calibrate(items, (1.0, 0.04), 0.2, used_only=True)
    assert cal.pairs == 2 and cal.scale == pytest.approx(1.0, abs=0.01)
