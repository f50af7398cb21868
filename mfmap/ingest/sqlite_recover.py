"""Reading what is left of a damaged ROS 2 sqlite3 bag (file cut short, or a corrupt page).

rosbags opens a `.db3` through queries that touch the whole database, so one bad page loses
every message. SQLite itself can still serve every row whose pages are intact: this reader walks
the messages table in id order, steps over a damaged stretch by asking for the following ids one
at a time, and checks each row's data as it goes. It keeps only (time, id, topic) per message,
then serves the data row by row in log-time order. A recorder that died also leaves no
metadata.yaml: a folder of `.db3` files is read the same way.
"""

from __future__ import annotations

import logging
import sqlite3
from collections.abc import Collection, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from mfmap.errors import DecodeError, LogError
from mfmap.ingest.backend import RawMessage, RawTopic, normalise_msgtype

logger = logging.getLogger(__name__)

# After this many unreadable ids in a row, the rest of the table is taken as lost: a file cut
# short ends in nothing but unreadable ids, and probing them all would take minutes.
MAX_PROBES = 100_000


@dataclass
class _Topic:
    name: str
    msgtype: str
    serialization: str


@dataclass
class _DbScan:
    path: Path
    con: sqlite3.Connection
    topics: dict[int, _Topic]
    definitions: dict[str, str]  # msgtype -> ros2msg definition
    ids: np.ndarray[Any, np.dtype[np.int64]]
    topic_ids: np.ndarray[Any, np.dtype[np.int64]]
    stamps_ns: np.ndarray[Any, np.dtype[np.int64]]
    damage: str | None


def connect(db: Path) -> sqlite3.Connection:
    # immutable: never touch (or create) -wal/-shm files next to a bag we only read.
    return sqlite3.connect(f"file:{db}?immutable=1", uri=True)


