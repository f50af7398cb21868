"""Cut simulated MCAP logs for bad-input tests: drop topics, keep only the first seconds."""

from __future__ import annotations

from pathlib import Path


def copy_log(src: Path, dst: Path, drop_topics: set[str], end_s: float | None = None) -> None:
    """Copy an MCAP log without some topics (and optionally only its first seconds)."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with src.open("rb") as fin, dst.open("wb") as fout:
        reader = make_reader(fin)
        writer = Writer(fout)
        writer.start(profile="ros2", library="test")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        first: int | None = None
        for schema, channel, message in reader.iter_messages():
            first = message.log_time if first is None else first
            if end_s is not None and message.log_time - first > end_s * 1e9:
                break
            if channel.topic in drop_topics:
                continue
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas.get(channel.schema_id, 0), channel.metadata
                )
            writer.add_message(channels[channel.id], message.log_time, message.data, message.publish_time)
        writer.finish()
