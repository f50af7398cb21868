"""Depth cameras: depth and colour images with their CameraInfo -> coloured points.

A depth pixel (u, v) with depth d becomes the point z = d / s, x = (u - cx) z / fx,
y = (v - cy) z / fy in the camera's optical frame (Fan et al., "3D Mapping of Multi-floor
Buildings Based on Sensor Fusion", eqs. 3-5; s is 1000 for 16UC1 millimetres, 1 for 32FC1
metres). With a plumb_bob distortion the pixel's ray is undistorted first (OpenCV), so (u - cx)
/ fx is replaced by the undistorted normalised coordinate. The build then places the points
with the camera's static transform and the base pose at the image's stamp (eq. 6).
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from mfmap.errors import DecodeError, MissingDataError
from mfmap.ingest.camera_config import CameraConfig, CameraTopics
from mfmap.types import F32, F64

if TYPE_CHECKING:
    from mfmap.ingest.source import LogSource

logger = logging.getLogger(__name__)

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"

DEPTH_ENCODINGS = ("16UC1", "32FC1")
COLOUR_ENCODINGS = ("rgb8", "bgr8")
DISTORTION_MODELS = ("plumb_bob", "rational_polynomial", "")

# compressed_depth_image_transport's ConfigHeader ahead of the PNG or RVL payload: int32 format
# (always its INV_DEPTH, 0: the format string says PNG or RVL), float32 depthParam[2] (the
# inverse-depth quantisation of 32FC1 images).
_DEPTH_HEADER = struct.Struct("<iff")


@dataclass(frozen=True)
class CameraModel:
    """A camera's intrinsics from its CameraInfo."""

    frame_id: str
    width: int
    height: int
    k: F64  # (3, 3)
    d: F64  # distortion coefficients (plumb_bob: k1 k2 p1 p2 k3)
    distortion_model: str

    @property
    def distorted(self) -> bool:
        return bool(np.any(self.d != 0.0))


@dataclass(frozen=True)
class Camera:
    """One depth camera of a log: its topics, model and pose on the robot."""

    depth_topic: str
    info_topic: str
    model: CameraModel
    to_base: F64  # (4, 4) optical frame in the base frame
    colour_topic: str | None = None
    colour_model: CameraModel | None = None
    colour_to_base: F64 | None = None


@dataclass(frozen=True)
class CameraPoints:
    """One depth image's points in its camera's optical frame, with their colours if any."""

    stamp_ns: int
    xyz: F32  # (N, 3)
    rgb: np.ndarray[Any, np.dtype[np.uint8]] | None  # (N, 3)


# ----- decoding ------------------------------------------------------------------------------


def _field(msg: Any, name: str) -> Any:
    # ROS 2 spells CameraInfo's matrices in lower case, ROS 1 in upper case.
    value = getattr(msg, name, None)
    return getattr(msg, name.upper()) if value is None else value


def camera_model(msg: Any, where: str) -> CameraModel:
    """A sensor_msgs/CameraInfo as a CameraModel (DecodeError naming `where` if unusable)."""
    k = np.asarray(_field(msg, "k"), dtype=np.float64).reshape(-1)
    d = np.asarray(_field(msg, "d"), dtype=np.float64).reshape(-1)
    model = str(msg.distortion_model)
    width, height = int(msg.width), int(msg.height)
    if k.shape[0] != 9 or not np.all(np.isfinite(k)) or k[0] <= 0 or k[4] <= 0:
        raise DecodeError(f"{where}: CameraInfo has no usable intrinsics K {k.tolist()}")
    if width <= 0 or height <= 0:
        raise DecodeError(f"{where}: CameraInfo has image size {width} x {height}")
    if model not in DISTORTION_MODELS and np.any(d != 0.0):
        raise DecodeError(
            f"{where}: distortion model '{model}' is not supported (plumb_bob, rational_polynomial)")
    if not np.all(np.isfinite(d)):
        raise DecodeError(f"{where}: CameraInfo distortion has non-finite values")
    header = getattr(msg, "header", None)
    frame = str(header.frame_id).lstrip("/") if header is not None else ""
    return CameraModel(frame, width, height, k.reshape(3, 3), d, model)


def _pixels(msg: Any, bytes_per_pixel: int, where: str) -> np.ndarray[Any, np.dtype[np.uint8]]:
    """The image's rows as (height, width * bytes_per_pixel) bytes, row padding removed."""
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    if h <= 0 or w <= 0 or step < w * bytes_per_pixel or data.shape[0] < h * step:
        raise DecodeError(
            f"{where}: image of {w} x {h} with step {step} needs {h * step} bytes, has {data.shape[0]}")
    return data[: h * step].reshape(h, step)[:, : w * bytes_per_pixel]


