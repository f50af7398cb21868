"""MCAP files as they come from the field: unindexed, unchunked, channels only inside chunks,
split over several files, truncated."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import ingest_logwriter as lw
import pytest
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import IndexType

from mfmap.ingest import open_log
from mfmap.types import Role

TOTAL = sum(lw.EXPECTED.counts.values())


def _write(tmp_path: Path, name: str, **kw: Any) -> Path:
    return lw.write_mcap_items(tmp_path / name, lw.messages(lw.typestore(False)), lw.typestore(False), **kw)


VARIANTS: dict[str, dict[str, Any]] = {
    "indexed": {},
    "no-index-no-summary": {"index_types": IndexType.NONE, "use_statistics": False,
                            "repeat_channels": False, "repeat_schemas": False,
                            "use_summary_offsets": False},
    "channels-only-in-chunks": {"repeat_channels": False, "repeat_schemas": False},
    "unchunked": {"use_chunking": False},
    "no-statistics": {"use_statistics": False},
    "small-chunks-lz4": {"chunk_size": 2048, "compression": "lz4"},
}


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_variant_reads_everything(tmp_path: Path, variant: str) -> None:
    kw = dict(VARIANTS[variant])
    if kw.get("compression") == "lz4":
        from mcap.writer import CompressionType

        kw["compression"] = CompressionType.LZ4
    path = _write(tmp_path, "log.mcap", **kw)
    with open_log(path) as src:
        assert {t.name: t.count for t in src.topics} == lw.EXPECTED.counts
        assert src.start_ns == lw.T0_NS - 1_000_000
        assert [c.stamp_ns for c in src.clouds()] == [lw.T0_NS + k * lw.LIDAR_DT for k in range(lw.LIDAR_N)]
        assert len(src.pressure()) == lw.BARO_N
        assert not src.warnings[1:]  # only the lidar-candidates note
    files = list(src._backend.files)  # type: ignore[attr-defined]
    assert files[0].indexed == (variant in ("indexed", "small-chunks-lz4", "no-statistics"))


def test_folder_of_mcap_files_without_metadata(tmp_path: Path) -> None:
    store = lw.typestore(False)
    items = list(lw.messages(store))
    half = len(items) // 2
    folder = tmp_path / "split"
    folder.mkdir()
    lw.write_mcap_items(folder / "part_0.mcap", items[:half], store)
    lw.write_mcap_items(folder / "part_1.mcap", items[half:], store)
    with open_log(folder) as src:
        assert src.format == "mcap"
        assert {t.name: t.count for t in src.topics} == lw.EXPECTED.counts
        stamps = [r.log_time_ns for r in src.messages(Role.IMU)]
        assert stamps == sorted(stamps) and len(stamps) == lw.IMU_N


def _complete_chunk_messages(path: Path, cut: int) -> tuple[int, int]:
    """Messages (all, lidar) inside the chunks that end before byte `cut`, counted with mcap's
    own StreamReader on the intact file."""
    total = lidar = 0
    channels: dict[int, str] = {}
    with path.open("rb") as f:
        for record in StreamReader(f, emit_chunks=True).records:
            if not isinstance(record, Chunk):
                continue
            if f.tell() > cut:
                break
            for rec in breakup_chunk(record):
                if hasattr(rec, "topic"):
                    channels[rec.id] = rec.topic  # type: ignore[attr-defined]
                if isinstance(rec, Message):
                    total += 1
                    lidar += channels[rec.channel_id] == "/lidar/points"
    return total, lidar


@pytest.mark.parametrize("fraction", [0.2, 0.45])
def test_truncated_file_recovers_every_message_before_the_cut(tmp_path: Path, fraction: float) -> None:
    full = _write(tmp_path, "full.mcap", chunk_size=2048)
    cut = int(full.stat().st_size * fraction)
    expected_total, expected_lidar = _complete_chunk_messages(full, cut)
    assert 0 < expected_total < TOTAL and 0 < expected_lidar < lw.LIDAR_N
    cut_path = tmp_path / "cut.mcap"
    shutil.copyfile(full, cut_path)
    with cut_path.open("r+b") as f:
        f.truncate(cut)
    with open_log(cut_path) as src:
        assert sum(t.count for t in src.topics) == expected_total
        warning = next(w for w in src.warnings if "truncated" in w)
        assert f"recovered {expected_total} messages covering" in warning
        clouds = list(src.clouds())
        assert len(clouds) == expected_lidar
        assert [c.stamp_ns for c in clouds] == [lw.T0_NS + k * lw.LIDAR_DT for k in range(expected_lidar)]
        assert sum(1 for _ in src.messages(Role.IMU)) == src.count(Role.IMU)


def test_garbage_after_valid_records(tmp_path: Path) -> None:
    full = _write(tmp_path, "full.mcap", use_chunking=False)
    data = full.read_bytes()
    # Overwrite the second half with noise: the reader stops at the first bad record.
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(data[: len(data) // 2] + bytes(range(256)) * 8)
    with open_log(damaged) as src:
        n = sum(t.count for t in src.topics)
        assert 0 < n < TOTAL
        assert any(f"recovered {n} messages" in w for w in src.warnings)
        assert sum(1 for _ in src.raw_messages("/imu/data")) == src.count("/imu/data")


def test_unindexed_out_of_order_file_is_read_in_time_order(tmp_path: Path) -> None:
    store = lw.typestore(False)
    items = list(lw.messages(store))
    # A recorder that flushed two buffers late: the second half of the IMU comes first.
    imu = [m for m in items if m[0] == "/imu/data"]
    rest = [m for m in items if m[0] != "/imu/data"]
    shuffled = rest + imu[50:] + imu[:50]
    path = lw.write_mcap_items(
        tmp_path / "ooo.mcap", shuffled, store, index_types=IndexType.NONE, use_statistics=False,
        repeat_channels=False, repeat_schemas=False, use_summary_offsets=False,
    )
    with open_log(path) as src:
        assert not src._backend.files[0].indexed  # type: ignore[attr-defined]
        stamps = [r.stamp_ns for r in src.messages(Role.IMU)]
        assert stamps == [lw.T0_NS + i * lw.IMU_DT for i in range(lw.IMU_N)]
        imu_series = src.imu()
        assert imu_series is not None and len(imu_series) == lw.IMU_N


def test_log_written_by_mcap_ros2_writer(tmp_path: Path) -> None:
    """mcap_ros2's own Writer (dynamic CDR encoder, plain dicts) instead of rosbags."""
    from mcap_ros2.writer import Writer as Ros2Writer

    store = lw.typestore(False)
    cloud_def = store.generate_msgdef("sensor_msgs/msg/PointCloud2", ros_version=2)[0]
    baro_def = store.generate_msgdef("sensor_msgs/msg/FluidPressure", ros_version=2)[0]
    path = tmp_path / "ros2writer.mcap"
    with path.open("wb") as f:
        w = Ros2Writer(f)
        cloud_schema = w.register_msgdef("sensor_msgs/msg/PointCloud2", cloud_def)
        baro_schema = w.register_msgdef("sensor_msgs/msg/FluidPressure", baro_def)
        for k in range(4):
            stamp = lw.T0_NS + k * lw.LIDAR_DT
            msg = lw.cloud_msg(store, k, stamp)
            header = {"stamp": {"sec": stamp // 10**9, "nanosec": stamp % 10**9}, "frame_id": "lidar"}
            w.write_message(
                "/points",
                cloud_schema,
                {
                    "header": header,
                    "height": msg.height,
                    "width": msg.width,
                    "fields": [
                        {"name": fl.name, "offset": fl.offset, "datatype": fl.datatype, "count": fl.count}
                        for fl in msg.fields
                    ],
                    "is_bigendian": False,
                    "point_step": msg.point_step,
                    "row_step": msg.row_step,
                    "data": bytes(msg.data),
                    "is_dense": False,
                },
                log_time=stamp,
            )
            w.write_message(
                "/baro", baro_schema,
                {"header": header, "fluid_pressure": lw.pressure_pa(k), "variance": 0.0}, log_time=stamp,
            )
        w.finish()
    with open_log(path) as src:
        assert src.roles[Role.LIDAR] == "/points" and src.roles[Role.BARO] == "/baro"
        clouds = list(src.clouds())
        assert [c.stamp_ns for c in clouds] == [lw.T0_NS + k * lw.LIDAR_DT for k in range(4)]
        for k, c in enumerate(clouds):
            assert (c.xyz == lw.lidar_points(k)[lw.NAN_PER_SCAN:]).all()
        assert src.pressure().pressure_pa.tolist() == [lw.pressure_pa(k) for k in range(4)]
