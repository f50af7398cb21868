"""A ROS 1 bag cut short (recorder killed): every message of the intact chunks is recovered."""

from __future__ import annotations

from pathlib import Path

import ingest_logwriter as lw
import pytest
from rosbags.rosbag1 import Reader

from mfmap.errors import LogError
from mfmap.ingest import open_log
from mfmap.types import Role


@pytest.mark.parametrize("compression", ["none", "bz2", "lz4"])
def test_truncated_bag(tmp_path: Path, compression: str) -> None:
    full = lw.write_log(tmp_path / "full", f"ros1-{compression}")
    with Reader(full) as reader:
        chunks = sorted(reader.chunk_infos, key=lambda c: c.pos)
        lidar_ids = {c.id for c in reader.connections if c.topic == "/lidar/points"}
    assert len(chunks) > 6
    k = len(chunks) // 2
    # Cut 10 bytes into chunk k: chunks 0..k-1 (and their index records) are intact.
    cut = chunks[k].pos + 10
    expected = sum(sum(c.connection_counts.values()) for c in chunks[:k])
    expected_lidar = sum(c.connection_counts.get(i, 0) for c in chunks[:k] for i in lidar_ids)
    cut_bag = tmp_path / "cut.bag"
    cut_bag.write_bytes(full.read_bytes()[:cut])
    with open_log(cut_bag) as src:
        assert src.format == "ros1"
        assert sum(t.count for t in src.topics) == expected
        assert sum(f"recovered {expected} messages" in w for w in src.warnings) == 1
        clouds = list(src.clouds())
        assert len(clouds) == expected_lidar > 0
        assert [c.stamp_ns for c in clouds] == [lw.T0_NS + i * lw.LIDAR_DT for i in range(expected_lidar)]
        assert len(src.pressure()) == src.count(Role.BARO) > 0


def test_bag_cut_inside_its_header_is_rejected(tmp_path: Path) -> None:
    full = lw.write_log(tmp_path / "full", "ros1-none")
    cut_bag = tmp_path / "cut.bag"
    cut_bag.write_bytes(full.read_bytes()[:40])
    with pytest.raises(LogError, match=r"cut\.bag: cannot read the bag"):
        open_log(cut_bag)


def test_recovery_streams_the_bag(tmp_path: Path) -> None:
    """The damaged bag is walked chunk by chunk: peak memory is a small part of the bag."""
    import tracemalloc

    import numpy as np
    from rosbags.rosbag1 import Writer

    store = lw.typestore(ros1=True)
    bag = tmp_path / "big.bag"
    n_msgs, payload = 200, 20_000
    w = Writer(bag)
    w.chunk_threshold = 64 * 1024
    with w:
        conn = w.add_connection("/lidar/points", "sensor_msgs/msg/PointCloud2", typestore=store)
        for k in range(n_msgs):
            msg = lw.cloud_msg(store, k, lw.T0_NS + k * lw.LIDAR_DT)
            msg.data = np.full(payload, k % 251, np.uint8)
            w.write(conn, lw.T0_NS + k * lw.LIDAR_DT, store.serialize_ros1(msg, "sensor_msgs/msg/PointCloud2"))
    with Reader(bag) as reader:
        chunks = sorted(reader.chunk_infos, key=lambda c: c.pos)
    k = len(chunks) - 3
    expected = sum(sum(c.connection_counts.values()) for c in chunks[:k])
    cut_bag = tmp_path / "cut.bag"
    cut_bag.write_bytes(bag.read_bytes()[: chunks[k].pos + 10])
    size = cut_bag.stat().st_size
    assert size > 3_000_000
    tracemalloc.start()
    try:
        with open_log(cut_bag) as src:
            assert src.count(Role.LIDAR) == expected > 150
            sizes = [src._backend.raw_size(r) for r in src.raw_messages(Role.LIDAR)]
            _current, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert len(sizes) == expected and min(sizes) > payload
    assert peak < size / 5, f"peak {peak} bytes for a {size}-byte bag: not streamed"
