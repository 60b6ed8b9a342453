"""MCAP files through the ``mcap`` library: files rosbags does not open (non-``ros2`` profiles,
``ros1msg`` schemas, non-ROS encodings) and damaged ones (no summary from a crashed recorder, a file
cut short).

Channels whose message encoding is ``cdr`` (schemas ``ros2msg``/``ros2idl``) or ``ros1``
(``ros1msg``) are decoded with the recording's rosbags typestore; other encodings (JSON, protobuf,
the conformance suite's ``a``) are listed by ``topics()`` and yielded undecoded. A file without a
summary is read linearly; a file that ends early is read up to its last complete record and marked
``truncated``. Channels whose schema id is 0 or unknown count as ``schema: None`` (undecodable).

Sizes the file declares are checked before they are read or decompressed (:mod:`.sizes`):
:func:`.containers.check_mcap` checks every chunk's declared uncompressed size against its compressed bytes
when a file is opened (RecordingError naming the file), the library reads through a
:class:`.sizes.BoundedFile`, and chunks are decompressed by holodata, in bounded steps
(:func:`.containers._inflated`, :func:`.sizes.inflate`), not by the library.
"""
from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path

from ..errors import RecordingError, one_line
from .base import MCAP_MAGIC, MessageDecoder, RawMessage, Recording, TopicInfo, rate_of
from .containers import _inflated, _read_chunk, check_mcap, read_message
from .sizes import BoundedFile, declared_size, inflate, open_bounded

_SCHEMA_FMT = {"ros2msg": "msg", "ros2idl": "idl", "ros1msg": "msg"}




def _summary(f):
    """The file's summary, or None when it has none / cannot be read."""
    from mcap.reader import SeekingReader

    try:
        s = SeekingReader(f if isinstance(f, BoundedFile) else BoundedFile(f)).get_summary()
    except Exception:  # noqa: BLE001 - no footer, cut short, ...
        return None
    return s


def topic_times_mcap(path: Path) -> dict[str, tuple[int, int]]:
    """{topic: (first, last) log time} from the chunk message indexes (no chunk is decompressed)."""
    from mcap.records import MessageIndex
    from mcap.stream_reader import StreamReader

    out: dict[str, list[int]] = {}
    with open_bounded(path) as f:
        s = _summary(f)
        if s is None or not s.chunk_indexes:
            return {}
        for ci in s.chunk_indexes:
            for ch_id, off in ci.message_index_offsets.items():
                f.seek(off)
                rec = next(StreamReader(f, skip_magic=True).records)
                if not isinstance(rec, MessageIndex) or not rec.records:
                    continue
                times = [t for t, _ in rec.records]
                topic = s.channels[ch_id].topic
                lo, hi = out.setdefault(topic, [min(times), max(times)])
                out[topic] = [min(lo, min(times)), max(hi, max(times))]
    return {k: (v[0], v[1]) for k, v in out.items()}


