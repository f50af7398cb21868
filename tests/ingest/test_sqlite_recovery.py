"""A ROS 2 sqlite3 bag cut short or with a damaged page: every row SQLite can still read is
recovered, with a warning; nothing readable means one clear error.

What "readable" means is worked out independently of the reader: the messages table's B-tree is
walked page by page in the intact file, so each message id is known with the pages it needs.
"""

from __future__ import annotations

import shutil
import sqlite3
from collections.abc import Callable
from pathlib import Path

import ingest_logwriter as lw
import numpy as np
import pytest

from mfmap.errors import LogError
from mfmap.ingest import open_log
from mfmap.types import Role

TOTAL = sum(lw.EXPECTED.counts.values())


def _varint(b: bytes, pos: int) -> tuple[int, int]:
    value = 0
    for i in range(9):
        byte = b[pos + i]
        if i == 8:
            return (value << 8) | byte, pos + 9
        value = (value << 7) | (byte & 0x7F)
        if byte < 0x80:
            return value, pos + i + 1
    raise AssertionError("unreachable")


def _pages_of_rows(db: Path) -> dict[int, set[int]]:
    """Per message id, every page its row needs (root to leaf)."""
    con = sqlite3.connect(db)
    root = con.execute("SELECT rootpage FROM sqlite_master WHERE name = 'messages'").fetchone()[0]
    page_size = con.execute("PRAGMA page_size").fetchone()[0]
    con.close()
    assert page_size == 4096
    data = db.read_bytes()
    out: dict[int, set[int]] = {}

    def walk(page: int, path: set[int]) -> None:
        b = data[(page - 1) * page_size : page * page_size]
        hdr = 100 if page == 1 else 0
        kind, ncells = b[hdr], int.from_bytes(b[hdr + 3 : hdr + 5], "big")
        path = path | {page}
        if kind == 0x05:  # interior table page: left children, then the right-most child
            for i in range(ncells):
                cell = int.from_bytes(b[hdr + 12 + 2 * i : hdr + 14 + 2 * i], "big")
                walk(int.from_bytes(b[cell : cell + 4], "big"), path)
            walk(int.from_bytes(b[hdr + 8 : hdr + 12], "big"), path)
            return
        assert kind == 0x0D, f"page {page} is not a table page"
        for i in range(ncells):
            cell = int.from_bytes(b[hdr + 8 + 2 * i : hdr + 10 + 2 * i], "big")
            size, pos = _varint(b, cell)
            rowid, _ = _varint(b, pos)
            assert size <= page_size - 35, "the test premise: no row spills to overflow pages"
            out[rowid] = path

    walk(root, set())
    return out


def _topics_by_id(db: Path) -> dict[int, str]:
    con = sqlite3.connect(db)
    rows = con.execute("SELECT messages.id, topics.name FROM messages JOIN topics ON topic_id = topics.id")
    out = {int(i): str(n) for i, n in rows}
    con.close()
    return out


def _damaged_copy(written_log: Callable[[str], Path], tmp_path: Path) -> tuple[Path, Path, bytes]:
    full = written_log("ros2-sqlite3")
    bag = tmp_path / "bag"
    shutil.copytree(full, bag)
    db = next(bag.glob("*.db3"))
    return bag, db, db.read_bytes()


def _check(bag: Path, readable: set[int], topic_of: dict[int, str]) -> None:
    expected_counts = {name: 0 for name in lw.EXPECTED.counts}
    for i in readable:
        expected_counts[topic_of[i]] += 1
    with open_log(bag) as src:
        assert {t.name: t.count for t in src.topics} == expected_counts
        assert sum(f"recovered {len(readable)} of {TOTAL} messages" in w for w in src.warnings) == 1
        clouds = list(src.clouds())
        # The lidar with the most recovered scans: /lidar2/points when none of /lidar/points is.
        topic = src.roles[Role.LIDAR]
        lidar_ids = sorted(i for i in readable if topic_of[i] == topic)
        assert len(clouds) == len(lidar_ids)
        # Each recovered scan is the one written: its stamp and its points.
        step, n, shift = ((lw.LIDAR_DT, lw.LIDAR_N, 0) if topic == "/lidar/points"
                          else (300_000_000, lw.LIDAR2_N, 1))
        all_stamps = [lw.T0_NS + k * step + shift for k in range(n)]
        lidar_all = sorted(i for i, t in topic_of.items() if t == topic)
        assert [c.stamp_ns for c in clouds] == [all_stamps[lidar_all.index(i)] for i in lidar_ids]
        for c in clouds:
            k = all_stamps.index(c.stamp_ns)
            np.testing.assert_array_equal(c.xyz, lw.lidar_points(k)[lw.NAN_PER_SCAN :])
        if expected_counts["/baro/pressure"]:
            assert len(src.pressure()) == src.count(Role.BARO) == expected_counts["/baro/pressure"]


