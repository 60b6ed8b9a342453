"""Bounded walks over container files: MCAP chunks and records, ROS 1 bag chunks.

Every length such a file declares (a record's, a chunk's uncompressed size, an index's) is checked
against the bytes the file holds (:mod:`.sizes`) before it is read, reserved or decompressed:

- MCAP (:mod:`.mcap_file`, and rosbag2 ``.mcap`` storage files before rosbags opens them,
  :mod:`.rosbag`): :func:`check_mcap` walks the summary's chunk indexes, or the records from the start
  when there is no usable summary, checking each chunk record (:func:`_chunk_problem`);
  :func:`_read_chunk` reads one chunk record and decompresses it in bounded steps (:func:`_inflated`).
- ROS 1 bags (:mod:`.rosbag`): :func:`ros1_chunk_sizes` walks the records rosbags' ``Reader.open()``
  reads (bag header, connection and chunk info records, chunk headers, index data records).
- Both readers' message tables read a message's payload by offset (:func:`read_message`).
"""
from __future__ import annotations

import os
from pathlib import Path

from .base import MCAP_MAGIC
from .sizes import declared_size, inflate, inflated_room, open_bounded


def read_message(fd: int, off: int, size: int) -> bytes:
    """The ``size`` payload bytes at byte ``off`` of the open file ``fd``; ValueError when the file
    ends first (the message is cut short)."""
    data = os.pread(fd, size, off)
    if len(data) != size:
        raise ValueError(f"message at byte {off} is cut short")
    return data


# --------------------------------------------------------------------------------------------------
# MCAP: chunk records, the summary's chunk indexes, a linear walk over the records

def _chunk_problem(f, path, pos: int, n: int, index=None) -> str | None:
    """Check the chunk record at byte ``pos`` (``n`` bytes after its opcode and length) of the open
    bounded file ``f``: RecordingError when the uncompressed size it declares (or its summary chunk
    ``index`` declares) is more than its compressed bytes can hold; a reason when the record is
    damaged (its data runs past the record, the index points elsewhere); None when it is sound."""
    import struct

    where = f"chunk at byte {pos}"
    if n < 40:
        return f"{where} is too short for a chunk record ({n} bytes)"
    f.seek(pos + 9)
    head = f.read(32)
    if len(head) < 32:
        return f"{where} is cut short"
    _, _, usize, _, clen = struct.unpack("<QQQII", head)
    if clen > n - 40:
        return f"{where} declares a {clen}-byte compression name, its record holds {n - 40}"
    comp = f.read(clen).decode("utf-8", "replace")
    b = f.read(8)
    if len(b) < 8:
        return f"{where} is cut short"
    (dlen,) = struct.unpack("<Q", b)
    if dlen > n - 40 - clen:
        return f"{where} declares {dlen} bytes of data, its record holds {n - 40 - clen}"
    if comp:
        declared_size(path, f"{where} ({comp})", usize, inflated_room(dlen),
                      f"its {dlen} compressed bytes can hold at most")
    if index is not None:
        if index.compressed_size != dlen or index.compression != comp:
            return f"the summary's index of the {where} does not match the chunk"
        if comp:
            declared_size(path, f"summary index of the {where} ({comp})", index.uncompressed_size,
                          inflated_room(dlen), f"its {dlen} compressed bytes can hold at most")
    return None