class McapMessageTable:
    """Where each message of an indexed MCAP file with uncompressed chunks lies, from the file's
    summary and chunk message indexes (parsed by the ``mcap`` library), so that a pass can read
    only the bytes it needs: a header prefix (stamp, frame id) of a message it will not decode,
    the whole payload of one it will. Messages come in log-time order (ties: chunk, then position
    in the chunk — the order rosbags yields them).

    ``build`` returns None (callers then read the usual way) for files without a summary or
    message indexes, with compressed chunks, or whose indexes do not account for ``counts``."""

    HEAD = 256   # bytes read for a header-only message: CDR/ROS 1 header with a frame id < ~230 chars

    def __init__(self, path: Path, log_ns, offsets, channels, topics: dict[int, str], chunk_of=None, chunks=()):
        self.path, self.log_ns, self.offsets, self.channels, self.topics = path, log_ns, offsets, channels, topics
        self.chunk_of = chunk_of            # per message: index into ``chunks``
        self.chunks = list(chunks)          # (chunk record offset, records offset, records length)
        self._chunk_bad: dict[int, str | None] = {}

    @classmethod
    def build(cls, path: Path, counts: dict[str, int] | None = None) -> McapMessageTable | None:
        import struct

        import numpy as np

        try:
            with open_bounded(path) as f:
                s = _summary(f)
                if s is None or not s.chunk_indexes or any(ci.compression for ci in s.chunk_indexes):
                    return None
                logs, offs, chans, cks, chunks = [], [], [], [], []
                for c_i, ci in enumerate(s.chunk_indexes):
                    base = ci.chunk_start_offset + 9 + 40 + len(ci.compression)   # chunk records start
                    start = ci.chunk_start_offset + ci.chunk_length
                    # what the index declares must lie in the file: the records in their chunk, the
                    # message indexes after it (else read the file the usual way)
                    if base + ci.uncompressed_size > start or start + ci.message_index_length > f.size:
                        return None
                    chunks.append((ci.chunk_start_offset, base, ci.uncompressed_size))
                    # the chunk's MessageIndex records (opcode 0x07, u64 length, u16 channel, u32 bytes,
                    # (u64 log time, u64 offset) pairs) follow it in one block of message_index_length
                    f.seek(start)
                    block = f.read(ci.message_index_length)
                    for ch_id, off in ci.message_index_offsets.items():
                        p = off - start
                        op, _, cid, nb = struct.unpack_from("<BQHI", block, p)
                        if op != 0x07 or cid != ch_id or nb % 16 or p + 15 + nb > len(block):
                            return None
                        pairs = np.frombuffer(block, "<u8", nb // 8, p + 15).reshape(-1, 2).astype(np.int64)
                        logs.append(pairs[:, 0])
                        offs.append(pairs[:, 1] + base)
                        chans.append(np.full(len(pairs), ch_id, np.int64))
                        cks.append(np.full(len(pairs), c_i, np.int64))
            topics = {i: c.topic for i, c in s.channels.items()}
        except Exception:  # noqa: BLE001 - anything odd: read the file the usual way
            return None
        if not logs:
            return None
        log_ns, offsets, channels = np.concatenate(logs), np.concatenate(offs), np.concatenate(chans)
        order = np.lexsort((offsets, log_ns))
        table = cls(path, log_ns[order], offsets[order], channels[order], topics, np.concatenate(cks)[order], chunks)
        if counts is not None:
            have: dict[str, int] = {}
            for ch, n in zip(*np.unique(channels, return_counts=True)):
                have[topics.get(int(ch), "")] = have.get(topics.get(int(ch), ""), 0) + int(n)
            if any(have.get(t, 0) != n for t, n in counts.items()):
                return None
        return table

    def messages(self, topics: Iterable[str], heads: set[str] | frozenset = frozenset()):
        """(topic, log_ns, payload, ref) of ``topics`` in log-time order; for a topic in ``heads``
        the payload is its first :attr:`HEAD` bytes and ``ref`` = (offset, size, chunk) to read the
        rest with :meth:`payload` (else ref is None). A message read whole whose chunk fails its CRC
        comes header-only too, so that :meth:`payload` refuses it when it is decoded. Raises ValueError where a record is not the
        message its index says."""
        import os
        import struct

        import numpy as np

        want = {i for i, t in self.topics.items() if t in set(topics)}
        sel = np.isin(self.channels, list(want))
        fd = os.open(self.path, os.O_RDONLY)
        try:
            for log, off, ch, ck in zip(self.log_ns[sel].tolist(), self.offsets[sel].tolist(),
                                        self.channels[sel].tolist(), self.chunk_of[sel].tolist()):
                topic = self.topics[ch]
                head = topic in heads
                b = os.pread(fd, 31 + (self.HEAD if head else 0), off)
                if len(b) < 31:
                    raise ValueError(f"message record at byte {off} lies past the end of the file")
                op, length, cid, _, t = struct.unpack_from("<BQHIQ", b)
                if op != 0x05 or cid != ch or t != log or length < 22:
                    raise ValueError(f"record at byte {off} is not the indexed message (opcode {op:#x})")
                _, base, n = self.chunks[ck]      # the message lies in its chunk's records (RecordingError: a ValueError)
                size = declared_size(self.path, f"message at byte {off}", length - 22, base + n - off - 31,
                                     "its chunk holds from there")
                if not head and self._damaged(fd, ck):      # its payload is refused when it is asked for
                    yield topic, log, os.pread(fd, min(size, self.HEAD), off + 31), (off + 31, size, ck)
                    continue
                if head and size > self.HEAD:
                    yield topic, log, b[31:], (off + 31, size, ck)
                    continue
                data = b[31:31 + size] if head else os.pread(fd, size, off + 31)
                if len(data) != size:
                    raise ValueError(f"message at byte {off} is cut short")
                yield topic, log, data, None
        finally:
            os.close(fd)

    def _damaged(self, fd: int, ck: int) -> str | None:
        """Why chunk ``ck`` is damaged (its records' CRC-32 differs from the one the chunk carries),
        else None; checked once per chunk. A chunk written without a CRC (0: rosbags' writer) passes."""
        if ck not in self._chunk_bad:
            import os
            import struct
            import zlib

            start, base, n = self.chunks[ck]
            head = os.pread(fd, 37, start)
            crc = struct.unpack_from("<I", head, 33)[0] if len(head) == 37 else 0
            why = None
            if crc:
                got = zlib.crc32(os.pread(fd, n, base))
                if got != crc:
                    why = f"{self.path}: chunk at byte {start} fails its CRC check (damaged bytes)"
            self._chunk_bad[ck] = why
        return self._chunk_bad[ck]

    def payload(self, ref) -> bytes:
        """The whole payload of a message :meth:`messages` gave header-only; DecodeError when its
        chunk fails its CRC check."""
        import os

        from .base import DecodeError

        off, size, ck = ref
        fd = os.open(self.path, os.O_RDONLY)
        try:
            why = self._damaged(fd, ck)
            if why:
                raise DecodeError(f"{why}; message at byte {off} dropped")
            return read_message(fd, off, size)
        finally:
            os.close(fd)


def check_magic(fh, path) -> None:
    """Read the 8 magic bytes from the open binary file ``fh`` (of ``path``); RecordingError when the
    file is empty or not MCAP."""
    head = fh.read(8)
    if not head:
        raise RecordingError(f"{path}: file is empty")
    if head != MCAP_MAGIC:
        raise RecordingError(f"{path}: not an MCAP file (bad magic)")


def ros2_cdr(path: Path) -> bool:
    """True when the MCAP file ``path`` (magic checked: RecordingError) is sound (:func:`check_mcap`:
    RecordingError when a chunk declares more than it holds), has a summary with chunk indexes and
    every channel CDR-encoded: a ROS 2 file rosbags can read."""
    with open_bounded(path) as fh:
        check_magic(fh, path)
        if check_mcap(path):
            return False
        s = _summary(fh)
    return bool(s is not None and s.chunk_indexes and s.channels
                and all(c.message_encoding == "cdr" for c in s.channels.values()))


class McapRecording(Recording):
    kind = "mcap"

    def __init__(self, path: Path, files: list[Path] | None = None, msg_dir: Path | None = None):
        super().__init__(path)
        self.files = [Path(f) for f in (files or [path])]
        self.channels: dict[tuple[int, int], tuple[str, str, str]] = {}   # (file, channel id) -> topic, type, encoding
        self.summaries = []
        self._cut: dict[Path, str] = {}
        self.bad_chunks: dict[tuple[Path, int], dict[int, int]] = {}   # (file, byte) -> {channel id: messages}
        self.profile = ""
        defs: list[tuple[str, str | None, str]] = []
        counts: dict[str, int] = {}
        times: dict[str, list[int]] = {}
        ros1 = False
        for i, f in enumerate(self.files):
            self._check_magic(f)
            check_mcap(f)      # RecordingError when a chunk declares more than it holds; damage is read past
            with open_bounded(f) as fh:
                s = _summary(fh)
            self.summaries.append(s)
            if s is not None:
                for sc in s.schemas.values():
                    if sc.encoding in _SCHEMA_FMT:
                        defs.append((self._typename(sc.name), _SCHEMA_FMT[sc.encoding], sc.data.decode("utf-8", "replace")))
                for ch in s.channels.values():
                    self._add_channel(i, ch, s.schemas.get(ch.schema_id))
                    counts.setdefault(ch.topic, 0)
                if s.statistics is not None and s.statistics.channel_message_counts is not None:
                    for cid, n in s.statistics.channel_message_counts.items():
                        if cid in s.channels:
                            counts[s.channels[cid].topic] = counts.get(s.channels[cid].topic, 0) + n
                    for t, (lo, hi) in topic_times_mcap(f).items():
                        a, b = times.setdefault(t, [lo, hi])
                        times[t] = [min(a, lo), max(b, hi)]
                    continue
            # no summary (or no statistics): one linear pass for channels, counts and times
            if s is None:
                self.problems.append(f"{f}: no MCAP summary (recorder crashed?); read linearly")
            for what, a, msg in self._stream(i, f):
                if what == "schema":
                    if a.encoding in _SCHEMA_FMT:
                        defs.append((self._typename(a.name), _SCHEMA_FMT[a.encoding], a.data.decode("utf-8", "replace")))
                elif what == "channel":
                    counts.setdefault(a.topic, 0)
                else:
                    topic = a[0]
                    counts[topic] = counts.get(topic, 0) + 1
                    lo, hi = times.setdefault(topic, [msg.log_time, msg.log_time])
                    times[topic] = [min(lo, msg.log_time), max(hi, msg.log_time)]
        ros1 = any(e == "ros1" for _, _, e in self.channels.values())
        cdr = any(e == "cdr" for _, _, e in self.channels.values())
        self.decoder = MessageDecoder(1 if ros1 and not cdr else 2, defs, msg_dir, self.path,
                                      needed={ty for _, ty, _ in self.channels.values()})
        self.problems += self.decoder.problems
        by_topic: dict[str, tuple[str, str]] = {}
        for topic, ty, enc in self.channels.values():
            by_topic.setdefault(topic, (ty, enc))
        self._infos = []
        for name in sorted(by_topic):
            ty, enc = by_topic[name]
            lo, hi = times.get(name, (None, None))
            ok = enc in ("cdr", "ros1") and self.decoder.known(ty)
            note = "" if ok else (f"message encoding {enc!r} is not a ROS encoding; listed only"
                                  if enc not in ("cdr", "ros1") else "no message definition (pass --msg-dir)")
            self._infos.append(TopicInfo(name, ty, counts.get(name, 0), rate_of(counts.get(name, 0), lo, hi), None,
                                         enc, ok, note, lo, hi))
        if not self.channels:
            raise RecordingError(f"{self.path}: MCAP file has no channels")

    def _check_magic(self, f: Path) -> None:
        with open(f, "rb") as fh:
            check_magic(fh, f)

    @staticmethod
    def _typename(name: str) -> str:
        from rosbags.typesys.msg import normalize_msgtype

        return normalize_msgtype(name) if "/" in name else name

    def _add_channel(self, i: int, ch, schema) -> None:
        ty = self._typename(schema.name) if schema is not None else "(no schema)"
        enc = ch.message_encoding or ""
        enc = "cdr" if enc == "cdr" else "ros1" if enc == "ros1" else enc
        self.channels[(i, ch.id)] = (ch.topic, ty, enc)

    def _stream(self, i: int, f: Path):
        """Linear read of file ``i``: yields ("schema", Schema, None), ("channel", Channel, None) and
        ("message", (topic, type, encoding), Message); stops at the first incomplete or damaged record
        (a chunk cut short gives the complete records it still holds)."""
        from mcap.records import Channel, Message, Schema

        schemas = {}
        n = 0
        for rec in self._records(f):
            if isinstance(rec, Schema):
                schemas[rec.id] = rec
                yield "schema", rec, None
            elif isinstance(rec, Channel):
                if (i, rec.id) not in self.channels:
                    self._add_channel(i, rec, schemas.get(rec.schema_id))
                yield "channel", rec, None
            elif isinstance(rec, Message):
                key = (i, rec.channel_id)
                if key in self.channels:
                    n += 1
                    yield "message", self.channels[key], rec
        reason = self._cut.pop(f, None)
        if reason:
            self.mark_truncated(f"{f}: file ends early ({reason}) after {n} messages; the readable part is used")

    def _records(self, f: Path):
        """Top-level records framed here (opcode + u64 length, checked against the file size) and
        parsed by the mcap library; chunks broken up into their records."""
        import io
        import struct as st

        from mcap.records import Chunk, Footer
        from mcap.stream_reader import CRCValidationError, StreamReader, breakup_chunk

        size = f.stat().st_size
        with open(f, "rb") as fh:
            fh.seek(8)
            reason = None
            while True:
                pos = fh.tell()
                head = fh.read(9)
                if len(head) < 9:
                    reason = "no footer" if pos < size or not head else "partial record header"
                    break
                op, length = head[0], st.unpack("<Q", head[1:])[0]
                if pos + 9 + length > size:
                    body = fh.read()
                    if op == 0x06:
                        yield from _salvage_chunk(body)
                    reason = f"record at byte {pos} needs {length} bytes, {size - pos - 9} left"
                    break
                body = fh.read(length)
                try:
                    rec = next(StreamReader(io.BytesIO(head + body), skip_magic=True, emit_chunks=True,
                                            record_size_limit=None).records)
                except StopIteration:
                    continue
                except Exception as err:  # noqa: BLE001
                    reason = f"unreadable record at byte {pos} ({one_line(err)[:80]})"
                    break
                if isinstance(rec, Chunk):
                    try:
                        yield from breakup_chunk(_inflated(f, pos, rec), validate_crc=True)
                    except CRCValidationError:    # damaged bytes inside: its messages are dropped, counted
                        self._skip_chunk(f, pos, rec)
                    except Exception as err:  # noqa: BLE001 - corrupt chunk: keep its readable records
                        yield from _salvage_chunk(body)
                        reason = f"damaged chunk at byte {pos} ({one_line(err)[:80]})"
                        break
                elif isinstance(rec, Footer):
                    return
                else:
                    yield rec
        self._cut[f] = reason

    def _skip_chunk(self, f: Path, pos: int, chunk) -> None:
        """A chunk whose records fail its CRC: its messages are left out (every pass the same way),
        counted by channel in :attr:`bad_chunks` and noted in one problem line per file."""
        from collections import Counter

        from mcap.records import Message
        from mcap.stream_reader import breakup_chunk

        if (f, pos) in self.bad_chunks:
            return
        try:
            recs = breakup_chunk(_inflated(f, pos, chunk))
        except Exception:  # noqa: BLE001 - framing damaged too: the messages cannot even be counted
            recs = []
        self.bad_chunks[(f, pos)] = Counter(r.channel_id for r in recs if isinstance(r, Message))
        mine = [c for (g, _), c in self.bad_chunks.items() if g == f]
        line = (f"{f}: {len(mine)} chunk(s) fail their CRC check (damaged bytes; first at byte "
                f"{min(p for g, p in self.bad_chunks if g == f)}): their {sum(sum(c.values()) for c in mine)} "
                f"messages dropped")
        self.problems = [p for p in self.problems if not p.startswith(f"{f}: ") or "fail their CRC" not in p] + [line]

    def dropped_by_container(self) -> dict[str, int]:
        """{topic: messages} left out because their chunk failed its CRC check."""
        out: dict[str, int] = {}
        for (f, _), counts in self.bad_chunks.items():
            i = self.files.index(f)
            for cid, n in counts.items():
                if (i, cid) in self.channels:
                    t = self.channels[(i, cid)][0]
                    out[t] = out.get(t, 0) + n
        return out

    def _topics(self) -> list[TopicInfo]:
        return [TopicInfo(**vars(t)) for t in self._infos]

    def _indexed(self, f: Path, s, ids: set[int]):
        """(channel id, Message) of the channels ``ids`` in log-time order (ties: chunk offset, then
        place in the chunk), chunk by chunk from the summary's chunk indexes — the order of the mcap
        library's ``SeekingReader.iter_messages``; chunks are read and decompressed here (bounded,
        :func:`_read_chunk`). Raises on a damaged chunk (CRC, framing)."""
        import heapq

        from mcap.records import Message
        from mcap.stream_reader import breakup_chunk

        heap = [(ci.message_start_time, ci.chunk_start_offset, -1, ci) for ci in s.chunk_indexes
                if not ci.message_index_offsets or ids.intersection(ci.message_index_offsets)]
        heapq.heapify(heap)
        with open_bounded(f) as fh:
            while heap:
                _, off, k, item = heapq.heappop(heap)
                if k >= 0:
                    yield item.channel_id, item
                    continue
                for j, rec in enumerate(breakup_chunk(_read_chunk(fh, f, off), validate_crc=True)):
                    if isinstance(rec, Message) and rec.channel_id in ids:
                        heapq.heappush(heap, (rec.log_time, off, j, rec))

    def raw_messages(self, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
        want = None if topics is None else set(topics)
        for i, (f, s) in enumerate(zip(self.files, self.summaries)):
            if s is not None and s.chunk_indexes:
                ids = {cid for cid, c in s.channels.items() if want is None or c.topic in want}
                if not ids:
                    continue
                try:
                    for cid, msg in self._indexed(f, s, ids):
                        topic, ty, enc = self.channels[(i, cid)]
                        yield RawMessage(topic, ty, msg.log_time, msg.data, enc)
                except Exception as err:  # noqa: BLE001
                    self.mark_truncated(f"{f}: stopped at a damaged chunk ({one_line(err)[:120]})")
                continue
            for what, ch, msg in self._stream(i, f):
                if what != "message":
                    continue
                topic, ty, enc = ch
                if want is None or topic in want:
                    yield RawMessage(topic, ty, msg.log_time, msg.data, enc)


def _salvage_chunk(body: bytes):
    """Complete records of a chunk record body that is cut short or damaged (partial decompression,
    at most the size the chunk declares)."""
    import io
    import struct as st

    from mcap.data_stream import ReadDataStream
    from mcap.records import Channel, Message, Schema

    try:
        (usize,) = st.unpack_from("<Q", body, 16)
        o = 8 + 8 + 8 + 4
        (clen,) = st.unpack_from("<I", body, o)
        comp = body[o + 4:o + 4 + clen].decode()
        o += 4 + clen + 8
        data = body[o:]
        if comp not in ("", "zstd", "lz4"):
            return
        data = inflate(None, "chunk", comp or "none", data, usize if comp else None, partial=True)
    except Exception:  # noqa: BLE001 - nothing salvageable
        return
    stream = ReadDataStream(io.BytesIO(data))
    n = len(data)
    while n - stream.count >= 9:
        op = stream.read1()
        length = stream.read8()
        if n - stream.count < length:
            return
        try:
            if op == 0x04:
                yield Channel.read(stream)
            elif op == 0x05:
                yield Message.read(stream, length)
            elif op == 0x03:
                yield Schema.read(stream)
            else:
                stream.read(length)
        except Exception:  # noqa: BLE001
            return
