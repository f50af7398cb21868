"""Colour cameras of a log that can paint the lidar's points: a depth camera's colour image, and
every other colour image topic with its CameraInfo and a static transform."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from mfmap.errors import DecodeError
from mfmap.ingest.camera_config import CameraConfig
from mfmap.ingest.depth import (
    CAMERA_INFO,
    COMPRESSED,
    IMAGE,
    Camera,
    CameraModel,
    camera_model,
    image_kind,
    info_topic,
)
from mfmap.types import F64

if TYPE_CHECKING:
    from mfmap.ingest.source import LogSource


@dataclass(frozen=True)
class ColourCamera:
    """A colour camera of the log: its topic, intrinsics and optical frame on the robot."""

    topic: str
    model: CameraModel
    to_base: F64  # (4, 4)


def colour_cameras(src: LogSource, depth_cameras: list[Camera], config: CameraConfig) -> tuple[list[ColourCamera], list[str]]:
    """The log's colour cameras with intrinsics and a transform: a depth camera's colour (its
    registered colour with the depth's intrinsics), and every other colour image topic with its
    CameraInfo and a static transform. A warning per colour topic that cannot be placed."""
    if not config.enabled:
        return [], []
    out: list[ColourCamera] = []
    for cam in depth_cameras:
        if cam.colour_topic and cam.colour_to_base is not None:
            out.append(ColourCamera(cam.colour_topic, cam.colour_model or cam.model, cam.colour_to_base))
    taken = {c.topic for c in out}
    types = {t.name: t.msgtype for t in src.topics if t.count > 0}
    if not any(t in (IMAGE, COMPRESSED) for t in types.values()):
        return out, []
    infos = sorted(n for n, t in types.items() if t == CAMERA_INFO)
    warnings: list[str] = []
    extr = None
    for topic in sorted(n for n, t in types.items() if t in (IMAGE, COMPRESSED) and n not in taken):
        first = next(iter(src.messages(topic)), None)
        if first is None or image_kind(first.msg, types[topic]) != "colour":
            continue
        where = f"{src.path} topic {topic}"
        info = info_topic(topic, "", infos)
        info_msg = next(iter(src.messages(info)), None) if info else None
        if info_msg is None:
            warnings.append(f"{where}: no sensor_msgs/CameraInfo beside it: it colours no lidar point")
            continue
        try:
            model = camera_model(info_msg.msg, f"{src.path} topic {info}")
        except DecodeError as err:
            warnings.append(f"{err.message}: it colours no lidar point")
            continue
        frame = model.frame_id or str(first.msg.header.frame_id).lstrip("/")
        extr = extr or src.extrinsics()
        to_base = extr.get(frame)
        if to_base is None:
            warnings.append(f"{where}: no static transform from '{extr.base_frame}' to camera frame "
                            f"'{frame}' in /tf_static: it colours no lidar point")
            continue
        out.append(ColourCamera(topic, model, to_base))
    return out, warnings