def check_mcap(path: Path) -> str | None:
    """Check the sizes an MCAP file declares where a reader (holodata's, the mcap library's,
    rosbags') would read or reserve them, before any does: every chunk's uncompressed size — the
    chunk record's and its summary index's — against its compressed bytes (a
    :class:`RecordingError` naming the file when more than they can hold, :func:`.sizes.declared_size`),
    and the lengths the records and the summary declare against the bytes the file holds.

    The chunks are those of the summary's chunk indexes, or of a linear walk over the records when
    the file has no usable summary. Returns None for a sound file; else a one-line reason (records
    that run past the end of the file, a damaged summary): such a file is read linearly, by
    :class:`McapRecording`, up to where it breaks, not by rosbags."""
    import struct
    from io import BytesIO

    from mcap.data_stream import ReadDataStream
    from mcap.records import ChunkIndex

    with open_bounded(path) as f:
        size = f.size
        if f.read(8) != MCAP_MAGIC:
            return "not an MCAP file (bad magic)"
        why = None
        indexes: list | None = None
        schemas = False
        data_end = size
        if size >= 8 + 37:
            f.seek(size - 37)
            foot = f.read(37)
            if foot[0] == 0x02 and foot[1:9] == struct.pack("<Q", 20) and foot[-8:] == MCAP_MAGIC:
                data_end = size - 37
                (start,) = struct.unpack_from("<Q", foot, 9)
                if start and not 8 <= start <= size - 37:
                    why = f"summary offset {start} lies outside the file"
                elif start:
                    data_end, indexes, pos = start, [], start
                    while pos < size - 37:
                        if pos + 9 > size - 37:
                            why = f"summary record at byte {pos} is cut short"
                            break
                        f.seek(pos)
                        head = f.read(9)
                        op, n = head[0], struct.unpack_from("<Q", head, 1)[0]
                        if n > size - 37 - pos - 9:
                            why = f"summary record at byte {pos} declares {n} bytes, {size - 37 - pos - 9} left"
                            break
                        if op == 0x08:
                            try:
                                indexes.append(ChunkIndex.read(ReadDataStream(BytesIO(f.read(n)))))
                            except Exception:  # noqa: BLE001 - a damaged record
                                why = f"summary chunk index at byte {pos} is damaged"
                                break
                        schemas = schemas or op == 0x03
                        pos += 9 + n
        if indexes and why is None:
            for ci in indexes:
                pos, n = ci.chunk_start_offset, ci.chunk_length - 9
                if not 8 <= pos <= pos + ci.chunk_length + ci.message_index_length <= data_end or n < 0:
                    why = f"the summary indexes a chunk at byte {pos} past the end of the file"
                    break
                why = _chunk_problem(f, path, pos, n, ci)
                if why:
                    break
            if why is None and schemas:
                return None              # every reader goes by the summary's chunk indexes
        # no (usable) summary: readers walk the records from the start (rosbags also without schemas)
        pos = 8
        while pos + 9 <= data_end:
            f.seek(pos)
            head = f.read(9)
            op, n = head[0], struct.unpack_from("<Q", head, 1)[0]
            if n > size - pos - 9:
                return why or f"record at byte {pos} declares {n} bytes, {size - pos - 9} left in the file"
            if op == 0x06:
                why = why or _chunk_problem(f, path, pos, n)
            elif op == 0x02:
                break
            pos += 9 + n
    return why


def _inflated(path, pos: int, chunk):
    """``chunk`` (an mcap ``Chunk`` at byte ``pos`` of ``path``) with its records decompressed here,
    in bounded steps up to the size it declares (:func:`.sizes.inflate`; the mcap library would
    reserve that size, or the size its zstd frame declares, first): a Chunk with compression ''."""
    from mcap.records import Chunk

    comp = chunk.compression
    raw = inflate(path, f"chunk at byte {pos}", comp or "none", chunk.data, chunk.uncompressed_size if comp else None)
    return Chunk(compression="", data=raw, message_end_time=chunk.message_end_time,
                 message_start_time=chunk.message_start_time, uncompressed_crc=chunk.uncompressed_crc,
                 uncompressed_size=len(raw))


def _read_chunk(fh, path, pos: int):
    """The chunk record at byte ``pos`` of the open bounded file ``fh``, decompressed (:func:`_inflated`);
    ValueError naming ``path`` when there is none or it runs past the end of the file."""
    import io
    import struct

    from mcap.data_stream import ReadDataStream
    from mcap.records import Chunk

    fh.seek(pos)
    head = fh.read(9)
    if len(head) < 9 or head[0] != 0x06:
        raise ValueError(f"{path}: no chunk record at byte {pos}")
    (n,) = struct.unpack_from("<Q", head, 1)
    body = fh.read(n)             # bounded: at most what the file holds
    if len(body) < n:
        raise ValueError(f"{path}: chunk at byte {pos} runs past the end of the file")
    return _inflated(path, pos, Chunk.read(ReadDataStream(io.BytesIO(body))))


# --------------------------------------------------------------------------------------------------
# declared sizes of ROS 1 bags: what rosbags' Reader.open() and messages() would read

class _Unusable(Exception):
    """The bag's index cannot be read as declared (rosbags would fail on it too)."""


