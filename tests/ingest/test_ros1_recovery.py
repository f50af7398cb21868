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