@pytest.mark.parametrize("keep_pages", [24, 20, 14, 11])
def test_truncated_db3(written_log: Callable[[str], Path], tmp_path: Path, keep_pages: int) -> None:
    bag, db, data = _damaged_copy(written_log, tmp_path)
    pages = _pages_of_rows(db)
    topic_of = _topics_by_id(db)
    assert len(pages) == TOTAL and len(data) // 4096 > keep_pages
    cut = keep_pages * 4096 + 1000  # part of one more page, too
    # The page the file ends in is not trusted (its missing end reads as zeros).
    readable = {i for i, need in pages.items() if max(need) <= keep_pages}
    assert 0 < len(readable) < TOTAL
    db.write_bytes(data[:cut])
    _check(bag, readable, topic_of)


def test_damaged_page_in_the_middle(written_log: Callable[[str], Path], tmp_path: Path) -> None:
    bag, db, data = _damaged_copy(written_log, tmp_path)
    page_size = 4096
    pages = _pages_of_rows(db)
    topic_of = _topics_by_id(db)
    leaves = sorted({max(need - {min(need)}) for need in pages.values() if len(need) > 1})
    assert len(leaves) > 4
    bad = leaves[len(leaves) // 2]
    readable = {i for i, need in pages.items() if bad not in need}
    assert 0 < len(readable) < TOTAL - 3
    db.write_bytes(data[: (bad - 1) * page_size] + b"\xff" * page_size + data[bad * page_size :])
    _check(bag, readable, topic_of)


def test_db3_cut_before_its_tables_is_one_clear_error(
    written_log: Callable[[str], Path], tmp_path: Path
) -> None:
    bag, db, data = _damaged_copy(written_log, tmp_path)
    for cut in (3000, 100):
        db.write_bytes(data[:cut])
        with pytest.raises(LogError, match=r"log\.db3: cannot read the sqlite3 storage: ") as err:
            open_log(bag)
        assert "\n" not in str(err.value)


def test_db3_without_metadata_yaml(written_log: Callable[[str], Path], tmp_path: Path) -> None:
    """A recorder that was killed leaves its .db3 but never writes metadata.yaml."""
    bag, db, _data = _damaged_copy(written_log, tmp_path)
    (bag / "metadata.yaml").unlink()
    with open_log(bag) as src:
        assert {t.name: t.count for t in src.topics} == lw.EXPECTED.counts
        assert sum(f"recovered {TOTAL} messages" in w and "no metadata.yaml" in w for w in src.warnings) == 1
        assert len(list(src.clouds())) == lw.LIDAR_N
        assert len(src.pressure()) == lw.BARO_N
    with open_log(db) as src:  # the .db3 itself names the same bag
        assert sum(t.count for t in src.topics) == TOTAL


def test_cut_through_large_messages_never_serves_zeroed_data(tmp_path: Path) -> None:
    """Scans larger than a page spill to overflow pages; wherever the file is cut, every
    message served is byte for byte what was written (SQLite reads a missing page end as
    zeros without an error)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    store = lw.typestore(ros1=False)
    bag = tmp_path / "big"
    written: dict[int, bytes] = {}
    with Writer(bag, version=9, storage_plugin=StoragePlugin.SQLITE3) as w:
        conn = w.add_connection("/lidar/points", "sensor_msgs/msg/PointCloud2", typestore=store)
        for k in range(40):
            t = lw.T0_NS + k * lw.LIDAR_DT
            msg = lw.cloud_msg(store, k, t)
            msg.data = np.random.default_rng(k).integers(1, 255, 9_000, dtype=np.uint8)
            written[t] = bytes(store.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2"))
            w.write(conn, t, written[t])
    db = next(bag.glob("*.db3"))
    data = db.read_bytes()
    counts = []
    for cut in (len(data) // 2 + 777, len(data) * 3 // 4 + 1234, len(data) - 2000):
        db.write_bytes(data[:cut])
        with open_log(bag) as src:
            got = [(raw.log_time_ns, bytes(src._backend.serialized(raw)[1])) for raw in src.raw_messages("/lidar/points")]
            assert sum("recovered" in w for w in src.warnings) == 1
        assert all(written[t] == payload for t, payload in got)
        counts.append(len(got))
    assert 0 < counts[0] < counts[1] < counts[2] < 40