def decode_depth(msg: Any, msgtype: str, where: str) -> np.ndarray[Any, np.dtype[np.float32]]:
    """A depth image in metres, (height, width) float32; no-returns are NaN."""
    if msgtype == COMPRESSED:
        return _decode_compressed_depth(msg, where)
    encoding = str(msg.encoding)
    if encoding not in DEPTH_ENCODINGS:
        raise DecodeError(f"{where}: depth encoding '{encoding}' is not supported "
                          f"({', '.join(DEPTH_ENCODINGS)})")
    big = bool(msg.is_bigendian)
    rows = _pixels(msg, 2 if encoding == "16UC1" else 4, where)
    if encoding == "16UC1":
        mm = np.ascontiguousarray(rows).view(">u2" if big else "<u2")
        depth = mm.astype(np.float32) / np.float32(1000.0)
        depth[mm == 0] = np.nan
    else:
        depth = np.ascontiguousarray(rows).view(">f4" if big else "<f4").astype(np.float32)
        depth[~np.isfinite(depth) | (depth <= 0)] = np.nan
    return depth


def _decode_compressed_depth(msg: Any, where: str) -> np.ndarray[Any, np.dtype[np.float32]]:
    import cv2

    fmt = str(msg.format)
    encoding = fmt.split(";")[0].strip()
    if "compresseddepth" not in fmt.lower():
        raise DecodeError(f"{where}: CompressedImage format '{fmt}' is not a compressedDepth image")
    if encoding not in DEPTH_ENCODINGS:
        raise DecodeError(f"{where}: compressedDepth encoding '{encoding}' is not supported "
                          f"({', '.join(DEPTH_ENCODINGS)})")
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    if data.shape[0] <= _DEPTH_HEADER.size:
        raise DecodeError(f"{where}: compressedDepth image of {data.shape[0]} bytes has no data")
    _, quant_a, quant_b = _DEPTH_HEADER.unpack(data[: _DEPTH_HEADER.size].tobytes())
    if _compression(fmt, where) == "rvl":
        from mfmap.ingest.rvl import decode_rvl_image

        raw = decode_rvl_image(data[_DEPTH_HEADER.size:].tobytes(), where)
    else:
        png = cv2.imdecode(data[_DEPTH_HEADER.size:], cv2.IMREAD_UNCHANGED)
        if png is None or png.dtype != np.uint16 or png.ndim != 2:
            raise DecodeError(f"{where}: compressedDepth payload is not a 16-bit single-channel PNG")
        raw = np.asarray(png, dtype=np.uint16)
    if encoding == "16UC1":
        depth = raw.astype(np.float32) / np.float32(1000.0)
    else:
        # 32FC1 is stored as quantised inverse depth: d = a / (v - b), v = 0 a no-return.
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = (np.float32(quant_a) / (raw.astype(np.float32) - np.float32(quant_b))).astype(np.float32)
    depth[(raw == 0) | ~np.isfinite(depth) | (depth <= 0)] = np.nan
    return depth


def _compression(fmt: str, where: str) -> str:
    """'png' or 'rvl' from a compressedDepth format string ("16UC1; compressedDepth rvl"); the
    older plug-in wrote PNG with no name after "compressedDepth"."""
    tail = fmt.split(";", 1)[1].strip().split() if ";" in fmt else []
    name = tail[1].lower() if len(tail) > 1 else "png"
    if name not in ("png", "rvl"):
        raise DecodeError(f"{where}: compressedDepth compression '{name}' is not supported (png, rvl)")
    return name


def decode_colour(msg: Any, msgtype: str, where: str) -> np.ndarray[Any, np.dtype[np.uint8]]:
    """A colour image as (height, width, 3) uint8 RGB."""
    import cv2

    if msgtype == COMPRESSED:
        fmt = str(msg.format).lower()
        if "jpeg" not in fmt and "jpg" not in fmt and "png" not in fmt:
            raise DecodeError(f"{where}: colour CompressedImage format '{msg.format}' is not "
                              "supported (jpeg, png)")
        bgr = cv2.imdecode(np.asarray(msg.data, dtype=np.uint8).reshape(-1), cv2.IMREAD_COLOR)
        if bgr is None:
            raise DecodeError(f"{where}: colour image does not decode as '{msg.format}'")
        return np.ascontiguousarray(bgr[:, :, ::-1])
    encoding = str(msg.encoding)
    if encoding not in COLOUR_ENCODINGS:
        raise DecodeError(f"{where}: colour encoding '{encoding}' is not supported "
                          f"({', '.join(COLOUR_ENCODINGS)})")
    rows = _pixels(msg, 3, where).reshape(int(msg.height), int(msg.width), 3)
    return np.ascontiguousarray(rows if encoding == "rgb8" else rows[:, :, ::-1])


