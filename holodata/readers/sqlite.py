"""Fallback for rosbag2 sqlite3 storage that rosbags cannot open (damaged metadata.yaml, unknown
storage id, a database cut short by a crashed recorder): the ``topics``, ``message_definitions``
and ``messages`` tables read with Python's sqlite3, row by row until the first unreadable page.
A database that stops early is marked ``truncated`` and holds the rows read before the damage.
"""
from __future__ import annotations

import sqlite3
from collections.abc import Iterable, Iterator
from pathlib import Path

from ..errors import RecordingError, one_line
from .base import MessageDecoder, RawMessage, Recording, TopicInfo, rate_of


def _connect(path: Path) -> sqlite3.Connection:
    return sqlite3.connect(f"file:{Path(path).resolve()}?mode=ro", uri=True)


def topic_times_sqlite(path: Path) -> dict[str, tuple[int, int]]:
    """{topic: (first, last) log time} with one indexed query."""
    con = _connect(path)
    try:
        rows = con.execute("SELECT t.name, MIN(m.timestamp), MAX(m.timestamp) FROM messages m "
                           "JOIN topics t ON t.id = m.topic_id GROUP BY m.topic_id").fetchall()
    finally:
        con.close()
    return {r[0]: (int(r[1]), int(r[2])) for r in rows if r[1] is not None}




class SqliteRecording(Recording):
    kind = "rosbag2-sqlite3"

    def __init__(self, path: Path, files: list[Path], msg_dir: Path | None = None):
        super().__init__(path)
        self.files = [Path(f) for f in files]
        self.topics_by_id: list[dict[int, tuple[str, str, str]]] = []
        defs: list[tuple[str, str | None, str]] = []
        for f in self.files:
            try:
                con = _connect(f)
                rows = con.execute("SELECT id, name, type, serialization_format FROM topics").fetchall()
            except sqlite3.Error as err:
                raise RecordingError(f"{f}: not a readable rosbag2 sqlite3 database ({one_line(err)})") from err
            self.topics_by_id.append({r[0]: (r[1], r[2], r[3] or "cdr") for r in rows})
            try:
                for ty, enc, text in con.execute("SELECT topic_type, encoding, encoded_message_definition "
                                                 "FROM message_definitions"):
                    defs.append((ty, {"ros2msg": "msg", "ros2idl": "idl"}.get(enc), text))
            except sqlite3.Error:
                pass
            con.close()
        self.decoder = MessageDecoder(2, defs, msg_dir, self.path,
                                      needed={ty for tb in self.topics_by_id for _, ty, _ in tb.values()})
        self.problems += self.decoder.problems
        self._infos: list[TopicInfo] | None = None

    def _topics(self) -> list[TopicInfo]:
        if self._infos is None:
            agg: dict[str, list] = {}
            for tb in self.topics_by_id:
                for name, ty, enc in tb.values():
                    agg.setdefault(name, [ty, enc, 0, None, None])
            for raw in self.raw_messages():
                a = agg[raw.topic]
                a[2] += 1
                a[3] = raw.log_ns if a[3] is None else min(a[3], raw.log_ns)
                a[4] = raw.log_ns if a[4] is None else max(a[4], raw.log_ns)
            self._infos = [TopicInfo(k, v[0], v[2], rate_of(v[2], v[3], v[4]), None, v[1],
                                     v[1] == "cdr" and self.decoder.known(v[0]), "", v[3], v[4])
                           for k, v in sorted(agg.items())]
        return [TopicInfo(**vars(t)) for t in self._infos]

    def raw_messages(self, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
        want = None if topics is None else set(topics)
        for f, tb in zip(self.files, self.topics_by_id):
            ids = [i for i, (name, _, _) in tb.items() if want is None or name in want]
            if not ids:
                continue
            con = _connect(f)
            where = f"WHERE topic_id IN ({','.join(str(i) for i in ids)})"
            n = 0
            try:
                for order in ("ORDER BY timestamp, id", ""):
                    try:
                        cur = con.execute(f"SELECT topic_id, timestamp, data FROM messages {where} {order}")
                        for tid, t, data in cur:
                            name, ty, enc = tb[tid]
                            n += 1
                            yield RawMessage(name, ty, int(t), data, enc)
                        break
                    except sqlite3.Error as err:
                        if order and n == 0:
                            continue  # sorting needs every page: retry in storage order
                        self.mark_truncated(f"{f}: database damaged after {n} readable messages ({one_line(err)}); "
                                            f"the readable part is used")
                        break
            finally:
                con.close()
