"""Sizes a file declares, checked against what the file can hold before anything is allocated.

Containers state sizes ahead of the bytes they describe: an HDF5 dataset its shape, a ROS 1 record
its header and data lengths and a chunk its uncompressed size, an MCAP record its length and a chunk
its uncompressed size, a ``.npy`` header its array's shape. Allocating such a size as read (numpy,
h5py, ``file.read(n)`` and ``os.pread(fd, n, ...)``, which reserve ``n`` bytes first,
``zstandard.decompress``) lets a few kilobytes ask for gigabytes. The readers go through these
helpers instead, so that a file from elsewhere gets a one-line :class:`~holodata.errors.RecordingError`
naming it and what it declares:

- :func:`declared_size`: a declared size against the room it must fit in: the bytes left in the
  file, the bytes HDF5 stores for a dataset, or :func:`inflated_room` of compressed bytes.
- :func:`inflate`: bz2 / LZ4 frame / zstd decompression in bounded steps that stops at the size the
  container declares (never decompressed in full first, never sized from the compressor's frame).
- :class:`BoundedFile` (:func:`open_bounded`): a file whose ``read(n)`` never asks for more than
  the file has left, for libraries that read declared lengths (mcap, rosbags' record headers,
  numpy's ``.npy`` header reader).
- :func:`check_npy` / :func:`check_npz`: ``.npy`` headers (alone or inside a ``.npz``) against the
  bytes that follow them.
"""
from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

from ..errors import RecordingError, one_line

MAX_RATIO = 1024           # the most a compressed chunk is believed to expand ...
BELIEVED = 64 * 2 ** 20    # ... unless what it declares is below this (a mostly-zero chunk compresses far more)
STEP = 2 ** 20             # decompressed in pieces of at most this


def fmt_bytes(n: int) -> str:
    """``n`` bytes in words: '4712 bytes', '80000000000 bytes (74.5 GiB)'."""
    if n < 2 ** 20:
        return f"{n} bytes"
    for unit, k in (("TiB", 40), ("GiB", 30), ("MiB", 20)):
        if n >= 2 ** k:
            return f"{n} bytes ({n / 2 ** k:.1f} {unit})"
    return f"{n} bytes"


def inflated_room(compressed: int) -> int:
    """The most ``compressed`` bytes are believed to decompress to."""
    return max(int(compressed) * MAX_RATIO, BELIEVED)


def declared_size(path, what: str, n: int, room: int, held: str = "the file holds",
                  hint: str = "damaged, or not written by a recorder", error=RecordingError) -> int:
    """``n`` (a size ``what`` in file ``path`` declares) when it fits in ``room`` bytes; else a one-line
    ``error`` naming the file: '<path>: <what> declares <n> bytes, but <held> <room> bytes (<hint>)'."""
    n = int(n)
    if 0 <= n <= room:
        return n
    where = f"{path}: " if path is not None else ""
    raise error(f"{where}{what} declares {fmt_bytes(n)}, but {held} {fmt_bytes(max(int(room), 0))} ({hint})")


def file_size(f) -> int:
    """Size in bytes of the open file ``f`` (a path also works)."""
    if isinstance(f, (str, os.PathLike)):
        return os.path.getsize(f)
    return os.fstat(f.fileno()).st_size


class BoundedFile:
    """A binary file whose ``read(n)`` reads at most the bytes left (``file.read(n)`` reserves ``n``
    bytes before it reads: a declared length of 4 GiB costs 4 GiB even in a 5 KB file). Short reads
    stay short, as at the end of any file; everything else is the wrapped file's."""

    def __init__(self, f, size: int | None = None):
        self._f = f
        self.size = file_size(f) if size is None else int(size)

    def read(self, n: int | None = -1) -> bytes:
        if n is None or n < 0:
            return self._f.read()
        return self._f.read(max(0, min(n, self.size - self._f.tell())))

    def readline(self, limit: int = -1) -> bytes:
        left = self.size - self._f.tell()
        return self._f.readline(left if limit is None or limit < 0 else min(limit, left))

    def __getattr__(self, name):
        return getattr(self._f, name)

    def __iter__(self):
        return iter(self._f)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._f.close()


def open_bounded(path) -> BoundedFile:
    return BoundedFile(open(path, "rb"))


# --------------------------------------------------------------------------------------------------
# decompression



def _pieces(codec: str, data, limit: int) -> Iterator[bytes]:
    """Decompressed pieces of ``data`` (concatenated streams/frames too), at most ``limit`` bytes in all."""
    if codec == "zstd":
        import zstandard

        reader = zstandard.ZstdDecompressor().stream_reader(data, read_across_frames=True)
        total = 0
        while total < limit:
            piece = reader.read(min(STEP, limit - total))
            if not piece:
                return
            total += len(piece)
            yield piece
        return
    if codec == "bz2":
        import bz2

        new = bz2.BZ2Decompressor
    elif codec == "lz4":
        import lz4.frame

        new = lz4.frame.LZ4FrameDecompressor
    else:
        raise ValueError(f"compression {codec!r} is not supported (bz2, lz4, zstd)")
    d, buf, total, later = new(), data, 0, False
    while total < limit:
        try:
            piece = d.decompress(buf, min(STEP, limit - total))
        except (OSError, RuntimeError, ValueError):
            if later:   # bytes after a complete stream that are no stream: ignored, as bz2.decompress does
                return
            raise
        later = later and not piece
        buf = b""
        total += len(piece)
        if piece:
            yield piece
        if d.eof:
            if not d.unused_data:
                return
            d, buf, later = new(), d.unused_data, True
        elif not piece and d.needs_input:
            return


