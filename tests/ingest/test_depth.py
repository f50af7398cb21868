"""Depth cameras: logs written by the real writers, decoded points checked against the plane."""

from __future__ import annotations

from pathlib import Path

import camera_logwriter as cw
import numpy as np
import pytest

from mfmap.errors import ConfigError
from mfmap.ingest import open_log
from mfmap.ingest.camera_config import CameraConfig, CameraTopics
from mfmap.ingest.depth import CameraProblem, camera_points, find_cameras

FORMATS = ["mcap-ros2", "mcap-ros1", "ros1", "ros2-sqlite3"]


@pytest.fixture(scope="module")
def camera_log(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return {fmt: cw.write_camera_log(tmp_path_factory.mktemp(fmt), fmt) for fmt in FORMATS}


def _cameras(path: Path, config: CameraConfig | None = None) -> tuple[dict[str, object], list[str]]:
    with open_log(path) as src:
        cams, warnings = find_cameras(src, config or CameraConfig(decimation=1, max_range_m=10.0))
        return {c.depth_topic: c for c in cams}, warnings


@pytest.mark.parametrize("fmt", FORMATS)
def test_three_cameras_decode_onto_their_plane(camera_log: dict[str, Path], fmt: str) -> None:
    cfg = CameraConfig(decimation=1, max_range_m=10.0)
    with open_log(camera_log[fmt]) as src:
        cams, warnings = find_cameras(src, cfg)
        assert warnings == []
        by_topic = {c.depth_topic: c for c in cams}
        assert sorted(by_topic) == ["/cam1/depth/image_raw", "/cam2/depth/image_raw",
                                    "/cam3/depth/image_raw/compressedDepth"]
        assert by_topic["/cam1/depth/image_raw"].colour_topic == "/cam1/color/image_raw/compressed"
        assert by_topic["/cam2/depth/image_raw"].colour_topic is None
        for cam in cams:
            clouds = list(camera_points(src, cam, cfg))
            assert len(clouds) == cw.N_IMAGES
            # 16UC1 rounds to the millimetre; 32FC1 is exact but its rays pass the distortion.
            tol = 1.5e-3
            for cloud in clouds:
                dist = cw.plane_distance(cloud.xyz)
                assert dist.max() < tol, (cam.depth_topic, dist.max())
            if cam.colour_topic is None:
                assert clouds[0].rgb is None
                assert clouds[0].xyz.shape[0] == cw.W * cw.H
        # The camera's pose on the robot, from /tf_static: optical z along the base's x.
        cam1 = by_topic["/cam1/depth/image_raw"]
        np.testing.assert_allclose(cam1.to_base[:3, 3], cw.CAM_XYZ["cam1_depth"], atol=1e-9)
        np.testing.assert_allclose(cam1.to_base[:3, 2], [1.0, 0.0, 0.0], atol=1e-9)


def test_distortion_is_undone(camera_log: dict[str, Path]) -> None:
    """cam2's depth is rendered through plumb_bob distortion: taking the pixel's pinhole ray
    instead of the undistorted one puts the corner points centimetres off the plane."""
    cfg = CameraConfig(decimation=1, max_range_m=10.0)
    with open_log(camera_log["mcap-ros2"]) as src:
        cams, _ = find_cameras(src, cfg)
        cam2 = next(c for c in cams if c.depth_topic == "/cam2/depth/image_raw")
        assert cam2.model.distorted
        good = next(camera_points(src, cam2, cfg)).xyz
        from dataclasses import replace

        naive = replace(cam2, model=replace(cam2.model, d=np.zeros(5)))
        bad = next(camera_points(src, naive, cfg)).xyz
    assert cw.plane_distance(good).max() < 1e-3
    assert cw.plane_distance(bad).max() > 0.02


def test_jpeg_colour_is_reprojected_from_its_own_camera(camera_log: dict[str, Path]) -> None:
    """cam1's colour camera is 30 cm aside with other intrinsics and size: each point takes the
    colour of the paint at its own position on the plane (red x < 0, blue x > 0); ignoring the
    offset would paint the points within 30 cm of the edge with the other colour."""
    cfg = CameraConfig(decimation=1, max_range_m=10.0)
    with open_log(camera_log["mcap-ros2"]) as src:
        cams, _ = find_cameras(src, cfg)
        cam1 = next(c for c in cams if c.depth_topic == "/cam1/depth/image_raw")
        assert cam1.colour_model is not None and cam1.colour_model.width == cw.CW
        clouds = list(camera_points(src, cam1, cfg))
    assert len(clouds) == cw.N_IMAGES
    for cloud in clouds:
        assert cloud.rgb is not None and cloud.rgb.shape == cloud.xyz.shape
        assert cloud.xyz.shape[0] > 0.7 * cw.W * cw.H  # the colour camera sees most of it
        # Away from the paint's edge (jpeg blurs a pixel or two), the colour is the paint's.
        far = np.abs(cloud.xyz[:, 0]) > 0.1
        want = cw.colour_of(cloud.xyz[far]).astype(int)
        err = np.abs(cloud.rgb[far].astype(int) - want).max(axis=1)
        assert np.mean(err < 40) > 0.98, np.mean(err < 40)


def test_decimation_and_range_limits(camera_log: dict[str, Path]) -> None:
    with open_log(camera_log["mcap-ros2"]) as src:
        cfg = CameraConfig(decimation=4, max_range_m=10.0)
        cams, _ = find_cameras(src, cfg)
        cam3 = next(c for c in cams if "cam3" in c.depth_topic)
        dec = next(camera_points(src, cam3, cfg)).xyz
        assert dec.shape[0] == len(range(2, cw.H, 4)) * len(range(2, cw.W, 4))
        cut = CameraConfig(decimation=1, min_range_m=0.3, max_range_m=2.0)
        near = next(camera_points(src, cam3, cut)).xyz
    depth = cw.plane_depth(cw.K1)
    assert near.shape[0] == int(np.sum(np.round(depth * 1000) / 1000 <= 2.0))
    assert 0 < near.shape[0] < cw.W * cw.H
    assert near[:, 2].max() <= 2.0


def test_config_is_validated_at_load() -> None:
    from mfmap.config import config_from_dict

    with pytest.raises(ConfigError, match="min_range_m"):
        config_from_dict({"camera": {"min_range_m": 5.0, "max_range_m": 4.0}})
    with pytest.raises(ConfigError, match="decimation"):
        config_from_dict({"camera": {"decimation": 0}})
    with pytest.raises(ConfigError, match="unknown key"):
        config_from_dict({"camera": {"decimate": 2}})


# ----- bad input -----------------------------------------------------------------------------


def test_depth_without_camera_info(tmp_path: Path) -> None:
    log = cw.write_camera_log(tmp_path, "mcap-ros2", drop=["/cam2/depth/camera_info"])
    cams, warnings = _cameras(log)
    assert "/cam2/depth/image_raw" not in cams and len(cams) == 2
    assert len(warnings) == 1
    assert "/cam2/depth/image_raw" in warnings[0] and "CameraInfo" in warnings[0]
    explicit = CameraConfig(cameras=[CameraTopics(depth="/cam2/depth/image_raw")])
    with pytest.raises(CameraProblem, match=r"topic /cam2/depth/image_raw: no sensor_msgs/CameraInfo "
                                            r"on '/cam2/depth/camera_info'"):
        _cameras(log, explicit)


def test_depth_encoding_not_listed(tmp_path: Path) -> None:
    log = cw.write_camera_log(tmp_path, "mcap-ros2", encodings={"cam1": "mono16"})
    cams, _ = _cameras(log)
    assert "/cam1/depth/image_raw" not in cams  # a mono16 image is not taken for a depth image
    explicit = CameraConfig(cameras=[CameraTopics(depth="/cam1/depth/image_raw")])
    with pytest.raises(CameraProblem, match=r"/cam1/depth/image_raw: encoding 'mono16' is not a depth"):
        _cameras(log, explicit)


def test_camera_frame_without_transform(tmp_path: Path) -> None:
    log = cw.write_camera_log(tmp_path, "mcap-ros2", frames={"cam3": "cam3_nowhere"})
    cams, warnings = _cameras(log)
    assert sorted(cams) == ["/cam1/depth/image_raw", "/cam2/depth/image_raw"]
    assert any("cam3_nowhere" in w and "/tf_static" in w for w in warnings)
    explicit = CameraConfig(cameras=[CameraTopics(depth="/cam3/depth/image_raw/compressedDepth")])
    with pytest.raises(CameraProblem, match=r"compressedDepth: no static transform .* 'cam3_nowhere'"):
        _cameras(log, explicit)