def metadata_count(folder: Path) -> int | None:
    """The message count metadata.yaml gives for the whole bag (None if it cannot say)."""
    import yaml

    try:
        info = yaml.safe_load((folder / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        return int(info["message_count"])
    except Exception:
        return None


def _first_line(err: BaseException) -> str:
    text = str(err).strip() or err.__class__.__name__
    return text.splitlines()[0]


def _scan_db(db: Path, max_id_hint: int | None) -> _DbScan:
    con, topics, definitions = _open_db(db)
    found: list[tuple[int, int, int]] = []
    damage = _walk_messages(con, max_id_hint, found, cut_short(db))
    found, damage = _drop_partial_tail(db, con, found, damage)
    arr = np.array(found, dtype=np.int64).reshape(-1, 3)
    return _DbScan(db, con, topics, definitions, arr[:, 0].copy(), arr[:, 1].copy(), arr[:, 2].copy(), damage)


def _open_db(db: Path) -> tuple[sqlite3.Connection, dict[int, _Topic], dict[str, str]]:
    """The open database, its topics by id and the message definitions it holds."""
    if not db.is_file():
        raise LogError("bag file listed in metadata.yaml is missing", db)
    con = connect(db)
    try:
        # A file cut short is smaller than its header says; SQLite refuses such a file unless
        # schema checks are relaxed (nothing is written: the file is opened immutable).
        con.execute("PRAGMA writable_schema = ON")
        rows = con.execute("SELECT id, name, type, serialization_format FROM topics").fetchall()
    except sqlite3.Error as err:
        con.close()
        raise LogError(f"cannot read the sqlite3 storage: {_first_line(err)}", db) from err
    topics = {int(i): _Topic(str(n), normalise_msgtype(str(t)), str(f)) for i, n, t, f in rows}
    definitions: dict[str, str] = {}
    try:
        for msgtype, encoding, text in con.execute(
            "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions"
        ):
            if encoding == "ros2msg" and text:
                definitions[normalise_msgtype(str(msgtype))] = str(text)
    except sqlite3.Error:
        pass  # bags before rosbag2 Iron have no definitions; damaged ones fall back the same way
    return con, topics, definitions


def _walk_messages(con: sqlite3.Connection, max_id_hint: int | None,
                   found: list[tuple[int, int, int]], damage: str | None) -> str | None:
    """Append (id, topic id, time) of every readable message to `found`, in id order, stepping
    over damaged stretches; return the damage seen (the first kind), or `damage`."""
    last_id = 0
    # substr(data, -1) makes SQLite follow the whole overflow chain of the data, so a row
    # whose data lost a page counts as damaged here, not when it is served.
    scan = "SELECT id, topic_id, timestamp, substr(data, -1) FROM messages WHERE id > ? ORDER BY id"
    probe = "SELECT id, topic_id, timestamp, substr(data, -1) FROM messages WHERE id = ?"
    while True:
        try:
            for row in con.execute(scan, (last_id,)):
                # A page lost off the end of the file reads as zeros: its "rows" have no
                # values (and id 0); they are damage, not messages.
                if None in row or int(row[0]) <= last_id:
                    damage = damage or "rows on pages past the end of the file"
                    continue
                found.append((int(row[0]), int(row[1]), int(row[2])))
                last_id = int(row[0])
            break
        except sqlite3.DatabaseError as err:
            damage = damage or _first_line(err)
        upper = _max_id(con, max_id_hint)
        hit = None
        probe_id = last_id + 1
        while hit is None and upper is not None and probe_id <= upper and probe_id - last_id <= MAX_PROBES:
            try:
                hit = con.execute(probe, (probe_id,)).fetchone()
            except sqlite3.DatabaseError:
                hit = None
            if hit is not None and None in hit:
                hit = None
            probe_id += 1
        if hit is None:
            break
        found.append((int(hit[0]), int(hit[1]), int(hit[2])))
        last_id = int(hit[0])
    return damage


def _drop_partial_tail(db: Path, con: sqlite3.Connection, found: list[tuple[int, int, int]],
                       damage: str | None) -> tuple[list[tuple[int, int, int]], str | None]:
    """`found` less the rows the page the file ends inside held, and the damage seen."""
    tail = _partial_tail(db, con)
    if tail is not None:
        damage = damage or "the file ends inside a page"
        in_tree, lo, hi = tail
        if in_tree:
            found = [r for r in found if not ((lo is None or r[0] > lo) and (hi is None or r[0] <= hi))]
        elif found:
            # Not a page of the messages table: taken as an overflow page of the last message
            # written (rosbag2 only appends, so the last page belongs to the last row).
            found.pop(max(range(len(found)), key=lambda k: found[k][0]))
    return found, damage


def cut_short(db: Path) -> str | None:
    """'cut short (N of M bytes)' when the file is smaller than its header says."""
    try:
        with db.open("rb") as f:
            head = f.read(100)
    except OSError:
        return None
    if len(head) < 100 or not head.startswith(b"SQLite format 3\x00"):
        return None
    page_size = int.from_bytes(head[16:18], "big")
    page_size = 65536 if page_size == 1 else page_size
    if head[24:28] != head[92:96]:
        return None  # the in-header size is stale (an old writer changed the file since)
    want = int.from_bytes(head[28:32], "big") * page_size
    size = db.stat().st_size
    return f"file cut short: {size} of {want} bytes" if size < want else None


def _partial_tail(db: Path, con: sqlite3.Connection) -> tuple[bool, int | None, int | None] | None:
    """When the file ends part way into a page: (that page is in the messages table, and the
    message ids (lo, hi] it holds; None is unbounded). None when the file ends on a page edge.

    SQLite reads the missing end of that page as zeros, so a row stored across the cut would
    come back with zeroed data and no error. Found by walking the interior pages of the
    messages table down to that page.
    """
    size = db.stat().st_size
    try:
        page_size = int(con.execute("PRAGMA page_size").fetchone()[0])
        root = int(con.execute("SELECT rootpage FROM sqlite_master WHERE name = 'messages'").fetchone()[0])
    except (sqlite3.Error, TypeError):
        return None
    if size % page_size == 0:
        return None
    last = size // page_size + 1
    with db.open("rb") as f:

        def page(n: int) -> bytes:
            f.seek((n - 1) * page_size)
            return f.read(page_size)

        def walk(n: int, lo: int | None, hi: int | None, depth: int) -> tuple[int | None, int | None] | None:
            if n == last:
                return lo, hi
            if n > last or depth > 20:
                return None
            b = page(n)
            hdr = 100 if n == 1 else 0
            if len(b) < hdr + 12 or b[hdr] != 0x05:  # not an interior table page
                return None
            prev = lo
            for i in range(int.from_bytes(b[hdr + 3 : hdr + 5], "big")):
                cell = int.from_bytes(b[hdr + 12 + 2 * i : hdr + 14 + 2 * i], "big")
                child = int.from_bytes(b[cell : cell + 4], "big")
                key = _varint(b, cell + 4)
                found = walk(child, prev, key, depth + 1)
                if found is not None:
                    return found
                prev = key
            return walk(int.from_bytes(b[hdr + 8 : hdr + 12], "big"), prev, hi, depth + 1)

        try:
            found = walk(root, None, None, 0)
        except (IndexError, ValueError):
            found = None
        return (False, None, None) if found is None else (True, *found)


def _varint(b: bytes, pos: int) -> int:
    value = 0
    for i in range(8):
        byte = b[pos + i]
        value = (value << 7) | (byte & 0x7F)
        if byte < 0x80:
            return value
    return (value << 8) | b[pos + 8]


def _max_id(con: sqlite3.Connection, hint: int | None) -> int | None:
    """The largest message id: from the table's rightmost page, else from metadata.yaml."""
    try:
        row = con.execute("SELECT max(id) FROM messages").fetchone()
        if row is not None and row[0] is not None:
            return int(row[0])
    except sqlite3.DatabaseError:
        pass
    return hint


class Ros2SqliteRecoveryBackend:
    """ROS 2 sqlite3 storage read row by row, as far as SQLite can still read it."""

    def __init__(self, path: Path, dbs: list[Path], expected_count: int | None, reason: str | None) -> None:
        self.format = "ros2"
        self.path = path
        self.scans: list[_DbScan] = []
        try:
            for db in dbs:
                self.scans.append(_scan_db(db, expected_count))
        except BaseException:
            self.close()
            raise
        names: dict[str, _Topic] = {}
        for s in self.scans:
            for t in s.topics.values():
                names.setdefault(t.name, t)
        self.topics = {n: RawTopic(n, t.msgtype, 0, None, None) for n, t in names.items()}
        # All recovered messages as columns: file, id, topic name index, stamp.
        topic_names = sorted(names)
        code = {n: i for i, n in enumerate(topic_names)}
        files, ids, tcodes, stamps = [], [], [], []
        for k, s in enumerate(self.scans):
            lookup = np.full(max(s.topics, default=0) + 2, -1, dtype=np.int64)
            for tid, t in s.topics.items():
                if tid >= 0:
                    lookup[tid] = code[t.name]
            valid = (s.topic_ids >= 0) & (s.topic_ids < lookup.shape[0] - 1)
            tc = np.where(valid, lookup[np.clip(s.topic_ids, 0, lookup.shape[0] - 1)], -1)
            keep = tc >= 0  # rows of a topic the topics table does not hold are unusable
            files.append(np.full(int(keep.sum()), k, dtype=np.int64))
            ids.append(s.ids[keep])
            tcodes.append(tc[keep])
            stamps.append(s.stamps_ns[keep])
        self._file = np.concatenate(files) if files else np.zeros(0, np.int64)
        self._id = np.concatenate(ids) if ids else np.zeros(0, np.int64)
        self._topic = np.concatenate(tcodes) if tcodes else np.zeros(0, np.int64)
        self._stamp = np.concatenate(stamps) if stamps else np.zeros(0, np.int64)
        self._topic_names = topic_names
        for i, name in enumerate(topic_names):
            mine = self._stamp[self._topic == i]
            if mine.size:
                raw = self.topics[name]
                raw.count, raw.first_ns, raw.last_ns = int(mine.size), int(mine.min()), int(mine.max())
        damages = [f"{s.path.name}: {s.damage}" for s in self.scans if s.damage]
        n = int(self._id.shape[0])
        covered = (int(self._stamp.max()) - int(self._stamp.min())) / 1e9 if n else 0.0
        of = f" of {expected_count}" if expected_count is not None else ""
        why = "; ".join(damages) or reason or "no metadata.yaml"
        # Storage without its metadata.yaml is not damaged, only read the slow way.
        what = ("sqlite3 storage read row by row" if not damages and reason and "metadata.yaml" in reason
                else "damaged or truncated sqlite3 storage")
        self.warnings = [
            f"{path}: {what} ({why}); recovered {n}{of} messages covering {covered:.1f} s of log time"
        ]
        if n == 0 and not self.topics:
            self.close()
            raise LogError(f"cannot read the bag: {why}; no readable messages", path)
        self._stores: dict[str, Typestore] = {}
        self._latest: Typestore | None = None

    @property
    def damaged(self) -> bool:
        return any(s.damage for s in self.scans)

    def log_times(self, topic: str) -> np.ndarray[Any, np.dtype[np.int64]]:
        """Log times of the topic's messages in recording order (file, then row id)."""
        if topic not in self._topic_names:
            return np.zeros(0, dtype=np.int64)
        idx = np.flatnonzero(self._topic == self._topic_names.index(topic))
        return np.asarray(self._stamp[idx[np.lexsort((self._id[idx], self._file[idx]))]], dtype=np.int64)

    def iter_raw(
        self, topics: Collection[str], start_ns: int | None, end_ns: int | None
    ) -> Iterator[RawMessage]:
        codes = [i for i, n in enumerate(self._topic_names) if n in topics]
        sel = np.isin(self._topic, codes)
        if start_ns is not None:
            sel &= self._stamp >= start_ns
        if end_ns is not None:
            sel &= self._stamp <= end_ns
        idx = np.flatnonzero(sel)
        # Log-time order; ties by file, then id (the order the recorder wrote them).
        idx = idx[np.lexsort((self._id[idx], self._file[idx], self._stamp[idx]))]
        for i in idx:
            scan = self.scans[int(self._file[i])]
            rid = int(self._id[i])
            try:
                row = scan.con.execute("SELECT topic_id, data FROM messages WHERE id = ?", (rid,)).fetchone()
            except sqlite3.Error as err:
                raise LogError(f"cannot read message {rid}: {_first_line(err)}", scan.path) from err
            if row is None:
                raise LogError(f"message {rid} vanished from the storage", scan.path)
            topic = scan.topics[int(row[0])]
            yield RawMessage(topic.name, int(self._stamp[i]), (topic, bytes(row[1]), scan))

    def _store_for(self, msgtype: str, scan: _DbScan, where: str) -> Typestore:
        text = scan.definitions.get(msgtype)
        if text is not None:
            store = self._stores.get(msgtype)
            if store is None:
                store = get_typestore(Stores.EMPTY)
                try:
                    store.register(get_types_from_msg(text, msgtype))
                    self._stores[msgtype] = store
                    return store
                except Exception:
                    logger.debug("%s: cannot parse the stored definition of %s", where, msgtype)
            else:
                return store
        if self._latest is None:
            self._latest = get_typestore(Stores.LATEST)
        if msgtype not in self._latest.fielddefs:
            raise DecodeError(f"message type '{msgtype}' has no definition", where)
        return self._latest

    def typestore(self, message: RawMessage) -> Typestore:
        topic, _data, scan = message.payload
        return self._store_for(topic.msgtype, scan, f"{scan.path} topic {topic.name}")

    def deserialize(self, message: RawMessage) -> Any:
        topic, data, scan = message.payload
        where = f"{scan.path} topic {topic.name}"
        store = self._store_for(topic.msgtype, scan, where)
        try:
            return store.deserialize_cdr(data, topic.msgtype)
        except Exception as err:
            raise DecodeError(f"cannot deserialise a '{topic.msgtype}' message: {_first_line(err)}", where) from err

    def raw_size(self, message: RawMessage) -> int:
        return len(message.payload[1])

    def serialized(self, message: RawMessage) -> tuple[str, Any]:
        return message.payload[0].serialization, message.payload[1]

    def close(self) -> None:
        for s in self.scans:
            s.con.close()
