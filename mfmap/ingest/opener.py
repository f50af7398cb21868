"""Which reader a log path needs: MCAP, ROS 1 bag, ROS 2 bag folder, or a damaged one's recovery.

`open_backend` looks at the path (file or folder, its first bytes, metadata.yaml) and opens the
backend for it; `check_one_recording` refuses a folder of .mcap files from different recordings.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from mfmap.errors import LogError
from mfmap.ingest.backend import Backend


def open_backend(path: Path) -> Backend:
    """The backend that reads `path`, chosen by what the path holds, not by its name alone."""
    from mfmap.ingest.bag_backend import ROS1_MAGIC, RosbagsBackend
    from mfmap.ingest.mcap_backend import MCAP_MAGIC, McapBackend

    if not path.exists():
        raise LogError("no such file or folder", path)
    if path.is_dir():
        meta = path / "metadata.yaml"
        if meta.is_file():
            storage, files = _ros2_metadata(meta)
            if storage == "mcap" and files is not None:
                return McapBackend([path / f for f in files], fmt="ros2")
            return _open_ros2_bag(path)
        mcaps = sorted(p for p in path.glob("*.mcap") if p.is_file())
        if mcaps:
            return McapBackend(mcaps, fmt="mcap")
        dbs = sorted(p for p in path.glob("*.db3") if p.is_file())
        if dbs:
            # rosbag2 writes metadata.yaml when it closes the bag: a recorder that died left
            # only its database files.
            from mfmap.ingest.sqlite_recover import Ros2SqliteRecoveryBackend

            return Ros2SqliteRecoveryBackend(path, dbs, None, "no metadata.yaml: the recorder did not finish")
        raise LogError("folder holds neither a ROS 2 metadata.yaml nor .mcap or .db3 files", path)
    if path.stat().st_size == 0:
        raise LogError("empty file (0 bytes), not a log", path)
    with path.open("rb") as f:
        head = f.read(16)
    if head.startswith(MCAP_MAGIC):
        return McapBackend([path], fmt="mcap")
    if head.startswith(ROS1_MAGIC):
        try:
            return RosbagsBackend(path, "ros1")
        except LogError as err:
            if err.__cause__ is None:
                raise
            # A recorder that died leaves no (or a broken) index: read what is intact.
            from mfmap.ingest.ros1_recover import Ros1RecoveryBackend

            return Ros1RecoveryBackend(path, str(err).split(": ", 2)[-1])
    if path.name == "metadata.yaml":
        return open_backend(path.parent)
    if path.suffix == ".db3":
        return _open_db3(path)
    kind = {".mcap": "an MCAP file", ".bag": "a ROS 1 bag"}.get(path.suffix, "a known log format")
    raise LogError(f"not {kind} (unrecognised content at the start of the file)", path)


def _open_db3(path: Path) -> Backend:
    """A .db3 file named on its own: its bag when the metadata.yaml beside it lists it, else
    that file alone (never another log that happens to lie in the same folder)."""
    from mfmap.ingest.sqlite_recover import Ros2SqliteRecoveryBackend

    meta = path.parent / "metadata.yaml"
    if meta.is_file() and path.name in _metadata_files(meta):
        return open_backend(path.parent)
    return Ros2SqliteRecoveryBackend(path, [path], None,
                                     "a .db3 file on its own: no metadata.yaml lists it")


def _metadata_files(meta: Path) -> list[str]:
    """The file names metadata.yaml lists (also for storage `_ros2_metadata` does not open)."""
    try:
        info = yaml.safe_load(meta.read_text())["rosbag2_bagfile_information"]
        return [Path(str(p)).name for p in info.get("relative_file_paths") or []]
    except Exception:
        return []


def _open_ros2_bag(path: Path) -> Backend:
    """A ROS 2 bag folder through rosbags; a damaged sqlite3 one row by row instead."""
    from mfmap.ingest.bag_backend import RosbagsBackend, sqlite_files
    from mfmap.ingest.sqlite_recover import Ros2SqliteRecoveryBackend, cut_short, metadata_count

    dbs = sqlite_files(path)
    if any(cut_short(db) for db in dbs):
        # SQLite may open a file cut short and fail only on the first lost page, mid-read.
        return Ros2SqliteRecoveryBackend(path, dbs, metadata_count(path), None)
    try:
        return RosbagsBackend(path, "ros2")
    except LogError as err:
        if err.__cause__ is None or not dbs:
            raise
        recovered = Ros2SqliteRecoveryBackend(path, dbs, metadata_count(path), str(err).split(": ", 1)[-1])
        if not recovered.damaged:
            recovered.close()  # the storage is intact: the problem is elsewhere
            raise
        return recovered


def _ros2_metadata(meta: Path) -> tuple[str, list[str] | None]:
    """Storage id and, for mcap storage without file compression, the files in order.

    Rejects topics with a serialization format other than CDR.
    """
    try:
        doc = yaml.safe_load(meta.read_text())
        info = doc["rosbag2_bagfile_information"]
    except Exception as err:
        raise LogError(f"not a ROS 2 bag metadata file ({err.__class__.__name__})", meta) from err
    if not isinstance(info, dict):
        raise LogError("not a ROS 2 bag metadata file (rosbag2_bagfile_information is not a "
                       "mapping)", meta)
    entries = info.get("topics_with_message_count") or []
    paths = info.get("relative_file_paths") or []
    for key, value in (("topics_with_message_count", entries), ("relative_file_paths", paths)):
        if not isinstance(value, list):
            raise LogError(f"not a ROS 2 bag metadata file ({key} is not a list: {value!r:.40})",
                           meta)
    for entry in entries:
        topic = entry.get("topic_metadata", {}) if isinstance(entry, dict) else None
        if not isinstance(topic, dict):
            raise LogError("not a ROS 2 bag metadata file (an entry of topics_with_message_count "
                           f"without topic_metadata: {entry!r:.40})", meta)
        fmt = topic.get("serialization_format", "cdr")
        if fmt != "cdr":
            raise LogError(
                f"topic {topic.get('name')} has unknown serialization format '{fmt}' "
                "(only cdr is supported)",
                meta,
            )
    storage = str(info.get("storage_identifier", ""))
    if storage not in ("mcap", "sqlite3"):
        raise LogError(f"unknown storage '{storage}' (expected sqlite3 or mcap)", meta)
    # Early rosbag2 versions wrote the bag folder into the "relative" paths: keep the name only.
    files = [str(p) if (meta.parent / str(p)).is_file() else Path(str(p)).name for p in paths]
    if info.get("compression_mode") or not files:
        return storage, None
    missing = [f for f in files if not (meta.parent / f).is_file()]
    if missing:
        raise LogError(f"bag file {missing[0]} listed in metadata.yaml is missing", meta.parent)
    return storage, files


def check_one_recording(backend: Backend, path: Path, max_gap_s: float) -> None:
    """Several .mcap files are one log only when they follow on from (or overlap) each other:
    two unrelated recordings in one folder must not become one log years long."""
    spans = []
    for fi in getattr(backend, "files", []):
        if fi.first_ns:
            spans.append((min(fi.first_ns.values()), max(fi.last_ns.values()), fi.path.name))
    spans.sort()
    end, last_name = None, ""
    for first, last, name in spans:
        if end is not None and first - end > max_gap_s * 1e9:
            raise LogError(
                f"holds .mcap files of different recordings: {name} starts "
                f"{(first - end) / 1e9:.0f} s after {last_name} ends (more than ingest.max_gap_s, "
                f"{max_gap_s:g} s); build each recording on its own", path)
        if end is None or last > end:
            end, last_name = last, name