def ros1_chunk_sizes(path: Path) -> dict[int, tuple[str, int | None]] | str:
    """Walk the records rosbags' ``Reader.open()`` reads — the bag header, the connection and chunk
    info records at ``index_pos``, every chunk's header and the index data records after it — and
    check every length they declare against the bytes left in the file, before rosbags reads (and
    reserves) them. Returns {chunk position: (compression, uncompressed size its header declares or
    None)}, or a one-line reason when the index cannot be read as declared (the bag is then read by
    a linear scan). A chunk whose declared uncompressed size its compressed bytes cannot hold is a
    :class:`RecordingError` (:func:`.sizes.declared_size`)."""
    out: dict[int, tuple[str, int | None]] = {}
    with open_bounded(path) as f:
        r = _Ros1Records(f)
        try:
            if not f.readline().startswith(b"#ROSBAG V2.0"):
                return "not a ROS 1 bag v2.0"
            bag = r.header("bag header")
            index_pos, conns, chunks = _uint(bag, b"index_pos", "<Q"), _uint(bag, b"conn_count"), _uint(bag, b"chunk_count")
            if index_pos == 0 or chunks == 0:
                return out                  # rosbags reads nothing more (unindexed bags: its own error)
            if index_pos > r.size:
                return f"index position {index_pos} lies past the end of the file ({r.size} bytes)"
            for pos, n_index in _ros1_chunk_infos(r, index_pos, conns, chunks):
                out[pos] = _ros1_chunk(r, path, pos, n_index)
        except _Unusable as err:
            return str(err)
    return out


class _Ros1Records:
    """Reads the records of a ROS 1 bag from the open bounded file ``f`` (``size`` bytes), every length
    checked against the bytes left before it is read (:class:`_Unusable` otherwise)."""

    def __init__(self, f):
        self.f, self.size = f, f.size

    def u32(self, what: str) -> int:
        import struct

        f = self.f
        b = f.read(4)
        if len(b) != 4:
            raise _Unusable(f"{what} at byte {f.tell() - len(b)} cut short")
        return struct.unpack("<I", b)[0]

    def length(self, what: str) -> int:
        """A record's (or its data's) length, within the bytes left in the file."""
        at = self.f.tell()
        n = self.u32(what)
        if n > self.size - at - 4:
            raise _Unusable(f"{what} at byte {at} declares {n} bytes, {self.size - at - 4} left in the file")
        return n

    def header(self, what: str) -> dict[bytes, bytes]:
        """A record header's fields {name: value}."""
        import struct

        b = self.f.read(self.length(f"{what} header"))
        fields, i = {}, 0
        while i < len(b):
            if i + 4 > len(b):
                raise _Unusable(f"{what} header is damaged")
            (n,) = struct.unpack_from("<I", b, i)
            name, eq, value = b[i + 4:i + 4 + n].partition(b"=")
            if not eq or i + 4 + n > len(b):
                raise _Unusable(f"{what} header is damaged")
            fields[name] = value
            i += 4 + n
        return fields

    def skip_data(self, what: str) -> None:
        """Past a record's data (its length checked)."""
        self.f.seek(self.length(what), os.SEEK_CUR)


def _uint(fields: dict, name: bytes, fmt: str = "<I") -> int:
    """Field ``name`` of a record header as an unsigned integer (``fmt``)."""
    import struct

    try:
        return struct.unpack(fmt, fields[name])[0]
    except (KeyError, struct.error) as err:
        raise _Unusable(f"record field {name.decode()!r} missing or damaged") from err


def _ros1_chunk_infos(r: _Ros1Records, index_pos: int, conns: int, chunks: int) -> list[tuple[int, int]]:
    """From ``index_pos``: past the ``conns`` connection records, then the ``chunks`` chunk info
    records: [(chunk position, how many connections' index data records follow the chunk)]."""
    import struct

    f = r.f
    f.seek(index_pos)
    for _ in range(conns):
        r.header("connection record")
        r.skip_data("connection record data")
    infos = []
    for _ in range(chunks):
        h = r.header("chunk info record")
        n = _uint(h, b"count")
        r.length("chunk info record data")
        b = f.read(8 * n)
        if len(b) != 8 * n:
            raise _Unusable("chunk info record cut short")
        infos.append((_uint(h, b"chunk_pos", "<Q"), len(dict(struct.iter_unpack("<II", b)))))
    return infos


def _ros1_chunk(r: _Ros1Records, path, pos: int, n_index: int) -> tuple[str, int | None]:
    """The chunk at ``pos``: (compression, the uncompressed size its header declares or None), the
    declared size checked against what its compressed bytes can hold; then past its ``n_index``
    index data records."""
    if pos >= r.size:
        raise _Unusable(f"chunk position {pos} lies past the end of the file")
    f = r.f
    f.seek(pos)
    h = r.header("chunk")
    comp = h.get(b"compression", b"none").decode("utf-8", "replace")
    datasize = r.length("chunk data")
    usize = _uint(h, b"size") if b"size" in h else None
    if comp != "none" and usize is not None:
        declared_size(path, f"chunk at byte {pos}: its {comp} data", usize, inflated_room(datasize),
                      f"its {datasize} compressed bytes can hold at most")
    f.seek(datasize, os.SEEK_CUR)
    for _ in range(n_index):
        r.header("index data record")
        r.skip_data("index data record data")
    return comp, usize
