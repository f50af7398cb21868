"""compressedDepth in its RVL form: the codec against a hand-made stream, an encoder written as
the paper's, and logs written by the real writers holding an RVL depth stream."""

from __future__ import annotations

import struct
from pathlib import Path
from types import SimpleNamespace

import camera_logwriter as cw
import numpy as np
import pytest

from mfmap.errors import DecodeError
from mfmap.ingest import open_log
from mfmap.ingest.camera_config import CameraConfig
from mfmap.ingest.depth import COMPRESSED, camera_points, decode_depth, find_cameras
from mfmap.ingest.rvl import rvl_decode

# [0, 0, 5, 6, 0]: 2 zeros, 2 non-zeros, delta 5 (zigzag 10 = groups 2 and 1, so nibbles 0xA
# then 0x1), delta 1 (zigzag 2), 1 zero, 0 non-zeros. Seven nibbles 2 2 A 1 2 1 0 and one of
# padding fill the word 0x22A12100, stored little-endian.
HAND = bytes([0x00, 0x21, 0xA1, 0x22])


def test_hand_made_stream() -> None:
    assert cw.rvl_encode(np.array([0, 0, 5, 6, 0])) == HAND
    assert rvl_decode(HAND, 5).tolist() == [0, 0, 5, 6, 0]


@pytest.mark.parametrize("case", ["noise", "holes", "full", "zeros", "extremes"])
def test_round_trip(case: str) -> None:
    rng = np.random.default_rng(7)
    pixels = {
        "noise": rng.integers(0, 65536, 997),
        "holes": np.where(rng.random(2000) < 0.3, 0, 1500 + np.cumsum(rng.integers(-9, 10, 2000))),
        "full": np.arange(1, 801) * 37 % 65535 + 1,
        "zeros": np.zeros(333, dtype=int),
        "extremes": np.array([65535, 1, 65535, 0, 0, 1, 65535] * 20),
    }[case].astype(np.uint16)
    np.testing.assert_array_equal(rvl_decode(cw.rvl_encode(pixels), pixels.shape[0]), pixels)


def _message(fmt: str, data: bytes) -> SimpleNamespace:
    return SimpleNamespace(format=fmt, data=np.frombuffer(data, dtype=np.uint8))


def test_32fc1_rvl_is_quantised_inverse_depth() -> None:
    """As the plug-in writes a 32FC1 image: v = a / d + b with a = z0 (z0 + 1), b = 1 - a / max."""
    depth = np.array([[0.5, 1.0, np.nan], [2.0, 4.0, 9.0]], dtype=np.float32)
    z0, depth_max = 100.0, 10.0  # the plug-in's defaults, depth_quantization and depth_max
    a = np.float32(z0 * (z0 + 1.0))
    b = np.float32(1.0 - a / depth_max)
    with np.errstate(invalid="ignore"):
        v = np.where(depth < depth_max, a / depth + b, 0)
    v = np.nan_to_num(v).astype(np.uint16)
    data = struct.pack("<iffII", 0, a, b, 3, 2) + cw.rvl_encode(v)
    out = decode_depth(_message("32FC1; compressedDepth rvl", data), COMPRESSED, "t")
    assert np.isnan(out[0, 2])
    np.testing.assert_allclose(out[np.isfinite(out)], depth[np.isfinite(depth)], rtol=2e-3)


def test_corrupt_rvl_names_the_topic() -> None:
    good = struct.pack("<iffII", 0, 0.0, 0.0, 5, 1) + HAND
    assert decode_depth(_message("16UC1; compressedDepth rvl", good), COMPRESSED, "t").shape == (1, 5)
    short = struct.pack("<iffII", 0, 0.0, 0.0, 6, 1) + HAND  # one pixel more than the stream holds
    with pytest.raises(DecodeError, match=r"/d/compressedDepth: compressedDepth RVL stream is corrupt"):
        decode_depth(_message("16UC1; compressedDepth rvl", short), COMPRESSED, "/d/compressedDepth")
    huge = struct.pack("<iffII", 0, 0.0, 0.0, 4000, 3000) + HAND
    with pytest.raises(DecodeError, match="claims 4000 x 3000"):
        decode_depth(_message("16UC1; compressedDepth rvl", huge), COMPRESSED, "t")
    with pytest.raises(DecodeError, match="compression 'zstd' is not supported"):
        decode_depth(_message("16UC1; compressedDepth zstd", good), COMPRESSED, "t")


@pytest.mark.parametrize("fmt", ["mcap-ros2", "ros2-sqlite3", "ros1"])
def test_rvl_stream_in_a_log(tmp_path: Path, fmt: str) -> None:
    """cam3 written as "16UC1; compressedDepth rvl" by mcap / rosbags: its millimetres back
    exactly, its points on the plane."""
    log = cw.write_camera_log(tmp_path, fmt, cam3_compression="rvl")
    cfg = CameraConfig(decimation=1, max_range_m=10.0)
    mm = np.round(cw.plane_depth(cw.K1) * 1000) / 1000
    with open_log(log) as src:
        cams, warnings = find_cameras(src, cfg)
        assert warnings == []
        cam3 = next(c for c in cams if c.depth_topic == "/cam3/depth/image_raw/compressedDepth")
        clouds = list(camera_points(src, cam3, cfg))
    assert len(clouds) == cw.N_IMAGES
    for cloud in clouds:
        assert cloud.xyz.shape[0] == cw.W * cw.H
        np.testing.assert_allclose(np.sort(cloud.xyz[:, 2]), np.sort(mm.ravel()), atol=1e-6)
        assert cw.plane_distance(cloud.xyz).max() < 1.5e-3