def image_kind(msg: Any, msgtype: str) -> str:
    """'depth', 'colour' or 'other' (a mono or IR image, an unknown encoding) by the header."""
    if msgtype == COMPRESSED:
        fmt = str(msg.format).lower()
        if "compresseddepth" in fmt:
            return "depth"
        return "colour" if any(s in fmt for s in ("jpeg", "jpg", "png")) else "other"
    encoding = str(msg.encoding)
    if encoding in DEPTH_ENCODINGS:
        return "depth"
    return "colour" if encoding in COLOUR_ENCODINGS else "other"


# ----- back-projection -----------------------------------------------------------------------


def pixel_rays(model: CameraModel, decimation: int) -> tuple[np.ndarray[Any, Any], np.ndarray[Any, Any], F64]:
    """Rows, columns and the (M, 2) undistorted normalised coordinates of the sampled pixels."""
    start = decimation // 2
    rows = np.arange(start, model.height, decimation)
    cols = np.arange(start, model.width, decimation)
    vv, uu = np.meshgrid(rows, cols, indexing="ij")
    uv = np.column_stack([uu.ravel(), vv.ravel()]).astype(np.float64)
    if model.distorted:
        import cv2

        norm = cv2.undistortPoints(uv.reshape(-1, 1, 2), model.k, model.d).reshape(-1, 2)
    else:
        k = model.k
        norm = np.column_stack([(uv[:, 0] - k[0, 2]) / k[0, 0], (uv[:, 1] - k[1, 2]) / k[1, 1]])
    return vv.ravel(), uu.ravel(), np.asarray(norm, dtype=np.float64)


def back_project(depth_m: np.ndarray[Any, Any], rays: tuple[np.ndarray[Any, Any], np.ndarray[Any, Any], F64],
                 min_range_m: float, max_range_m: float) -> tuple[F32, np.ndarray[Any, Any]]:
    """Points (N, 3) in the optical frame of the sampled pixels with a depth in range, and the
    indices of those pixels in `rays`."""
    rows, cols, norm = rays
    z = depth_m[rows, cols].astype(np.float64)
    with np.errstate(invalid="ignore"):
        keep = np.flatnonzero(np.isfinite(z) & (z >= min_range_m) & (z <= max_range_m))
    z = z[keep]
    xyz = np.column_stack([norm[keep, 0] * z, norm[keep, 1] * z, z]).astype(np.float32)
    return xyz, keep


def colour_points(xyz_depth: F32, rgb_image: np.ndarray[Any, Any], model: CameraModel,
                  depth_to_colour: F64) -> tuple[np.ndarray[Any, Any], np.ndarray[Any, Any]]:
    """Colours of points (depth optical frame) seen by the colour camera: (M, 3) uint8, and the
    indices of those points (points behind it or outside its image have none)."""
    import cv2

    pts = xyz_depth.astype(np.float64) @ depth_to_colour[:3, :3].T + depth_to_colour[:3, 3]
    front = np.flatnonzero(pts[:, 2] > 1e-3)
    if front.shape[0] == 0:
        return np.zeros((0, 3), dtype=np.uint8), front
    if model.distorted:
        uv, _ = cv2.projectPoints(pts[front].reshape(-1, 1, 3), np.zeros(3), np.zeros(3), model.k, model.d)
        uv = uv.reshape(-1, 2)
    else:
        p = pts[front]
        k = model.k
        uv = np.column_stack([k[0, 0] * p[:, 0] / p[:, 2] + k[0, 2], k[1, 1] * p[:, 1] / p[:, 2] + k[1, 2]])
    u = np.floor(uv[:, 0] + 0.5).astype(np.int64)
    v = np.floor(uv[:, 1] + 0.5).astype(np.int64)
    h, w = rgb_image.shape[:2]
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    return rgb_image[v[inside], u[inside]], front[inside]


# ----- discovery -----------------------------------------------------------------------------


