"""ROS bags through rosbags' own readers: ROS 1 ``.bag`` (uncompressed, bz2 or lz4 chunks),
rosbag2 folders (``metadata.yaml`` + sqlite3 ``.db3`` or ``.mcap`` files, split bags, zstd file or
message compression) and bare rosbag2 storage files (``.db3``, ``.mcap`` with the ``ros2`` profile).

Damaged files: a ROS 1 bag without a usable index (recorder killed, file cut short) is read by a
linear scan over its chunks with rosbags' record parser until the first unreadable record; the
recording is then marked ``truncated`` and holds the readable prefix. rosbag2 storage files that
rosbags cannot open are handed to the sqlite3 / MCAP fallbacks (:mod:`.sqlite`, :mod:`.mcap_file`),
which do the same.

Sizes the file declares (record header and data lengths, a chunk's uncompressed size) are checked
against the bytes the file holds before they are read or decompressed (:mod:`.sizes`): rosbags' ROS 1
reader is opened only after :func:`.containers.ros1_chunk_sizes` walked the records it reads, and its chunks are
decompressed in bounded steps up to the size their headers declare; rosbags' MCAP chunks likewise
(:func:`bound_rosbags_mcap`).
"""
from __future__ import annotations

import contextlib
import os
from collections import defaultdict
from collections.abc import Iterable, Iterator
from io import BytesIO
from pathlib import Path

from ..errors import RecordingError, one_line
from .base import MessageDecoder, RawMessage, Recording, TopicInfo, rate_of
from .containers import check_mcap, read_message, ros1_chunk_sizes
from .sizes import inflate, open_bounded


def _defs(conn) -> tuple[str, str | None, str]:
    fmt = getattr(conn.msgdef.format, "name", "NONE").lower()
    return conn.msgtype, (fmt if fmt in ("msg", "idl") else None), conn.msgdef.data


