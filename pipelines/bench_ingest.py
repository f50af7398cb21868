"""Ingest benchmark: full PointCloud2 decode through open_log().clouds() against bare MCAP
message iteration (the floor no decoder can beat), at two log lengths.

    .venv/bin/python pipelines/bench_ingest.py                      # 1000 and 2000 scans, 32x1024
    .venv/bin/python pipelines/bench_ingest.py --scans 400 --compression zstd

Writes Ouster-like logs (48-byte points: x y z, intensity, t, reflectivity, ring, ambient, range;
about 10 % no-returns at the origin) with mcap's Writer and rosbags' CDR serialiser into --dir
(kept between runs), then runs every measurement in a fresh subprocess so each peak RSS is its
own. Prints CPU and wall time, scans/s and MB/s (serialised message bytes, per CPU second),
peak RSS and the decode/bare CPU-time ratio (best of --repeat runs).
Target: ratio <= 2 and peak RSS flat from the short log to the long one.

Modes: bare = mcap's SeekingReader iterating the lidar messages (copies each chunk out of the
page cache, then each message out of the chunk); read = mfmap's own indexed reader, no decoding
(messages are zero-copy views into memory-mapped chunks, so it is cheaper than bare);
deserialise = rosbags' CDR deserialiser on those views; mcap_ros2 = mcap_ros2's dynamic decoder;
decode = open_log().clouds(), everything a build pays per scan.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

TOPIC = "/os_cloud_node/points"
T0_NS = 1_700_000_000_000_000_000
SCAN_DT_NS = 100_000_000

OUSTER = np.dtype(
    {
        "names": ["x", "y", "z", "intensity", "t", "reflectivity", "ring", "ambient", "range"],
        "formats": ["<f4", "<f4", "<f4", "<f4", "<u4", "<u2", "<u2", "<u2", "<u4"],
        "offsets": [0, 4, 8, 16, 20, 24, 26, 28, 32],
        "itemsize": 48,
    }
)
# PointField datatypes for the layout above.
FIELDS = [
    ("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 16, 7), ("t", 20, 6),
    ("reflectivity", 24, 4), ("ring", 26, 4), ("ambient", 28, 4), ("range", 32, 6),
]


def write_log(path: Path, scans: int, rows: int, cols: int, compression: str) -> None:
    """An Ouster-like lidar log (plus a 25 Hz barometer) written with the real writers."""
    from mcap.writer import CompressionType, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    rng = np.random.default_rng(0)
    n = rows * cols
    base = np.zeros(n, OUSTER)
    az = np.tile(np.linspace(0, 2 * np.pi, cols, endpoint=False), rows)
    el = np.repeat(np.linspace(-0.3, 0.3, rows), cols)
    r = rng.uniform(1.0, 30.0, n)
    base["x"], base["y"], base["z"] = r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)
    base["intensity"] = rng.uniform(0, 1000, n)
    base["t"] = np.tile(np.arange(cols, dtype=np.uint32) * (SCAN_DT_NS // cols), rows)
    base["ring"] = np.repeat(np.arange(rows), cols)
    base["range"] = (r * 1000).astype(np.uint32)
    no_return = rng.random(n) < 0.1
    for name in ("x", "y", "z"):
        base[name][no_return] = 0.0
    fields = [T["sensor_msgs/msg/PointField"](name=nm, offset=o, datatype=d, count=1) for nm, o, d in FIELDS]
    msgdef = store.generate_msgdef("sensor_msgs/msg/PointCloud2", ros_version=2)[0]
    baro_def = store.generate_msgdef("sensor_msgs/msg/FluidPressure", ros_version=2)[0]
    comp = {"none": CompressionType.NONE, "zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4}[compression]
    tmp = path.with_suffix(".tmp")
    with tmp.open("wb") as f:
        w = Writer(f, compression=comp, chunk_size=4 * 1024 * 1024)
        w.start(profile="ros2", library="mfmap bench_ingest")
        cloud_ch = w.register_channel(TOPIC, "cdr", w.register_schema("sensor_msgs/msg/PointCloud2", "ros2msg", msgdef.encode()))
        baro_ch = w.register_channel("/baro", "cdr", w.register_schema("sensor_msgs/msg/FluidPressure", "ros2msg", baro_def.encode()))
        baro_i = 0
        for k in range(scans):
            stamp = T0_NS + k * SCAN_DT_NS
            while T0_NS + baro_i * 40_000_000 <= stamp:
                t = T0_NS + baro_i * 40_000_000
                hdr = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=t // 10**9, nanosec=t % 10**9), frame_id="baro")
                msg = T["sensor_msgs/msg/FluidPressure"](header=hdr, fluid_pressure=101_325.0, variance=0.0)
                w.add_message(baro_ch, log_time=t, data=bytes(store.serialize_cdr(msg, "sensor_msgs/msg/FluidPressure")), publish_time=t)
                baro_i += 1
            base["x"][~no_return] += np.float32(0.001)  # every scan differs a little
            hdr = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id="os_lidar")
            cloud = T["sensor_msgs/msg/PointCloud2"](
                header=hdr, height=rows, width=cols, fields=fields, is_bigendian=False,
                point_step=OUSTER.itemsize, row_step=OUSTER.itemsize * cols,
                data=np.frombuffer(base.tobytes(), np.uint8), is_dense=False,
            )
            data = store.serialize_cdr(cloud, "sensor_msgs/msg/PointCloud2")
            w.add_message(cloud_ch, log_time=stamp + 2_000_000, data=bytes(data), publish_time=stamp)
        w.finish()
    tmp.replace(path)


def measure(mode: str, log: Path) -> dict[str, Any]:
    """One measurement; runs inside a fresh process (imports happen before the clock starts)."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from mfmap.ingest import open_log

    t0 = time.perf_counter()
    c0 = time.process_time()
    scans = 0
    nbytes = 0
    points = 0
    if mode == "bare":
        with log.open("rb") as f:
            for _schema, _channel, message in make_reader(f).iter_messages(topics=[TOPIC]):
                scans += 1
                nbytes += len(message.data)
    elif mode == "decode":
        with open_log(log) as src:
            for raw in src.raw_messages("lidar"):
                nbytes += src._backend.raw_size(raw)
            # The size pass above is not part of the measurement.
            t0, c0 = time.perf_counter(), time.process_time()
            for cloud in src.clouds():
                scans += 1
                points += cloud.xyz.shape[0]
    elif mode == "read":
        # mfmap's reader alone: the part of `decode` that is not decoding.
        with open_log(log) as src:
            for raw in src.raw_messages("lidar"):
                scans += 1
                nbytes += src._backend.raw_size(raw)
    elif mode == "deserialise":
        # rosbags CDR deserialisation alone (what open_log uses), no numpy decode.
        with open_log(log) as src:
            for raw in src.raw_messages("lidar"):
                src._backend.deserialize(raw)
                scans += 1
                nbytes += src._backend.raw_size(raw)
    elif mode == "mcap_ros2":
        # The alternative deserialiser: mcap_ros2's dynamic decoder.
        with log.open("rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for _s, _c, message, _decoded in reader.iter_decoded_messages(topics=[TOPIC]):
                scans += 1
                nbytes += len(message.data)
    else:
        raise SystemExit(f"unknown mode {mode}")
    wall = time.perf_counter() - t0
    cpu = time.process_time() - c0
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return {"mode": mode, "scans": scans, "points": points, "bytes": nbytes, "wall_s": wall, "cpu_s": cpu, "peak_rss_mb": peak_mb}


def run_measurement(mode: str, log: Path) -> dict[str, Any]:
    out = subprocess.run(
        [sys.executable, __file__, "--measure", mode, "--log", str(log)],
        capture_output=True, text=True, check=True,
    )
    return dict(json.loads(out.stdout.strip().splitlines()[-1]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scans", type=int, default=2000, help="scans in the long log (the short has half)")
    ap.add_argument("--rows", type=int, default=32)
    ap.add_argument("--cols", type=int, default=1024)
    ap.add_argument("--compression", choices=["none", "zstd", "lz4"], default="none")
    ap.add_argument("--dir", type=Path, default=Path(__file__).resolve().parent.parent / ".cache" / "bench_ingest")
    ap.add_argument("--repeat", type=int, default=2, help="runs per measurement (best wall time kept)")
    ap.add_argument("--measure", help=argparse.SUPPRESS)
    ap.add_argument("--log", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.measure:
        print(json.dumps(measure(args.measure, args.log)))
        return
    args.dir.mkdir(parents=True, exist_ok=True)
    print(f"ingest benchmark: {args.rows}x{args.cols} points/scan, 48 B/point, compression {args.compression}")
    rows = []
    for scans in (args.scans // 2, args.scans):
        log = args.dir / f"ouster-{args.rows}x{args.cols}-{scans}-{args.compression}.mcap"
        if not log.exists():
            t = time.perf_counter()
            write_log(log, scans, args.rows, args.cols, args.compression)
            print(f"wrote {log} ({log.stat().st_size / 1e9:.2f} GB) in {time.perf_counter() - t:.1f} s")
        with log.open("rb") as f:  # warm the page cache so every mode reads from memory
            while f.read(64 << 20):
                pass
        results = {}
        for mode in ("bare", "read", "deserialise", "mcap_ros2", "decode"):
            runs = [run_measurement(mode, log) for _ in range(args.repeat)]
            results[mode] = min(runs, key=lambda r: r["cpu_s"])
        rows.append((scans, results))
    # CPU time is the figure of merit: on a shared machine wall time mostly measures the others.
    print(
        f"{'scans':>6} {'mode':<12} {'cpu s':>7} {'wall s':>7} {'scans/s':>9} {'MB/s':>7} "
        f"{'peak RSS MB':>12} {'x bare':>7}"
    )
    for scans, results in rows:
        bare = results["bare"]["cpu_s"]
        for mode, r in results.items():
            print(
                f"{scans:>6} {mode:<12} {r['cpu_s']:>7.2f} {r['wall_s']:>7.2f} "
                f"{r['scans'] / r['cpu_s']:>9.1f} {r['bytes'] / 1e6 / r['cpu_s']:>7.0f} "
                f"{r['peak_rss_mb']:>12.0f} {r['cpu_s'] / bare:>7.2f}"
            )
    (short_n, short), (long_n, long) = rows
    print(
        f"decode/bare CPU time ratio: {short['decode']['cpu_s'] / short['bare']['cpu_s']:.2f} "
        f"({short_n} scans), {long['decode']['cpu_s'] / long['bare']['cpu_s']:.2f} ({long_n} scans); "
        "target <= 2"
    )
    print(
        f"decode peak RSS: {short['decode']['peak_rss_mb']:.0f} MB ({short_n} scans) -> "
        f"{long['decode']['peak_rss_mb']:.0f} MB ({long_n} scans): flat means streamed"
    )


if __name__ == "__main__":
    main()