def _namespace(topic: str) -> str:
    """The topic's namespace, an image_transport suffix (compressed, compressedDepth) left out."""
    parts = topic.rstrip("/").split("/")
    if parts[-1] in ("compressed", "compressedDepth"):
        parts = parts[:-1]
    return "/".join(parts[:-1])


class CameraProblem(MissingDataError):
    """A camera topic that cannot be used: no CameraInfo, an unknown encoding, no transform."""


def _first(src: LogSource, topic: str) -> Any | None:
    for rec in src.messages(topic):
        return rec.msg
    return None


def find_cameras(src: LogSource, config: CameraConfig) -> tuple[list[Camera], list[str]]:
    """The log's usable depth cameras and a warning per skipped one.

    Explicit cameras (config.cameras) raise CameraProblem naming the topic and what is missing;
    discovered ones are skipped with a warning instead, since the lidar carries the build.
    """
    if not config.enabled:
        return [], []
    types = {t.name: t.msgtype for t in src.topics if t.count > 0}
    infos = sorted(n for n, t in types.items() if t == CAMERA_INFO)
    explicit = list(config.cameras)
    if not explicit:
        depth_topics, colour_topics = [], []
        for name in sorted(n for n, t in types.items() if t in (IMAGE, COMPRESSED)):
            msg = _first(src, name)
            kind = image_kind(msg, types[name]) if msg is not None else "other"
            if kind == "depth":
                depth_topics.append(name)
            elif kind == "colour":
                colour_topics.append(name)
        for depth in depth_topics:
            # The colour image of the same camera: in the depth's namespace (registered) or a
            # sibling of it (/camera/depth/image_raw and /camera/color/image_raw).
            ns = _namespace(depth)
            cam_root = ns.rsplit("/", 1)[0]
            colour = ""
            near = [c for c in colour_topics
                    if _namespace(c) == ns or _namespace(c).rsplit("/", 1)[0] == cam_root]
            if near:
                # A raw image before its compressed copy, then the busiest.
                near.sort(key=lambda c: (c.endswith("/compressed"), -src.count(c), c))
                colour = near[0]
            explicit.append(CameraTopics(depth=depth, colour=colour))
        strict = False
    else:
        strict = True
    cameras: list[Camera] = []
    warnings: list[str] = []
    for topics in explicit:
        try:
            cameras.append(_camera(src, topics, types, infos))
        except CameraProblem as err:
            if strict:
                raise
            warnings.append(f"{err.message}: camera skipped (the lidar carries the build)")
    return cameras, warnings


_KNOWN_ENCODINGS = {"depth": f"{', '.join(DEPTH_ENCODINGS)}, compressedDepth",
                    "colour": f"{', '.join(COLOUR_ENCODINGS)}, jpeg, png"}


def _first_image(src: LogSource, topic: str, types: dict[str, str], kind: str, where: str) -> Any:
    """The topic's first image, when the topic holds images of `kind` ("depth" or "colour")."""
    if topic not in types or types[topic] not in (IMAGE, COMPRESSED):
        raise CameraProblem(f"{where}: no sensor_msgs/Image or CompressedImage messages")
    first = _first(src, topic)
    if first is None or image_kind(first, types[topic]) != kind:
        enc = getattr(first, "encoding", getattr(first, "format", "?"))
        raise CameraProblem(f"{where}: encoding '{enc}' is not a {kind} encoding "
                            f"({_KNOWN_ENCODINGS[kind]})")
    return first


def _camera(src: LogSource, topics: CameraTopics, types: dict[str, str], infos: list[str]) -> Camera:
    where = f"{src.path} topic {topics.depth}"
    first = _first_image(src, topics.depth, types, "depth", where)
    model = _model(src, topics.depth, topics.info, infos, where)
    extr = src.extrinsics()
    frame = model.frame_id or str(first.header.frame_id).lstrip("/")
    to_base = extr.get(frame)
    if to_base is None:
        raise CameraProblem(f"{where}: no static transform from '{extr.base_frame}' to camera "
                            f"frame '{frame}' in /tf_static")
    if not topics.colour:
        return Camera(topics.depth, model.frame_id, model, to_base)
    cwhere = f"{src.path} topic {topics.colour}"
    cfirst = _first_image(src, topics.colour, types, "colour", cwhere)
    cframe = str(cfirst.header.frame_id).lstrip("/") or frame
    try:
        cmodel = _model(src, topics.colour, topics.colour_info, infos, cwhere)
    except CameraProblem:
        if cframe != frame:
            raise
        cmodel = None  # registered to the depth: same frame, and (checked per image) same size
    if cmodel is not None:
        cframe = cmodel.frame_id or cframe
    cto_base = to_base if cframe == frame else extr.get(cframe)
    if cto_base is None:
        raise CameraProblem(f"{cwhere}: no static transform from '{extr.base_frame}' to colour "
                            f"frame '{cframe}' in /tf_static")
    return Camera(topics.depth, info_topic(topics.depth, topics.info, infos) or "", model, to_base,
                  topics.colour, cmodel, cto_base)


