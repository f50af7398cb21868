"""What `mfmap info` says about a log's cameras: per image topic its kind, encoding, size, rate,
frame, CameraInfo and transform, and whether a build uses it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rich.console import RenderableType
from rich.text import Text

from mfmap.errors import MfmapError
from mfmap.ingest.camera_config import CameraConfig
from mfmap.ingest.config import IngestConfig
from mfmap.tables import table
from mfmap.types import Extrinsics


def describe_cameras(path: Path | str, ingest: IngestConfig | None = None,
                     camera: CameraConfig | None = None) -> tuple[list[dict[str, Any]], list[str]]:
    """One row per image topic (sensor_msgs/Image, CompressedImage) of the log, and the reasons
    a build would skip a camera."""
    from mfmap.ingest import open_log
    from mfmap.ingest.colour import colour_cameras
    from mfmap.ingest.depth import (
        CAMERA_INFO,
        COMPRESSED,
        IMAGE,
        CameraProblem,
        find_cameras,
        info_topic,
    )

    camera = camera or CameraConfig()
    with open_log(path, ingest) as src:
        images = [t for t in src.topics if t.msgtype in (IMAGE, COMPRESSED) and t.count > 0]
        if not images:
            return [], []
        infos = sorted(t.name for t in src.topics if t.msgtype == CAMERA_INFO and t.count > 0)
        try:
            frames: Extrinsics | None = src.extrinsics()
        except MfmapError:
            frames = None  # the lidar's transform is missing: `mfmap info` says so elsewhere
        try:
            cameras, skipped = find_cameras(src, camera)
        except CameraProblem as err:
            cameras, skipped = [], [err.message]
        colour, colour_skipped = colour_cameras(src, cameras, camera)
        skipped += colour_skipped
        used = {c.topic: "paints the lidar" for c in colour}
        used.update({c.depth_topic: "depth" for c in cameras})
        used.update({str(c.colour_topic): f"colour of {c.depth_topic}" for c in cameras if c.colour_topic})
        rows = []
        for topic in images:
            first = next(iter(src.messages(topic.name)), None)
            row = _describe(first.msg if first is not None else None, topic.msgtype, topic.name)
            info = info_topic(topic.name, "", infos)
            row.update(rate_hz=round(topic.rate_hz, 3), count=topic.count, camera_info=info,
                       transform=None if frames is None else frames.get(row["frame"]) is not None,
                       used=used.get(topic.name, ""))
            rows.append(row)
        return rows, skipped


def _describe(msg: Any, msgtype: str, topic: str) -> dict[str, Any]:
    from mfmap.errors import DecodeError
    from mfmap.ingest.depth import COMPRESSED, decode_colour, decode_depth, image_kind

    if msg is None:
        return {"topic": topic, "kind": "other", "encoding": "?", "width": None, "height": None, "frame": ""}
    kind = image_kind(msg, msgtype)
    encoding = str(msg.format if msgtype == COMPRESSED else msg.encoding)
    width, height = (int(msg.width), int(msg.height)) if msgtype != COMPRESSED else (None, None)
    if msgtype == COMPRESSED and kind != "other":
        # A compressed image's size is in its payload.
        try:
            pixels = decode_depth(msg, msgtype, topic) if kind == "depth" else decode_colour(msg, msgtype, topic)
            height, width = int(pixels.shape[0]), int(pixels.shape[1])
        except DecodeError:
            pass
    frame = str(msg.header.frame_id).lstrip("/")
    return {"topic": topic, "kind": kind, "encoding": encoding, "width": width, "height": height,
            "frame": frame}


def render_cameras(rows: list[dict[str, Any]]) -> RenderableType:
    """The cameras table of `mfmap info`."""
    out = table(
        [("camera topic", "left"), ("kind", "left"), ("encoding", "left"), ("size", "right"),
         ("rate Hz", "right"), ("frame", "left"), ("CameraInfo", "left"), ("transform", "left"),
         ("build", "left")],
        show_header=True, header_style="bold", box=None, pad_edge=False,
        title="cameras", title_justify="left",
    )
    for row in rows:
        size = f"{row['width']} x {row['height']}" if row["width"] else "?"
        transform = {True: Text("yes"), False: Text("missing", style="red"), None: Text("?", style="yellow")}
        out.add_row(
            row["topic"], row["kind"], row["encoding"], size, f"{row['rate_hz']:.2f}", row["frame"] or "-",
            row["camera_info"] or Text("none", style="yellow" if row["kind"] == "colour" else "red"),
            transform[row["transform"]], row["used"] or Text("not used", style="dim"),
        )
    return out
