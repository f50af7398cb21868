"""`mfmap info` lists the cameras: kind, encoding, size, rate, frame, CameraInfo, transform."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import camera_logwriter as cw

from mfmap.ingest.camera_info import describe_cameras


def test_rows_of_the_camera_log(tmp_path: Path) -> None:
    log = cw.write_camera_log(tmp_path, "mcap-ros2", drop=["/cam2/depth/camera_info"],
                              frames={"cam3": "cam3_nowhere"}, cam3_compression="rvl")
    rows, skipped = describe_cameras(log)
    by = {r["topic"]: r for r in rows}
    assert sorted(by) == ["/cam1/color/image_raw/compressed", "/cam1/depth/image_raw",
                          "/cam2/depth/image_raw", "/cam3/depth/image_raw/compressedDepth"]
    cam1 = by["/cam1/depth/image_raw"]
    assert (cam1["kind"], cam1["encoding"], cam1["width"], cam1["height"]) == ("depth", "16UC1", cw.W, cw.H)
    assert cam1["camera_info"] == "/cam1/depth/camera_info" and cam1["transform"] is True
    assert cam1["used"] == "depth" and cam1["frame"] == "cam1_depth"
    assert abs(cam1["rate_hz"] - 1e9 / cw.DT_NS) < 1e-6 and cam1["count"] == cw.N_IMAGES
    colour = by["/cam1/color/image_raw/compressed"]
    assert (colour["kind"], colour["width"], colour["height"]) == ("colour", cw.CW, cw.CH)
    assert colour["used"] == "colour of /cam1/depth/image_raw"
    cam2 = by["/cam2/depth/image_raw"]
    assert cam2["camera_info"] is None and cam2["used"] == ""
    cam3 = by["/cam3/depth/image_raw/compressedDepth"]
    assert cam3["encoding"] == "16UC1; compressedDepth rvl" and (cam3["width"], cam3["height"]) == (cw.W, cw.H)
    assert cam3["transform"] is False and cam3["used"] == ""
    assert len(skipped) == 2
    assert any("/cam2/depth/image_raw" in s and "CameraInfo" in s for s in skipped)
    assert any("cam3_nowhere" in s for s in skipped)


def test_cli_info_lists_cameras(tmp_path: Path) -> None:
    log = cw.write_camera_log(tmp_path, "mcap-ros2")
    res = subprocess.run([sys.executable, "-m", "mfmap.cli", "info", str(log)], capture_output=True,
                         text=True, timeout=300, env={**os.environ, "COLUMNS": "250"})
    assert res.returncode == 0, res.stderr
    assert "cameras" in res.stdout and "/cam3/depth/image_raw/compressedDepth" in res.stdout
    res = subprocess.run([sys.executable, "-m", "mfmap.cli", "info", str(log), "--json"],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    cams = json.loads(res.stdout)["cameras"]
    assert len(cams) == 4 and sum(c["used"] == "depth" for c in cams) == 3
