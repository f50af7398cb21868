"""A build with a depth camera that cannot be used: one line naming the topic, before any work."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent / "ingest"))

import camera_logwriter as cw
from ingest_logwriter import typestore


def _with_cameras(src: Path, dst: Path, drop: list[str]) -> None:
    """The sim log with the test cameras' topics added (written by mcap's Writer)."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    store = typestore(False)
    with src.open("rb") as fin, dst.open("wb") as fout:
        reader = make_reader(fin)
        writer = Writer(fout)
        writer.start(profile="ros2", library="test")
        schemas: dict[int, int] = {}
        channels: dict[str, int] = {}
        start = None
        for schema, channel, message in reader.iter_messages():
            start = message.log_time if start is None else start
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.topic not in channels:
                channels[channel.topic] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas.get(channel.schema_id, 0), channel.metadata)
            writer.add_message(channels[channel.topic], message.log_time, message.data, message.publish_time)
        for topic, msgtype, t, msg in cw.camera_items(store, drop=drop):
            if topic == "/tf_static":
                continue
            if topic not in channels:
                sid = writer.register_schema(msgtype, "ros2msg", store.generate_msgdef(msgtype)[0].encode())
                channels[topic] = writer.register_channel(topic, "cdr", sid)
            t = (start or 0) + (t - cw.T0_NS)
            writer.add_message(channels[topic], t, bytes(store.serialize_cdr(msg, msgtype)), t)
        writer.finish()


def test_configured_camera_without_camera_info(sim_run: Callable[..., Path], tmp_path: Path) -> None:
    log = tmp_path / "log.mcap"
    _with_cameras(sim_run("tiny") / "log.mcap", log, drop=["/cam2/depth/camera_info"])
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("camera:\n  cameras:\n    - depth: /cam2/depth/image_raw\n")
    res = subprocess.run([sys.executable, "-m", "mfmap.cli", "build", str(log), "-o", str(tmp_path / "out"),
                          "--config", str(cfg)], capture_output=True, text=True, timeout=600)
    assert res.returncode != 0
    lines = [line for line in res.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, res.stderr
    assert "/cam2/depth/image_raw" in lines[0] and "no sensor_msgs/CameraInfo" in lines[0]
    assert "Traceback" not in res.stderr
    assert not (tmp_path / "out").exists()
