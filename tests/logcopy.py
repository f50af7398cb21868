"""Cut and edit simulated MCAP logs for bad-input tests: drop topics, keep only the first
seconds, move messages in time."""

from __future__ import annotations

import struct
from collections.abc import Callable
from pathlib import Path


def copy_log(src: Path, dst: Path, drop_topics: set[str], end_s: float | None = None,
             drop_prefix: str | None = None) -> None:
    """Copy an MCAP log without some topics (and those under `drop_prefix`), and optionally
    only its first seconds."""
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
            if channel.topic in drop_topics or (drop_prefix and channel.topic.startswith(drop_prefix)):
                continue
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas.get(channel.schema_id, 0), channel.metadata
                )
            writer.add_message(channels[channel.id], message.log_time, message.data, message.publish_time)
        writer.finish()


Edit = Callable[[str, int, bytes], list[tuple[int, bytes]]]


def edit_log(src: Path, dst: Path, edit: Edit, end_s: float | None = None) -> None:
    """Copy an MCAP log, each message replaced by what `edit(topic, log_time_ns, data)` returns:
    a list of (log_time_ns, data), so a message can be moved in time, dropped or repeated.
    Messages are written in the order they are read (the recording order), whatever their times."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with src.open("rb") as fin, dst.open("wb") as fout:
        reader = make_reader(fin)
        writer = Writer(fout)
        writer.start(profile="ros2", library="test")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        first: int | None = None
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            first = message.log_time if first is None else first
            if end_s is not None and message.log_time - first > end_s * 1e9:
                break
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas.get(channel.schema_id, 0), channel.metadata
                )
            for log_time, data in edit(channel.topic, message.log_time, bytes(message.data)):
                writer.add_message(channels[channel.id], log_time, data, log_time)
        writer.finish()


def shift_stamp(data: bytes, delta_ns: int) -> bytes:
    """A CDR message whose first field is a std_msgs/Header, with its stamp moved by delta_ns."""
    sec, nanosec = struct.unpack_from("<iI", data, 4)
    total = sec * 1_000_000_000 + nanosec + delta_ns
    return data[:4] + struct.pack("<iI", total // 1_000_000_000, total % 1_000_000_000) + data[12:]


def shifted(topics: set[str], delta_ns: int, when: Callable[[int], bool]) -> Edit:
    """An edit moving the messages of `topics` whose log time satisfies `when` by delta_ns, log
    time and header stamp alike (a clock that jumped)."""

    def edit(topic: str, log_time: int, data: bytes) -> list[tuple[int, bytes]]:
        if topic in topics and when(log_time):
            return [(log_time + delta_ns, shift_stamp(data, delta_ns))]
        return [(log_time, data)]

    return edit