class RosbagsRecording(Recording):
    """A bag opened with rosbags' ``rosbag1.Reader`` (``ros_version`` 1) or ``rosbag2.Reader``."""

    def __init__(self, path: Path, reader, ros_version: int, kind: str, msg_dir: Path | None = None):
        super().__init__(path)
        self.reader = reader
        self.ros_version = ros_version
        self.kind = kind
        self.decoder = MessageDecoder(ros_version, [_defs(c) for c in reader.connections], msg_dir, self.path)
        self.problems += self.decoder.problems
        self._infos: list[TopicInfo] | None = None
        if ros_version == 1:
            self.files = [self.path]
        elif self.path.is_dir():
            self.files = [Path(s.path) for s in getattr(reader.storage, "storages", [])] or sorted(
                p for p in self.path.iterdir() if p.suffix in (".db3", ".mcap", ".zstd"))
        else:
            self.files = [self.path]

    def _encoding(self, conn) -> str:
        if self.ros_version == 1:
            return "ros1"
        return getattr(conn.ext, "serialization_format", "cdr") or "cdr"

    def _times(self) -> dict[str, tuple[int, int]]:
        """First/last log time per topic, from indexes only (no message data read)."""
        out: dict[str, list[int]] = {}
        try:
            if self.ros_version == 1:
                for c in self.reader.connections:
                    idx = self.reader.indexes.get(c.id) or []
                    if idx:
                        lo, hi = out.setdefault(c.topic, [idx[0].time, idx[-1].time])
                        out[c.topic] = [min(lo, idx[0].time), max(hi, idx[-1].time)]
            elif (table := self._message_table()) and hasattr(table, "channels"):
                import numpy as np  # a single MCAP file whose index ingest reads anyway: its log times

                for ch, topic in table.topics.items():
                    t = table.log_ns[table.channels == ch]
                    if len(t):
                        lo, hi = out.setdefault(topic, [int(t.min()), int(t.max())])
                        out[topic] = [min(lo, int(np.min(t))), max(hi, int(np.max(t)))]
            else:
                from .mcap_file import topic_times_mcap
                from .sqlite import topic_times_sqlite

                for f in self.files:
                    tt = topic_times_sqlite(f) if f.suffix == ".db3" else topic_times_mcap(f) if f.suffix == ".mcap" else {}
                    for t, (lo, hi) in tt.items():
                        a, b = out.setdefault(t, [lo, hi])
                        out[t] = [min(a, lo), max(b, hi)]
        except Exception:  # noqa: BLE001 - rates are a nicety
            pass
        return {k: (v[0], v[1]) for k, v in out.items()}

    def _topics(self) -> list[TopicInfo]:
        if self._infos is None:
            counts: dict[str, int] = defaultdict(int)
            types: dict[str, str] = {}
            enc: dict[str, str] = {}
            for c in self.reader.connections:
                counts[c.topic] += c.msgcount
                types.setdefault(c.topic, c.msgtype)
                enc.setdefault(c.topic, self._encoding(c))
            times = self._times()
            infos = []
            for name in sorted(counts):
                lo, hi = times.get(name, (None, None))
                e = enc[name]
                ok = e in ("cdr", "ros1") and self.decoder.known(types[name])
                note = "" if ok else (f"serialisation {e!r} not decoded" if e not in ("cdr", "ros1")
                                      else "no message definition (pass --msg-dir)")
                infos.append(TopicInfo(name, types[name], counts[name], rate_of(counts[name], lo, hi), None, e, ok,
                                       note, lo, hi))
            self._infos = infos
        return [TopicInfo(**vars(t)) for t in self._infos]

    def raw_messages(self, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
        conns = self.reader.connections
        if topics is not None:
            want = set(topics)
            conns = [c for c in conns if c.topic in want]
            if not conns:
                return
        enc = {c.id: self._encoding(c) for c in conns}
        try:
            for c, t, data in self.reader.messages(connections=conns):
                yield RawMessage(c.topic, c.msgtype, t, data, enc[c.id])
        except Exception as err:  # noqa: BLE001 - damaged data past the index
            self.mark_truncated(f"{self.path}: stopped reading at a damaged record ({one_line(err)[:160]})")

    _table = None

    def _message_table(self):
        """Where each message lies, so that a pass reads only the bytes it needs: a
        :class:`.mcap_file.McapMessageTable` for a single-file rosbag2 MCAP bag with uncompressed
        chunks whose indexes match the bag's message counts, a :class:`Ros1MessageTable` for a ROS 1
        bag with uncompressed chunks; else False (messages are read through rosbags)."""
        if self._table is None:
            self._table = False
            if self.ros_version == 1:
                self._table = Ros1MessageTable.build(self.path, self.reader) or False
            elif len(self.files) == 1 and self.files[0].suffix == ".mcap" \
                    and not getattr(self.reader, "compression_mode", None):
                from .mcap_file import McapMessageTable

                counts: dict[str, int] = defaultdict(int)
                for c in self.reader.connections:
                    counts[c.topic] += c.msgcount
                self._table = McapMessageTable.build(self.files[0], dict(counts)) or False
        return self._table

    def raw_heads(self, topics: Iterable[str], heads: Iterable[str]) -> Iterator[RawMessage]:
        table = self._message_table()
        if not table:
            yield from self.raw_messages(topics)
            return
        want = set(topics)
        try:
            if self.ros_version == 1:
                conns = [c for c in self.reader.connections if c.topic in want]
                for c, log, data, ref in table.messages(conns, set(heads)):
                    yield RawMessage(c.topic, c.msgtype, log, data, "ros1", ref=ref)
                return
            conns = {c.topic: c for c in self.reader.connections if c.topic in want}
            enc = {t: self._encoding(c) for t, c in conns.items()}
            for topic, log, data, ref in table.messages(conns, set(heads)):
                yield RawMessage(topic, conns[topic].msgtype, log, data, enc[topic], ref=ref)
        except (ValueError, OSError) as err:
            self.mark_truncated(f"{self.path}: stopped reading at a damaged record ({one_line(err)[:160]})")

    def full(self, raw: RawMessage) -> RawMessage:
        if raw.ref is None:
            return raw
        from dataclasses import replace

        return replace(raw, data=self._message_table().payload(raw.ref), ref=None)

    def close(self) -> None:
        with contextlib.suppress(Exception):   # rosbags' own, on a reader that failed half-open; nothing to keep
            self.reader.close()


class Ros1MessageTable:
    """Where each message of an indexed ROS 1 bag with uncompressed chunks lies (rosbags' index:
    per message its chunk and its offset in the chunk's data), so that a pass can read only the bytes
    it needs: a header prefix (stamp, frame id) of a message it will not decode, the whole payload of
    one it will — as :class:`.mcap_file.McapMessageTable` does for MCAP. rosbags' own reader reads
    (and copies) every chunk whole for any message in it. Messages come in the order rosbags yields
    them: log time, then the connection's place in the list asked for, then the connection's index
    order (rosbags merges its per-connection indexes, which compare by time only).

    ``build`` returns None (callers then read through rosbags) when any chunk is compressed."""

    HEAD = 256     # payload bytes read for a header-only message (ROS 1 header, frame id < ~230 chars)
    PROBE = 96     # record header bytes read with it (a message data record's is 4 + ~45)

    def __init__(self, path: Path, log_ns, pos, conn, seq, limit):
        self.path, self.log_ns, self.pos, self.conn, self.seq, self.limit = path, log_ns, pos, conn, seq, limit

    @classmethod
    def build(cls, path: Path, reader) -> Ros1MessageTable | None:
        import numpy as np
        from rosbags.rosbag1.reader import decompressors

        chunks = reader.chunks
        if not chunks or any(c.decompressor is not decompressors["none"] for c in chunks.values()):
            return None
        rows = [(e.time, e.chunk_pos, e.offset, cid, k) for cid, idx in reader.indexes.items()
                for k, e in enumerate(idx)]
        if not rows:
            return None
        t, cpos, off, cid, seq = (np.array(c, np.int64) for c in zip(*rows))
        datapos = np.array([chunks[k].datapos for k in cpos.tolist()], np.int64)
        size = np.array([chunks[k].datasize for k in cpos.tolist()], np.int64)
        return cls(path, t, datapos + off, cid, seq, datapos + size)

    def messages(self, conns, heads: set[str] | frozenset = frozenset()):
        """(connection, log_ns, payload, ref) of the connections ``conns`` in rosbags' order; for a
        topic in ``heads`` the payload is its first :attr:`HEAD` bytes and ``ref`` = (offset, size) to
        read the rest with :meth:`payload` (else ref is None). Raises ValueError where a record is not
        the message the index says or runs past its chunk."""
        import os

        import numpy as np

        by_id = {c.id: c for c in conns}
        rank = {c.id: r for r, c in enumerate(conns)}
        sel = np.flatnonzero(np.isin(self.conn, list(by_id)))
        ranks = np.array([rank[k] for k in self.conn[sel].tolist()], np.int64)
        sel = sel[np.lexsort((self.seq[sel], ranks, self.log_ns[sel]))]
        fd = os.open(self.path, os.O_RDONLY)
        try:
            for log, pos, cid, limit in zip(self.log_ns[sel].tolist(), self.pos[sel].tolist(),
                                            self.conn[sel].tolist(), self.limit[sel].tolist()):
                c = by_id[cid]
                head = c.topic in heads
                start, size, b, at = self._record(fd, pos, limit, cid, log, self.HEAD if head else 0)
                if head and size > self.HEAD:
                    yield c, log, b[start - at:start - at + self.HEAD], (start, size)
                    continue
                if start + size <= at + len(b):
                    data = b[start - at:start - at + size]
                else:
                    data = read_message(fd, start, size)
                yield c, log, data, None
        finally:
            os.close(fd)

    def _record(self, fd: int, pos: int, limit: int, cid: int, log: int, extra: int) -> tuple[int, int, bytes, int]:
        """(payload offset, payload size, bytes read, their file offset) of the message data record
        at ``pos`` (connection records before it skipped, as rosbags does); ValueError unless it is
        connection ``cid``'s message at ``log`` and lies within its chunk (ending at ``limit``)."""
        import os
        import struct

        try:
            while True:
                b = os.pread(fd, 4 + self.PROBE + 4 + extra, pos)
                (hlen,) = struct.unpack_from("<I", b, 0)
                if pos + 8 + hlen > limit:
                    raise ValueError(f"record at byte {pos} runs past the end of its chunk")
                if 8 + hlen > len(b):
                    b = os.pread(fd, 8 + hlen + extra, pos)
                fields, i = {}, 4
                while i < 4 + hlen:
                    (n,) = struct.unpack_from("<I", b, i)
                    name, eq, value = b[i + 4:i + 4 + n].partition(b"=")
                    if not eq or i + 4 + n > 4 + hlen:
                        raise ValueError(f"record at byte {pos} has a damaged header")
                    fields[name] = value
                    i += 4 + n
                (size,) = struct.unpack_from("<I", b, 4 + hlen)
                start = pos + 8 + hlen
                if start + size > limit:
                    raise ValueError(f"record at byte {pos} runs past the end of its chunk")
                op = fields.get(b"op", b"")
                if op == b"\x07":     # a connection record: the message follows it
                    pos = start + size
                    continue
                if op != b"\x02" or len(fields.get(b"conn", b"")) != 4 or len(fields.get(b"time", b"")) != 8:
                    raise ValueError(f"record at byte {pos} is not a message data record")
                (conn,) = struct.unpack("<I", fields[b"conn"])
                sec, nsec = struct.unpack("<II", fields[b"time"])
                if conn != cid or sec * 1_000_000_000 + nsec != log:
                    raise ValueError(f"record at byte {pos} is not the indexed message")
                return start, size, b, pos
        except struct.error as err:
            raise ValueError(f"record at byte {pos} is cut short") from err

    def payload(self, ref) -> bytes:
        """The whole payload of a message :meth:`messages` gave header-only."""
        import os

        off, size = ref
        fd = os.open(self.path, os.O_RDONLY)
        try:
            return read_message(fd, off, size)
        finally:
            os.close(fd)


# --------------------------------------------------------------------------------------------------
# ROS 1 linear scan (no index)

class Ros1ScanRecording(Recording):
    """A ROS 1 bag read front to back without its index (see module docstring)."""

    kind = "rosbag1"

    def __init__(self, path: Path, reason: str, msg_dir: Path | None = None):
        super().__init__(path)
        self.files = [self.path]
        self.conns: dict[int, tuple[str, str, str]] = {}   # id -> topic, type, definition
        counts: dict[int, int] = defaultdict(int)
        first: dict[int, int] = {}
        last: dict[int, int] = {}
        n = 0
        for cid, t, _ in self._scan(count_only=True):
            counts[cid] += 1
            first.setdefault(cid, t)
            last[cid] = max(last.get(cid, t), t)
            n += 1
        if not self.conns:
            raise RecordingError(f"{self.path}: ROS 1 bag has no readable connection records ({reason})")
        self.problems.insert(0, f"{self.path}: bag index unusable ({reason}); read {n} messages by a linear scan")
        self.decoder = MessageDecoder(1, [(ty, "msg", d) for _, ty, d in self.conns.values()], msg_dir, self.path)
        self.problems += self.decoder.problems
        by_topic: dict[str, list] = {}
        for cid, (topic, ty, _) in self.conns.items():
            e = by_topic.setdefault(topic, [ty, 0, None, None])
            e[1] += counts.get(cid, 0)
            if cid in first:
                e[2] = first[cid] if e[2] is None else min(e[2], first[cid])
                e[3] = last[cid] if e[3] is None else max(e[3], last[cid])
        self._infos = [TopicInfo(k, v[0], v[1], rate_of(v[1], v[2], v[3]), None, "ros1", self.decoder.known(v[0]),
                                 "", v[2], v[3]) for k, v in sorted(by_topic.items())]

    def _scan(self, count_only: bool = False):
        from rosbags.rosbag1.reader import Header, ReaderError, RecordType, decompressors, read_bytes, read_uint32
        from rosbags.typesys.msg import normalize_msgtype

        def conn_record(header, data):
            cid = header.get_uint32("conn")
            if cid not in self.conns:
                info = Header.read(BytesIO(len(data).to_bytes(4, "little") + data))
                self.conns[cid] = (header.get_string("topic"), normalize_msgtype(info.get_string("type")),
                                   info.get_string("message_definition") if "message_definition" in info else "")

        with open_bounded(self.path) as f:     # reads of declared lengths stop at the end of the file
            size = f.size
            try:
                magic = f.readline()
                if not magic.startswith(b"#ROSBAG V2.0"):
                    raise RecordingError(f"{self.path}: not a ROS 1 bag v2.0 (bad magic)")
                Header.read(f, RecordType.BAGHEADER)
                f.seek(read_uint32(f), os.SEEK_CUR)
                while f.tell() < size:
                    pos = f.tell()
                    header = Header.read(f)
                    op = header.get_uint8("op")
                    want = read_uint32(f)
                    data = f.read(want)
                    cut = len(data) < want
                    if op == RecordType.CHUNK:
                        comp = header.get_string("compression")
                        if comp not in decompressors:
                            raise ReaderError(f"chunk compression {comp!r} is not supported")
                        usize = header.get_uint32("size") if "size" in header else None
                        # bounded: stops at the declared size (RecordingError if the data cannot hold it)
                        data = inflate(self.path, f"chunk at byte {pos}", comp, data, usize, partial=cut)
                        inner = BytesIO(data)
                        n_inner = len(data)
                        try:
                            while inner.tell() < n_inner:
                                h = Header.read(inner)
                                d = read_bytes(inner, read_uint32(inner))
                                o = h.get_uint8("op")
                                if o == RecordType.CONNECTION:
                                    conn_record(h, d)
                                elif o == RecordType.MSGDATA:
                                    yield h.get_uint32("conn"), h.get_time("time"), (None if count_only else d)
                        except ReaderError:
                            if not cut:
                                raise
                    elif cut:
                        pass
                    elif op == RecordType.CONNECTION:
                        conn_record(header, data)
                    elif op == RecordType.MSGDATA:
                        yield header.get_uint32("conn"), header.get_time("time"), (None if count_only else data)
                    if cut:
                        raise ReaderError(f"record of {want} bytes cut short at "
                                          f"{len(data) if op != RecordType.CHUNK else 'its end'}")
            except RecordingError:
                raise
            except (ReaderError, KeyError, OSError, ValueError, EOFError) as err:
                self.mark_truncated(f"{self.path}: file ends in a damaged or partial record at byte {f.tell()} of "
                                    f"{size} ({one_line(err)[:100]}); the readable part is used")

    def _topics(self) -> list[TopicInfo]:
        return [TopicInfo(**vars(t)) for t in self._infos]

    def raw_messages(self, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
        want = None if topics is None else set(topics)
        for cid, t, data in self._scan():
            topic, ty, _ = self.conns[cid]
            if want is None or topic in want:
                yield RawMessage(topic, ty, t, data, "ros1")


# --------------------------------------------------------------------------------------------------
# rosbags' decompressors bounded (the sizes they declare are walked first: :mod:`.containers`)

def _bounded_chunks(path: Path, reader, sizes: dict[int, tuple[str, int | None]]) -> None:
    """rosbags decompresses a chunk in full (``bz2.decompress``, ``lz4.frame.decompress``): give each
    compressed chunk of ``reader`` a decompressor that stops at the size its header declares."""
    from functools import partial

    for pos, chunk in list(reader.chunks.items()):
        comp, usize = sizes.get(pos, ("none", None))
        if comp != "none":
            reader.chunks[pos] = chunk._replace(
                decompressor=partial(inflate, path, f"chunk at byte {pos}", comp, size=usize))


_ROSBAGS_MCAP_BOUNDED = False


def bound_rosbags_mcap() -> None:
    """rosbags' MCAP storage decompresses each chunk in full before it compares the size (its
    ``DECOMPRESSORS`` table, called with the chunk's declared uncompressed size): swap in
    :func:`.sizes.inflate`, which stops there. The sizes were checked against the chunks' bytes
    first (:func:`.containers.check_mcap`)."""
    global _ROSBAGS_MCAP_BOUNDED
    if _ROSBAGS_MCAP_BOUNDED:
        return
    try:
        from rosbags.rosbag2 import storage_mcap
    except ImportError:
        return
    table = getattr(storage_mcap, "DECOMPRESSORS", None)
    if isinstance(table, dict):
        for codec in ("lz4", "zstd"):
            if codec in table:
                table[codec] = lambda data, size, _c=codec: inflate(None, "MCAP chunk", _c, data, size)
    _ROSBAGS_MCAP_BOUNDED = True


# --------------------------------------------------------------------------------------------------
# openers used by the registry

def open_rosbag1(path: Path, msg_dir: Path | None = None) -> Recording:
    from rosbags.rosbag1 import Reader

    with open(path, "rb") as f:
        head = f.read(13)
    if not head:
        raise RecordingError(f"{path}: file is empty")
    if not head.startswith(b"#ROSBAG V"):
        raise RecordingError(f"{path}: not a ROS 1 bag (no '#ROSBAG V2.0' magic at the start)")
    if not head.startswith(b"#ROSBAG V2.0"):
        raise RecordingError(f"{path}: ROS 1 bag version {head[9:12].decode('ascii', 'replace')} is not supported "
                             f"(only 2.0; convert it with `rosbag fix`)")
    sizes = ros1_chunk_sizes(Path(path))     # before rosbags reads what the index declares
    if isinstance(sizes, str):
        return Ros1ScanRecording(path, sizes[:120], msg_dir)
    reader = Reader(path)
    try:
        reader.open()
    except Exception as err:  # noqa: BLE001 - rosbags raises ReaderError, struct/unicode errors
        return Ros1ScanRecording(path, one_line(err)[:120], msg_dir)
    _bounded_chunks(Path(path), reader, sizes)
    return RosbagsRecording(path, reader, 1, "rosbag1", msg_dir)


def open_rosbag2(path: Path, msg_dir: Path | None = None) -> Recording:
    """rosbag2 folder with metadata.yaml, or a bare ``.db3`` / ROS 2 ``.mcap`` storage file."""
    from rosbags.rosbag2 import Reader

    path = Path(path)
    files = _storage_files(path)
    # MCAP sizes checked before rosbags reads them (RecordingError when a chunk declares more than it holds)
    unsound = [(f, why) for f in files if f.suffix == ".mcap" and f.is_file() and (why := check_mcap(f))]
    try:
        if unsound:
            raise RecordingError(f"{unsound[0][0].name}: {unsound[0][1]}")
        bound_rosbags_mcap()
        reader = Reader(path)
        reader.open()
    except Exception as err:  # noqa: BLE001 - fall back to the storage files themselves
        reason = one_line(err)[:160]
        if not files:
            raise RecordingError(f"{path}: rosbag2 folder without readable storage files ({reason})") from err
        suffixes = {f.suffix for f in files}
        if suffixes == {".db3"}:
            from .sqlite import SqliteRecording

            rec = SqliteRecording(path, files, msg_dir)
        elif suffixes == {".mcap"}:
            from .mcap_file import McapRecording

            rec = McapRecording(path, files, msg_dir)
        else:
            raise RecordingError(f"{path}: rosbags cannot open it ({reason})") from err
        if path.is_dir():
            rec.problems.insert(0, f"{path}: rosbags cannot open the bag ({reason}); read its storage files directly")
        return rec
    kind = "rosbag2-" + ("mcap" if any(f.suffix == ".mcap" for f in files) else "sqlite3")
    return RosbagsRecording(path, reader, 2, kind, msg_dir)


def _storage_files(path: Path) -> list[Path]:
    if not path.is_dir():
        return [path]
    meta = path / "metadata.yaml"
    if meta.exists():
        try:
            import yaml

            info = yaml.safe_load(meta.read_text())["rosbag2_bagfile_information"]
            from ..safe_io import name_problem

            names = [Path(str(p)).name for p in info.get("relative_file_paths", [])]
            # storage files are the folder's own ('..' would be the folder above): else the folder listing
            files = [path / n for n in names] if not any(name_problem(n) for n in names) else []
            if files and all(f.is_file() for f in files):
                return files
        except Exception:  # noqa: BLE001 - damaged metadata: look at the folder instead
            pass
    return sorted(p for p in path.iterdir() if p.suffix in (".db3", ".mcap"))