def info_topic(image_topic: str, given: str, infos: list[str]) -> str | None:
    """The image topic's CameraInfo topic (`given`, else <its namespace>/camera_info), None if the
    log has no such CameraInfo."""
    if given:
        return given if given in infos else None
    want = _namespace(image_topic) + "/camera_info"
    return want if want in infos else None


def _model(src: LogSource, image_topic: str, given: str, infos: list[str], where: str) -> CameraModel:
    topic = info_topic(image_topic, given, infos)
    if topic is None:
        wanted = given or _namespace(image_topic) + "/camera_info"
        raise CameraProblem(f"{where}: no sensor_msgs/CameraInfo on '{wanted}' (intrinsics needed "
                            "to back-project the image)")
    msg = _first(src, topic)
    if msg is None:
        raise CameraProblem(f"{where}: CameraInfo topic '{topic}' has no messages")
    try:
        return camera_model(msg, f"{src.path} topic {topic}")
    except DecodeError as err:
        raise CameraProblem(err.message) from err


# ----- streaming -----------------------------------------------------------------------------


def camera_points(src: LogSource, camera: Camera, config: CameraConfig,
                  want: Callable[[int], bool] | None = None) -> Iterator[CameraPoints]:
    """The camera's images as points in its optical frame, in stamp order (only those whose
    stamp `want` accepts, when given: the others are not decoded)."""
    types = {t.name: t.msgtype for t in src.topics}
    where = f"{src.path} topic {camera.depth_topic}"
    rays = pixel_rays(camera.model, config.decimation)
    colour_iter = _colour_stream(src, camera) if camera.colour_topic else None
    pending: list[tuple[int, Any]] = []
    offset_ns = int(config.colour_max_offset_s * 1e9)
    depth_to_colour = None
    if camera.colour_to_base is not None:
        depth_to_colour = np.linalg.inv(camera.colour_to_base) @ camera.to_base
    for rec in src.messages(camera.depth_topic):
        if want is not None and not want(rec.stamp_ns):
            continue
        depth = decode_depth(rec.msg, types[camera.depth_topic], where)
        if depth.shape != (camera.model.height, camera.model.width):
            raise DecodeError(f"{where}: depth image is {depth.shape[1]} x {depth.shape[0]}, its "
                              f"CameraInfo says {camera.model.width} x {camera.model.height}")
        xyz, _ = back_project(depth, rays, config.min_range_m, config.max_range_m)
        if colour_iter is None:
            yield CameraPoints(rec.stamp_ns, xyz, None)
            continue
        # Colour images up to the depth's stamp (plus the tolerance), nearest one used.
        while not pending or pending[-1][0] <= rec.stamp_ns + offset_ns:
            nxt = next(colour_iter, None)
            if nxt is None:
                break
            pending.append(nxt)
        pending = [p for p in pending if p[0] >= rec.stamp_ns - offset_ns]
        near = [p for p in pending if abs(p[0] - rec.stamp_ns) <= offset_ns]
        if not near:
            continue  # no colour image close enough: a coloured cloud carries no uncoloured points
        _, msg = min(near, key=lambda p: (abs(p[0] - rec.stamp_ns), p[0]))
        cwhere = f"{src.path} topic {camera.colour_topic}"
        rgb = decode_colour(msg, types[str(camera.colour_topic)], cwhere)
        cmodel = camera.colour_model
        if cmodel is None:
            if rgb.shape[:2] != depth.shape:
                raise DecodeError(f"{cwhere}: colour image is {rgb.shape[1]} x {rgb.shape[0]} with no "
                                  f"CameraInfo, the depth {depth.shape[1]} x {depth.shape[0]}")
            cmodel = camera.model
        assert depth_to_colour is not None
        colours, idx = colour_points(xyz, rgb, cmodel, depth_to_colour)
        yield CameraPoints(rec.stamp_ns, xyz[idx], colours)


def _colour_stream(src: LogSource, camera: Camera) -> Iterator[tuple[int, Any]]:
    for rec in src.messages(str(camera.colour_topic)):
        yield rec.stamp_ns, rec.msg
