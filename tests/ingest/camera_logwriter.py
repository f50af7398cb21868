"""Small depth-camera logs written by the REAL writers (mcap, rosbags), with known geometry.

Every camera looks at one plane whose depth image is computed exactly per pixel, so the decoded
points can be checked against the plane in metres: cam1 16UC1 millimetres with a jpeg colour
camera of its own (other frame, size and intrinsics), cam2 32FC1 metres with plumb_bob
distortion, cam3 16UC1 as compressedDepth PNG (or RVL, with the encoder below).
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from ingest_logwriter import Item, _header, _quat, _vec, typestore, write_mcap_items
from rosbags.typesys.store import Typestore

T0_NS = 1_700_000_000_000_000_000
N_IMAGES, DT_NS = 4, 200_000_000
W, H = 40, 30
K1 = (30.0, 0.0, 19.5, 0.0, 30.0, 14.5, 0.0, 0.0, 1.0)
D2 = (-0.2, 0.05, 0.001, -0.002, 0.0)
CW, CH = 64, 48
KC = (50.0, 0.0, 31.5, 0.0, 50.0, 23.5, 0.0, 0.0, 1.0)
# A plane in each camera's optical frame: n . X = c (tilted, so depths vary over the image).
PLANE_N = np.array([0.15, -0.1, 1.0]) / np.linalg.norm([0.15, -0.1, 1.0])
PLANE_C = 2.0
COLOUR_OFFSET_X = 0.3  # the colour camera sits 30 cm along the depth camera's x axis
RED, BLUE = (220, 30, 30), (30, 30, 220)


def colour_of(xyz: np.ndarray) -> np.ndarray:
    """The plane's paint at points in cam1's optical frame: red where x < 0, blue elsewhere."""
    return np.where((xyz[:, 0] < 0.0)[:, None], np.array(RED), np.array(BLUE)).astype(np.uint8)


def undistort(uv: np.ndarray, k: tuple[float, ...], d: tuple[float, ...]) -> np.ndarray:
    """Normalised undistorted coordinates of pixels under plumb_bob, by fixed-point iteration
    (independent of OpenCV, which the decoder uses)."""
    k1, k2, p1, p2, k3 = d
    xd = (uv[:, 0] - k[2]) / k[0]
    yd = (uv[:, 1] - k[5]) / k[4]
    x, y = xd.copy(), yd.copy()
    for _ in range(200):
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2**3
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        x, y = (xd - dx) / radial, (yd - dy) / radial
    return np.column_stack([x, y])


def rvl_encode(pixels: np.ndarray) -> bytes:
    """RVL (Wilson, "Fast Lossless Depth Image Compression") of 16-bit pixels, written the way
    the paper's CompressRVL does it, one nibble at a time: runs of zeros and non-zeros, zigzag
    deltas in 3-bit groups, nibbles filling 32-bit little-endian words from the top."""
    words: list[int] = []
    word, nibbles = 0, 0

    def vle(value: int) -> None:
        nonlocal word, nibbles
        while True:
            nibble = value & 0x7
            value >>= 3
            if value:
                nibble |= 0x8
            word = ((word << 4) | nibble) & 0xFFFFFFFF
            nibbles += 1
            if nibbles == 8:
                words.append(word)
                word, nibbles = 0, 0
            if not value:
                return

    flat = [int(v) for v in np.asarray(pixels, dtype=np.uint16).ravel()]
    i, previous = 0, 0
    while i < len(flat):
        zeros = 0
        while i < len(flat) and flat[i] == 0:
            zeros, i = zeros + 1, i + 1
        vle(zeros)
        nonzeros = 0
        while i + nonzeros < len(flat) and flat[i + nonzeros] != 0:
            nonzeros += 1
        vle(nonzeros)
        for current in flat[i: i + nonzeros]:
            delta = current - previous
            vle((delta << 1) ^ (delta >> 31))
            previous = current
        i += nonzeros
    if nibbles:
        words.append((word << (4 * (8 - nibbles))) & 0xFFFFFFFF)
    return struct.pack(f"<{len(words)}I", *words)


def plane_depth(k: tuple[float, ...], d: tuple[float, ...] | None = None) -> np.ndarray:
    """(H, W) depth in metres of the plane at each pixel (z along the optical axis)."""
    vv, uu = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    uv = np.column_stack([uu.ravel(), vv.ravel()]).astype(np.float64)
    if d is None:
        norm = np.column_stack([(uv[:, 0] - k[2]) / k[0], (uv[:, 1] - k[5]) / k[4]])
    else:
        norm = undistort(uv, k, d)
    rays = np.column_stack([norm, np.ones(len(norm))])
    return (PLANE_C / (rays @ PLANE_N)).reshape(H, W)


def colour_image() -> np.ndarray:
    """(CH, CW, 3) RGB of the plane seen by the colour camera (its own intrinsics and frame)."""
    vv, uu = np.meshgrid(np.arange(CH), np.arange(CW), indexing="ij")
    rays = np.column_stack([(uu.ravel() - KC[2]) / KC[0], (vv.ravel() - KC[5]) / KC[4], np.ones(uu.size)])
    # The plane in the colour frame: n . (X + offset) = c.
    t = (PLANE_C - PLANE_N[0] * COLOUR_OFFSET_X) / (rays @ PLANE_N)
    pts_depth_frame = rays * t[:, None] + np.array([COLOUR_OFFSET_X, 0.0, 0.0])
    return colour_of(pts_depth_frame).reshape(CH, CW, 3)


def _info(store: Typestore, stamp: int, frame: str, w: int, h: int, k: tuple[float, ...],
          d: tuple[float, ...]) -> Any:
    names = [f[0] for f in store.fielddefs["sensor_msgs/msg/CameraInfo"][1]]
    upper = "K" in names
    roi = store.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0,
                                                          do_rectify=False)
    kw: dict[str, Any] = {
        "header": _header(store, stamp, frame), "height": h, "width": w,
        "distortion_model": "plumb_bob", "binning_x": 0, "binning_y": 0, "roi": roi,
    }
    mats = {"d": np.array(d, dtype=np.float64), "k": np.array(k, dtype=np.float64),
            "r": np.eye(3).ravel(), "p": np.array([k[0], 0, k[2], 0, 0, k[4], k[5], 0, 0, 0, 1, 0],
                                                  dtype=np.float64)}
    for key, value in mats.items():
        kw[key.upper() if upper else key] = value
    return store.types["sensor_msgs/msg/CameraInfo"](**kw)


def _image(store: Typestore, stamp: int, frame: str, encoding: str, pixels: np.ndarray,
           pad: int = 0) -> Any:
    h, w = pixels.shape[:2]
    row = pixels.reshape(h, -1).view(np.uint8).reshape(h, -1)
    step = row.shape[1] + pad
    data = np.zeros((h, step), dtype=np.uint8)
    data[:, : row.shape[1]] = row
    return store.types["sensor_msgs/msg/Image"](
        header=_header(store, stamp, frame), height=h, width=w, encoding=encoding,
        is_bigendian=0, step=step, data=data.ravel())


def _compressed(store: Typestore, stamp: int, frame: str, fmt: str, data: bytes) -> Any:
    return store.types["sensor_msgs/msg/CompressedImage"](
        header=_header(store, stamp, frame), format=fmt, data=np.frombuffer(data, dtype=np.uint8))


def _tf(store: Typestore, child: str, xyz: tuple[float, float, float], q: tuple[float, ...]) -> Any:
    return store.types["geometry_msgs/msg/TransformStamped"](
        header=_header(store, 0, "base_link"), child_frame_id=child,
        transform=store.types["geometry_msgs/msg/Transform"](translation=_vec(store, *xyz),
                                                             rotation=_quat(store, *q)))


# Optical frame (z forward, x right, y down) of a camera looking along the base's x axis.
OPTICAL_Q = (-0.5, 0.5, -0.5, 0.5)
CAM_XYZ = {"cam1_depth": (0.2, 0.0, 0.5), "cam1_color": (0.2, -COLOUR_OFFSET_X, 0.5),
           "cam2": (0.0, 0.2, 0.6), "cam3": (0.0, -0.2, 0.7)}


def camera_items(store: Typestore, drop: Iterable[str] = (), frames: dict[str, str] | None = None,
                 encodings: dict[str, str] | None = None, cam3_compression: str = "png") -> list[Item]:
    """(topic, msgtype, log_time_ns, message) of the three cameras and /tf_static; cam3's
    compressedDepth as `cam3_compression` ("png" or "rvl")."""
    frames = frames or {}
    encodings = encodings or {}
    out: list[Item] = []
    mm = np.round(plane_depth(K1) * 1000).astype(np.uint16)
    metres = plane_depth(K1, D2).astype(np.float32)
    ok, jpeg = cv2.imencode(".jpg", colour_image()[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    ok, png = cv2.imencode(".png", mm)
    assert ok
    cdepth = struct.pack("<iff", 0, 0.0, 0.0) + png.tobytes()
    if cam3_compression == "rvl":
        cdepth = struct.pack("<iffII", 0, 0.0, 0.0, W, H) + rvl_encode(mm)
    for i in range(N_IMAGES):
        t = T0_NS + i * DT_NS
        f1, f2, f3 = (frames.get(c, c) for c in ("cam1_depth", "cam2", "cam3"))
        out += [
            ("/cam1/depth/image_raw", "sensor_msgs/msg/Image", t,
             _image(store, t, f1, encodings.get("cam1", "16UC1"), mm, pad=4)),
            ("/cam1/depth/camera_info", "sensor_msgs/msg/CameraInfo", t,
             _info(store, t, f1, W, H, K1, (0.0,) * 5)),
            ("/cam1/color/image_raw/compressed", "sensor_msgs/msg/CompressedImage", t + 3_000_000,
             _compressed(store, t + 3_000_000, "cam1_color", "rgb8; jpeg compressed bgr8", jpeg.tobytes())),
            ("/cam1/color/camera_info", "sensor_msgs/msg/CameraInfo", t + 3_000_000,
             _info(store, t, "cam1_color", CW, CH, KC, (0.0,) * 5)),
            ("/cam2/depth/image_raw", "sensor_msgs/msg/Image", t + 1_000_000,
             _image(store, t + 1_000_000, f2, "32FC1", metres)),
            ("/cam2/depth/camera_info", "sensor_msgs/msg/CameraInfo", t + 1_000_000,
             _info(store, t, f2, W, H, K1, D2)),
            ("/cam3/depth/image_raw/compressedDepth", "sensor_msgs/msg/CompressedImage", t + 2_000_000,
             _compressed(store, t + 2_000_000, f3, f"16UC1; compressedDepth {cam3_compression}", cdepth)),
            ("/cam3/depth/camera_info", "sensor_msgs/msg/CameraInfo", t + 2_000_000,
             _info(store, t, f3, W, H, K1, (0.0,) * 5)),
        ]
    tfs = [_tf(store, c, xyz, OPTICAL_Q) for c, xyz in CAM_XYZ.items()]
    out.append(("/tf_static", "tf2_msgs/msg/TFMessage", T0_NS - 1_000_000,
                store.types["tf2_msgs/msg/TFMessage"](transforms=tfs)))
    out = [it for it in out if not any(it[0].startswith(p) for p in drop)]
    out.sort(key=lambda m: m[2])
    return out


def write_camera_log(folder: Path, fmt: str, edit: Callable[[Typestore], list[Item]] | None = None,
                     **kw: Any) -> Path:
    """The camera log in `fmt` ('mcap-ros2', 'mcap-ros1', 'ros1', 'ros2-sqlite3')."""
    from ingest_logwriter import _write_ros1, _write_ros2

    folder.mkdir(parents=True, exist_ok=True)

    def items(store: Typestore) -> list[Item]:
        return edit(store) if edit is not None else camera_items(store, **kw)

    if fmt.startswith("mcap-"):
        ros1 = fmt == "mcap-ros1"
        store = typestore(ros1)
        return write_mcap_items(folder / "log.mcap", items(store), store, ros1=ros1)
    if fmt == "ros1":
        return _write_ros1(folder / "log.bag", "none", items)
    return _write_ros2(folder / "log", "sqlite3", items)


def plane_distance(xyz: np.ndarray) -> np.ndarray:
    """Distance of points (a camera's optical frame) from the plane."""
    return np.abs(xyz.astype(np.float64) @ PLANE_N - PLANE_C)