def inflate(path, what: str, codec: str | None, data, size: int | None, partial: bool = False) -> bytes:
    """The bytes of ``data`` compressed with ``codec`` ('none' / '' / None, 'bz2', 'lz4', 'zstd'), which
    the container declares to be ``size`` bytes (None: it does not say).

    ``size`` is first checked against :func:`inflated_room` of ``len(data)`` (:func:`declared_size`:
    RecordingError naming ``path``); decompression then runs in pieces and stops one byte past
    ``size``: more, or fewer, than declared is a ValueError naming ``what`` (damaged data: callers
    that keep a readable prefix treat it so, and name the file). ``partial``: the data is cut short; give
    whatever decompresses, at most ``size`` bytes (or the believed room), never an error."""
    codec = (codec or "none").lower()
    if codec == "none":
        if partial:
            return bytes(data[:size]) if size is not None else data
        if size is not None and len(data) != size:
            raise ValueError(f"{what} holds {len(data)} bytes, its header declares {size}")
        return data
    room = inflated_room(len(data))
    if partial:
        limit = room if size is None else min(int(size), room)
    else:
        limit = room if size is None else declared_size(
            path, f"{what} (uncompressed)", size, room, f"its {len(data)} bytes of {codec} data can hold at most")
    out: list[bytes] = []
    n = 0
    try:
        for piece in _pieces(codec, data, limit + 1):
            out.append(piece)
            n += len(piece)
    except Exception as err:  # noqa: BLE001 - each codec raises its own kind
        if not partial:
            raise ValueError(f"{what} does not decompress ({codec}: {one_line(err, 100)})") from err
    raw = b"".join(out)
    if partial:
        return raw[:limit]
    if n > limit:
        raise ValueError(f"{what} decompresses to more than the {fmt_bytes(limit)} "
                         f"{'its header declares' if size is not None else 'believed'}")
    if size is not None and n != size:
        raise ValueError(f"{what} decompresses to {n} bytes, its header declares {size}")
    return raw


# --------------------------------------------------------------------------------------------------
# .npy / .npz headers

def _npy_header(fp, path, what: str):
    """(shape, dtype, bytes the array needs) from the ``.npy`` header at ``fp``'s position; the header
    itself is read through a :class:`BoundedFile` (or a zip member stream, which is bounded)."""
    import numpy as np
    from numpy.lib import format as npf

    try:
        version = npf.read_magic(fp)
        if version == (1, 0):
            shape, _, dtype = npf.read_array_header_1_0(fp)
        elif version == (2, 0):
            shape, _, dtype = npf.read_array_header_2_0(fp)
        elif version == (3, 0) and hasattr(npf, "_read_array_header"):
            shape, _, dtype = npf._read_array_header(fp, version)
        else:
            raise ValueError(f"version {version} is not supported")
    except (ValueError, OSError, EOFError, SyntaxError, TypeError) as err:
        raise RecordingError(f"{path}: {what + ' is ' if what else ''}not a readable .npy array, truncated? "
                             f"({one_line(err, 100)})") from err
    n = int(np.prod(shape, dtype=object)) * dtype.itemsize
    return shape, dtype, n


def check_npy(path) -> None:
    """RecordingError naming ``path`` unless the array its ``.npy`` header declares fits in the bytes
    after the header (run before ``np.load``, which reserves the declared array first). A missing
    file is left to the caller."""
    path = Path(path)
    if not path.is_file():
        return
    with open_bounded(path) as f:
        shape, dtype, n = _npy_header(f, path, "")
        left = f.size - f.tell()
    declared_size(path, f".npy header: array {tuple(shape)} {dtype}", n, left, "the file holds after the header",
                  "truncated?")


def check_npz(path) -> None:
    """:func:`check_npy` for every ``.npy`` member of the ``.npz`` ``path`` (the member's uncompressed
    size, declared by the zip directory, also checked against its compressed bytes). Files that are
    not zip archives are left to ``np.load``'s own error."""
    import zipfile

    path = Path(path)
    if not path.is_file():
        return
    try:
        z = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError):
        return
    total = file_size(path)
    with z:
        for info in z.infolist():
            if not info.filename.endswith(".npy"):
                continue
            what = f"member {info.filename}"
            declared_size(path, f"{what} (compressed)", info.compress_size, total)
            room = info.compress_size if info.compress_type == zipfile.ZIP_STORED else inflated_room(info.compress_size)
            declared_size(path, f"{what} (uncompressed)", info.file_size, room,
                          f"its {info.compress_size} stored bytes can hold at most")
            try:
                fp = z.open(info)
            except (zipfile.BadZipFile, OSError, NotImplementedError, RuntimeError) as err:
                raise RecordingError(f"{path}: {what} unreadable ({one_line(err, 100)})") from err
            with fp:
                shape, dtype, n = _npy_header(fp, path, what)
                head = fp.tell() if hasattr(fp, "tell") else 0
            declared_size(path, f"{what}: array {tuple(shape)} {dtype}", n, info.file_size - head,
                          "the member holds after its header", "truncated?")


__all__ = ["MAX_RATIO", "BELIEVED", "declared_size", "inflated_room", "inflate", "BoundedFile", "open_bounded",
           "check_npy", "check_npz", "fmt_bytes", "file_size"]
