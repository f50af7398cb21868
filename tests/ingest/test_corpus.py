"""Walk the reader-robustness corpus: other projects' own test files for the formats we read.

Every file is either read, with per-topic message counts equal to what the corpus says
(mcap_conformance `.json` expected records; rosbag2 `metadata.yaml` counts) and every message
actually delivered, or rejected with a clear MfmapError. Decoding every topic may fail only with
a DecodeError (non-ROS encodings such as the conformance suite's made-up "a"). No crash, no hang.
"""

from __future__ import annotations

import json
import signal
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np
import yaml

import mfmap.ingest.series as ingest_series
from mfmap.errors import DecodeError, MfmapError
from mfmap.ingest import open_log
from mfmap.ingest.config import IngestConfig
from mfmap.ingest.decode import decode_pointcloud2
from mfmap.types import Role

# What the walk found when it was written; a change in either direction is worth a look.
EXPECTED_READ = 434
EXPECTED_REJECTED = {
    "empty-file.bag": "empty file (0 bytes)",
    "mcap_wrong_rmw_test": "unknown serialization format 'wrong_format'",
}
SECONDS_PER_FILE = 30


@dataclass
class Walk:
    read: list[str] = field(default_factory=list)
    rejected: dict[str, str] = field(default_factory=dict)
    mismatched: dict[str, str] = field(default_factory=dict)
    decode_errors: Counter[str] = field(default_factory=Counter)
    decoded_messages: int = 0
    clouds_checked: int = 0
    series_read: int = 0
    small_checked: int = 0  # barometer/IMU/odometry messages read directly, checked against rosbags


def corpus_items(root: Path) -> list[Path]:
    items = sorted((root / "mcap_conformance").rglob("*.mcap"))
    for sub in ("ros2_rosbag2_tests", "ros1_rosbagjs", "ros2_rosbags_rs"):
        items += sorted((root / sub).iterdir())
    return items


def expected_counts(item: Path) -> Counter[str] | None:
    if item.suffix == ".mcap":
        records = json.loads(item.with_suffix(".json").read_text())["records"]
        topics = {}
        counts: Counter[str] = Counter()
        for rec in records:
            fields = dict(rec["fields"])
            if rec["type"] == "Channel":
                topics[fields["id"]] = fields["topic"]
            elif rec["type"] == "Message":
                counts[topics[fields["channel_id"]]] += 1
        return counts
    meta = item / "metadata.yaml"
    if meta.is_file():
        info = yaml.safe_load(meta.read_text())["rosbag2_bagfile_information"]
        return Counter(
            {e["topic_metadata"]["name"]: e["message_count"] for e in info["topics_with_message_count"]}
        )
    return None  # ROS 1 bags and bare mcap folders: the delivered messages must match the index


def _small(item: Path, flat: dict[Role, Any]) -> dict[Role, tuple[list[int], list[tuple[float, ...]]]]:
    """The small streams' stamps and rows, read with the direct parser's table `flat`."""
    saved = dict(ingest_series._FLAT)
    ingest_series._FLAT.clear()
    ingest_series._FLAT.update(flat)
    try:
        with open_log(item) as src:
            return {role: (rows.stamps, rows.values) for role, rows in src._series.read().items()
                    if role != Role.TF_STATIC}
    finally:
        ingest_series._FLAT.clear()
        ingest_series._FLAT.update(saved)


class Hang(Exception):
    pass


def _alarm(signum: int, frame: FrameType | None) -> None:
    raise Hang


def walk(root: Path) -> Walk:
    out = Walk()
    previous = signal.signal(signal.SIGALRM, _alarm)
    try:
        for item in corpus_items(root):
            name = str(item.relative_to(root))
            signal.alarm(SECONDS_PER_FILE)
            try:
                # A corpus of other people's logs: their sensor frames need not reach a
                # base_link (the extrinsics are tested elsewhere).
                with open_log(item, IngestConfig(assume_identity_extrinsics=True)) as src:
                    got = Counter({t.name: t.count for t in src.topics if t.count})
                    delivered = Counter(
                        {t.name: sum(1 for _ in src.raw_messages(t.name)) for t in src.topics}
                    )
                    want = expected_counts(item)
                    if (want is not None and +want != got) or +delivered != got:
                        out.mismatched[name] = f"expected {dict(want or {})} got {dict(got)}"
                    else:
                        out.read.append(name)
                    for t in src.topics:
                        try:
                            out.decoded_messages += sum(1 for _ in src.messages(t.name))
                        except DecodeError as err:
                            out.decode_errors[str(err).split(": ", 1)[1].split(":")[0]] += 1
                    if Role.BARO in src.roles:
                        out.series_read += len(src.pressure())
                    for series in (src.imu(), src.odometry()):
                        out.series_read += 0 if series is None else len(series)
                    if {Role.BARO, Role.IMU, Role.ODOM} & set(src.roles):
                        # The direct parser of the small streams against the generic one.
                        direct = _small(item, ingest_series._FLAT)
                        if direct != _small(item, {}):
                            out.mismatched[name] = "small streams: direct parser differs from rosbags"
                        out.small_checked += sum(len(stamps) for stamps, _ in direct.values())
                    src.extrinsics()
                    if Role.LIDAR in src.roles:
                        # The direct PointCloud2 parser against rosbags' generic deserialiser,
                        # on bytes somebody else wrote.
                        fast = list(src.clouds())
                        ref = [decode_pointcloud2(r.msg, r.stamp_ns, drop_zero=True)
                               for r in src.messages(Role.LIDAR)]
                        assert len(fast) == len(ref) == src.count(Role.LIDAR)
                        for a, b in zip(fast, ref, strict=True):
                            assert a.stamp_ns == b.stamp_ns and a.frame_id == b.frame_id
                            np.testing.assert_array_equal(a.xyz, b.xyz)
                        out.clouds_checked += len(fast)
            except MfmapError as err:
                out.rejected[name] = str(err)
            finally:
                signal.alarm(0)
    finally:
        signal.signal(signal.SIGALRM, previous)
    return out


def test_corpus_walk(shared_dir: Path) -> None:
    root = shared_dir / "realdata" / "reader_robustness"
    result = walk(root)
    print(
        f"\ncorpus: {len(result.read)} read, {len(result.rejected)} rejected, "
        f"{len(result.mismatched)} mismatched; {result.decoded_messages} messages decoded, "
        f"{result.clouds_checked} point clouds parsed directly and checked against rosbags, "
        f"{result.series_read} barometer/IMU/odometry samples ({result.small_checked} read directly "
        "and checked against rosbags)"
    )
    for name, why in sorted(result.rejected.items()):
        print(f"  rejected {name}: {why}")
    for why, n in result.decode_errors.most_common():
        print(f"  {n} topics not decodable: {why}")
    assert result.mismatched == {}
    assert result.clouds_checked == 4  # two PointCloud2 in each rosbags-rs bag
    assert result.series_read == 12  # two FluidPressure, Imu and Odometry in each
    assert result.small_checked == 12  # the same, read by the direct parser as rosbags reads them
    assert len(result.read) == EXPECTED_READ
    assert len(result.rejected) == len(EXPECTED_REJECTED)
    for key, reason in EXPECTED_REJECTED.items():
        hits = [why for name, why in result.rejected.items() if key in name]
        assert len(hits) == 1 and reason in hits[0]
