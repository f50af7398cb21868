"""pipelines/ride_noise.py: a simulated log's rides replayed through the IMU ride estimator."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from pipelines.ride_noise import main, ride_errors, rides_of


def test_a_noise_free_accelerometer_gives_the_true_ride_height() -> None:
    # The bias alone, a fresh one per draw: the stand-stills and the zero-velocity ends take it
    # out, so what the script measures at a density is that density's noise.
    (ride,) = rides_of("tiny", 0, 1.0, "tiny")
    assert ride.height_change_m == pytest.approx(3.5, abs=0.01)
    errors = ride_errors(ride, 0.0, 5, np.random.default_rng(0))
    assert np.all(np.abs(errors) < 0.002)
    noisy = ride_errors(ride, 300.0, 40, np.random.default_rng(1))
    # The simulator's accelerometer over a 3.5 m ride: about 0.8 cm RMS.
    assert 0.003 < float(np.sqrt(np.mean(noisy**2))) < 0.02


def test_prints_the_share_within_one_centimetre(
    write_manifest: Callable[..., Path], capsys: pytest.CaptureFixture[str]
) -> None:
    path = write_manifest({"name": "one", "baseline": "b.json",
                           "logs": [{"name": "tiny", "simulate": {"scenario": "tiny", "seed": 0}}]})
    assert main([str(path), "--draws", "3", "--densities", "0,300"]) == 0
    out = capsys.readouterr().out
    assert "| 0 | 100% |" in out
    assert "tiny ride 1 (building floors 0 -> 1) | +3.50 |" in out


@pytest.mark.parametrize(("scenario", "code", "message"), [
    ("single-floor", 1, "no simulated elevator rides"),
    ("no-such", 2, "unknown scenario 'no-such'"),
])
def test_a_manifest_it_cannot_use_is_one_line(
    write_manifest: Callable[..., Path], capsys: pytest.CaptureFixture[str], scenario: str, code: int,
    message: str,
) -> None:
    path = write_manifest({"name": "m", "baseline": "b.json",
                           "logs": [{"name": "x", "simulate": {"scenario": scenario, "seed": 0}}]})
    assert main([str(path), "--draws", "1"]) == code
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1


def test_a_missing_manifest_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main([str(tmp_path / "none.yaml")]) == 2
    assert capsys.readouterr().err.strip() == f"{tmp_path / 'none.yaml'}: manifest not found"
