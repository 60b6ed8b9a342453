"""Shard bytes: encode one whole shard in memory (so it can be put atomically and hashed), decode
one shard read as bytes, and the per-shard manifest records.

Fast path (every array holodata writes): chunk = one frame, codecs ``bytes`` (little endian) +
``blosc``, index codecs ``bytes`` + ``crc32c`` at the end. The shard object is then assembled here
per the Zarr v3 sharding spec: the frames' Blosc-compressed chunks concatenated in chunk order,
then the index (``(offset, nbytes)`` uint64 little-endian per chunk of the shard grid, C order;
``2**64-1`` twice for a chunk past the end of a partial last shard) and its crc32c (uint32 LE).
This is byte-for-byte what zarr-python writes (tests/dataset/test_writer.py checks it) but several
times faster: zarr's sharding encoder runs every chunk through asyncio and copies (the numbers are in
docs/design/performance.md). Blosc and crc32c release the GIL, so shards encode in parallel threads.

Any other codec layout goes through a scratch zarr array in a ``MemoryStore`` that has the target
array's exact metadata (codecs, chunk and shard shape) but a frame axis of the shard's length; its
single shard object is what zarr would store at ``c/k/0/...`` of the real array. Decoding goes
the other way, so ``validate`` reads every shard object exactly once (checksum + decode).
"""
from __future__ import annotations

import hashlib
import json
from typing import Any

import numpy as np

MANIFEST_DIR = "manifest"  # <array>/manifest/<k>.json: the commit record of shard k


def shard_key(array_path: str, k: int, ndim: int) -> str:
    return f"{array_path}/c/{k}" + "/0" * (ndim - 1)


def manifest_key(array_path: str, k: int) -> str:
    return f"{array_path}/{MANIFEST_DIR}/{k}.json"


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _scratch(meta: dict, n: int):
    import zarr
    from zarr.core.buffer.cpu import Buffer

    m = dict(meta)
    m["shape"] = [n] + list(meta["shape"][1:])
    m["attributes"] = {}
    ms = zarr.storage.MemoryStore()
    ms._store_dict["zarr.json"] = Buffer.from_bytes(json.dumps(m).encode())
    return ms, zarr.open_array(ms, mode="r+", config={"write_empty_chunks": True})


_EMPTY = np.uint64(2**64 - 1)


def _fast_layout(meta: dict):
    """(numcodecs Blosc, chunks per shard, per-frame shape) when ``meta`` is the layout the fast
    path handles (see module docstring), else None."""
    try:
        (sc,) = meta["codecs"]
        if sc["name"] != "sharding_indexed":
            return None
        cfg = sc["configuration"]
        inner, index = cfg["codecs"], cfg["index_codecs"]
        if cfg.get("index_location", "end") != "end" or len(inner) != 2 or len(index) != 2:
            return None
        if index[0]["name"] != "bytes" or (index[0].get("configuration") or {}).get("endian", "little") != "little" \
                or index[1]["name"] != "crc32c":
            return None
        chunk = [int(c) for c in cfg["chunk_shape"]]
        shard = [int(c) for c in meta["chunk_grid"]["configuration"]["chunk_shape"]]
        shape = [int(c) for c in meta["shape"]]
        if chunk[0] != 1 or chunk[1:] != shape[1:] or shard[1:] != shape[1:]:
            return None
        codec = _blosc(inner)
        if codec is None:
            return None
        return codec, shard[0], tuple(shape[1:])
    except (KeyError, TypeError, ValueError):
        return None


def _blosc(inner: list):
    """numcodecs Blosc for a codec list ``[bytes (little endian), blosc]``, else None."""
    if len(inner) != 2 or inner[0]["name"] != "bytes" or inner[1]["name"] != "blosc" \
            or (inner[0].get("configuration") or {}).get("endian", "little") != "little":
        return None
    from numcodecs import Blosc

    b = inner[1]["configuration"]
    shuffle = {"noshuffle": 0, "shuffle": 1, "bitshuffle": 2}[b.get("shuffle", "noshuffle")]
    return Blosc(cname=b["cname"], clevel=int(b["clevel"]), shuffle=shuffle, blocksize=int(b.get("blocksize", 0)),
                 typesize=int(b["typesize"]))


def chunk_codec(meta: dict):
    """numcodecs Blosc that writes the chunks of an unsharded array whose codecs are ``bytes`` +
    ``blosc`` (ragged ``values``), else None (then write through zarr)."""
    try:
        if meta.get("chunk_key_encoding", {}).get("name") != "default" or \
                (meta["chunk_key_encoding"].get("configuration") or {}).get("separator", "/") != "/":
            return None
        return _blosc(meta["codecs"])
    except (KeyError, TypeError, ValueError):
        return None


def _crc32c(b) -> int:
    import google_crc32c

    return google_crc32c.value(b)


def encode_shard(meta: dict, data: np.ndarray) -> bytes:
    """Bytes of the shard object holding ``data`` (frames of one shard: an array, or a list of
    per-frame arrays) for an array with zarr metadata ``meta`` (the parsed ``zarr.json``)."""
    parts = encode_shard_parts(meta, data)
    return parts[0] if len(parts) == 1 else b"".join(parts)


def encode_shard_parts(meta: dict, data) -> list:
    """:func:`encode_shard` as a list of byte strings whose concatenation is the shard object
    (written and hashed part by part: no joined copy of a large shard)."""
    fast = _fast_layout(meta)
    dt = np.dtype(meta["data_type"])
    frames = data if isinstance(data, (list, tuple)) else None
    if fast is not None and all(f.dtype == dt and f.dtype.byteorder in ("<", "=", "|") for f in (frames or [data])):
        codec, S, _ = fast
        n = len(frames) if frames is not None else data.shape[0]
        if n > S:
            raise ValueError(f"{n} frames do not fit a shard of {S}")
        parts = [codec.encode(np.ascontiguousarray(f)) for f in (frames if frames is not None else data)]
        index = np.full((S, 2), _EMPTY, dtype="<u8")
        sizes = np.array([len(p) for p in parts], dtype=np.uint64)
        index[:len(parts), 1] = sizes
        index[:len(parts), 0] = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.uint64) if parts else []
        ib = index.tobytes()
        return parts + [ib + _crc32c(ib).to_bytes(4, "little")]
    return [_encode_shard_zarr(meta, np.stack(frames) if frames is not None else data)]


def _encode_shard_zarr(meta: dict, data: np.ndarray) -> bytes:
    import zarr

    with zarr.config.set({"array.write_empty_chunks": True}):  # every chunk stored: a shard always exists
        ms, a = _scratch(meta, data.shape[0])
        a[...] = data
    return ms._store_dict[shard_key("", 0, data.ndim).lstrip("/")].to_bytes()


def _index(tail, S: int, size: int) -> np.ndarray:
    """(S, 2) offsets/sizes of a shard object of ``size`` bytes from its last ``16·S + 4`` bytes
    ``tail`` (the index and its crc32c); ValueError on a damaged index (too short, bad crc32c, a
    chunk outside the object)."""
    ilen = 16 * S + 4
    if size < ilen or len(tail) != ilen:
        raise ValueError(f"shard object of {size} bytes is shorter than its index ({ilen} bytes)")
    ib = bytes(tail[:-4])
    if _crc32c(ib) != int.from_bytes(tail[-4:], "little"):
        raise ValueError("shard index crc32c does not match")
    index = np.frombuffer(ib, dtype="<u8").reshape(S, 2)
    full = index[:, 0] != _EMPTY
    end = size - ilen
    if np.any(full & ((index[:, 0] > end) | (index[:, 1] > end - np.minimum(index[:, 0], end)))):
        raise ValueError("shard index points outside the shard object")
    return index


def _fill(meta: dict):
    """The fill value of ``meta`` as a number; None for a hex-encoded float fill (zarr parses it)."""
    fill = meta.get("fill_value", 0)
    if isinstance(fill, str):
        try:
            return float(fill)   # "NaN", "Infinity", "-Infinity"
        except ValueError:
            return None
    return fill


def _fast_chunks(meta: dict, n: int, blob: bytes | memoryview) -> tuple[Any, Any, np.dtype, Any, np.ndarray] | None:
    """(codec, per-frame shape, dtype, fill, (n, 2) offsets/sizes) of a fast-layout shard, or None;
    raises ValueError on a damaged index (bad crc32c, chunk outside the object)."""
    fast = _fast_layout(meta)
    if fast is None:
        return None
    codec, S, per = fast
    blob = memoryview(blob)
    index = _index(blob[max(len(blob) - (16 * S + 4), 0):], S, len(blob))[:n]
    fill = _fill(meta)
    if fill is None:
        return None
    return codec, per, np.dtype(meta["data_type"]), fill, index


def blosc_sizes(chunk) -> tuple[int, int] | None:
    """(uncompressed, compressed) bytes a Blosc chunk's header states (bytes 4-8 and 12-16, uint32
    LE), None when it is too short to hold a header."""
    if len(chunk) < 16:
        return None
    mv = memoryview(chunk)
    return int.from_bytes(mv[4:8], "little"), int.from_bytes(mv[12:16], "little")


def _check_chunk(chunk, want: int, nb: int, i: int) -> None:
    """ValueError unless chunk ``i`` (``nb`` bytes stored) is a Blosc chunk of ``want`` bytes."""
    if len(chunk) != nb or blosc_sizes(chunk) != (want, nb):
        raise ValueError(f"chunk {i} of the shard is damaged (Blosc header does not match its size: "
                         f"{want} bytes a frame declared)")


def _decode_frames(codec, per, dt, fill, index, blob, start: int, stop: int) -> np.ndarray:
    """Frames ``start:stop`` of a fast-layout shard. Every chunk's Blosc header is checked against the
    frame size the metadata declares before anything is allocated: metadata declaring larger frames
    than the chunks hold raises ValueError instead of allocating what it declares."""
    want = int(np.prod(per, dtype=np.int64)) * dt.itemsize
    mv = memoryview(blob)
    for i in range(start, stop):
        if index[i, 0] != _EMPTY:
            _check_chunk(mv[int(index[i, 0]):int(index[i, 0]) + int(index[i, 1])], want, int(index[i, 1]), i)
    out = np.empty((stop - start,) + per, dt)
    flat = out.reshape(stop - start, -1)
    for i in range(start, stop):
        if index[i, 0] == _EMPTY:
            flat[i - start] = fill
            continue
        o, nb = int(index[i, 0]), int(index[i, 1])
        codec.decode(mv[o:o + nb], out=flat[i - start])
    return out


def read_frame(store, array_path: str, meta: dict, k: int, index_cache: dict | None = None) -> np.ndarray | None:
    """Frame ``k`` of a fast-layout frame array (module docstring) read straight from its shard:
    the shard's index (its last ``16·S + 4`` bytes, crc32c checked; kept in ``index_cache`` by shard
    key) and the one chunk, Blosc-decoded into the result. The loader's path: zarr's reads of
    a 64×512×256 heatmap go through asyncio and a copy (benchmarks/loader.py has both).
    None when the layout is not the fast one (read through zarr then). A frame of an absent shard
    or chunk is the fill value, as zarr reads it; a damaged shard raises ValueError."""
    fast = _fast_layout(meta)
    fill = _fill(meta)
    if fast is None or fill is None:
        return None
    codec, S, per = fast
    dt = np.dtype(meta["data_type"])
    s, i = divmod(int(k), S)
    key = shard_key(array_path, s, len(meta["shape"]))
    cache = index_cache if index_cache is not None else {}
    if key not in cache:
        try:
            size = store.size(key)
        except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
            size = None
        try:
            cache[key] = None if size is None else _index(store.get_range(key, max(size - (16 * S + 4), 0), size),
                                                          S, size)
        except ValueError as err:
            raise ValueError(f"{key}: {err}") from None
    index = cache[key]
    if index is None or index[i, 0] == _EMPTY:
        return np.full(per, fill, dt)
    o, nb = int(index[i, 0]), int(index[i, 1])
    chunk = store.get_range(key, o, o + nb)
    try:
        _check_chunk(chunk, int(np.prod(per, dtype=np.int64)) * dt.itemsize, nb, i)
    except ValueError as err:
        raise ValueError(f"{key}: {err}") from None
    out = np.empty(per, dt)
    codec.decode(chunk, out=out.reshape(-1))
    return out


def decode_shard(meta: dict, n: int, blob: bytes) -> np.ndarray:
    """Inverse of :func:`encode_shard`: ``(n,) + per-frame shape`` array. Raises on corrupt bytes."""
    from zarr.core.buffer.cpu import Buffer

    fast = _fast_chunks(meta, n, blob)
    if fast is not None:
        return _decode_frames(*fast, blob, 0, n)

    ms, a = _scratch(meta, n)
    ms._store_dict[shard_key("", 0, len(meta["shape"])).lstrip("/")] = Buffer.from_bytes(blob)
    return a[...]


def decode_shard_blocks(meta: dict, n: int, blob: bytes, block: int):
    """Like :func:`decode_shard` but yields ``(start, frames[start:start+block])`` so a large shard
    (e.g. radar heatmaps) is never decoded whole."""
    from zarr.core.buffer.cpu import Buffer

    fast = _fast_chunks(meta, n, blob)
    if fast is not None:
        for i in range(0, n, block):
            yield i, _decode_frames(*fast, blob, i, min(n, i + block))
        return
    ms, a = _scratch(meta, n)
    ms._store_dict[shard_key("", 0, len(meta["shape"])).lstrip("/")] = Buffer.from_bytes(blob)
    for i in range(0, n, block):
        yield i, a[i:i + block]


def manifest_record(k: int, frames: slice, blob, shape: tuple, dtype, meta: dict | None = None,
                    grid: str | None = None) -> dict:
    """Commit record of shard ``k``; ``blob``: the shard object's bytes or its parts in order.
    ``meta``: the array's parsed ``zarr.json`` (its :func:`meta_digest` is recorded as ``meta_sha256``);
    ``grid``: the dataset's :func:`grid_digest` (``grid_sha256``), for the arrays shaped by the grid."""
    parts = blob if isinstance(blob, (list, tuple)) else [blob]
    h = hashlib.sha256()
    for b in parts:
        h.update(b)
    rec = {"shard": k, "frames": [frames.start, frames.stop], "sha256": h.hexdigest(),
           "nbytes": sum(len(b) for b in parts), "shape": list(shape), "dtype": str(np.dtype(dtype))}
    if meta is not None:
        rec["meta_sha256"] = meta_digest(meta)
    if grid is not None:
        rec["grid_sha256"] = grid
    return rec


# The zarr.json fields that decide what a stored chunk decodes to (the dtype, the chunk grid, the codecs
# and their settings, the fill value of absent chunks); ``attributes`` and ``dimension_names`` do not.
VALUE_FIELDS = ("zarr_format", "node_type", "data_type", "chunk_grid", "chunk_key_encoding", "fill_value", "codecs",
                "storage_transformers")


def value_fields(meta: dict, rows_grow: bool = False) -> dict:
    """The :data:`VALUE_FIELDS` and the shape of a parsed ``zarr.json``; ``rows_grow``: an array whose
    first axis grows by appends (ragged ``values``): its length is left out (the records' rows say it)."""
    shape = list(meta.get("shape") or [])
    return {**{k: meta.get(k) for k in VALUE_FIELDS}, "shape": shape[1:] if rows_grow else shape}


def _digest(obj) -> str:
    return sha256(json.dumps(obj, sort_keys=True, separators=(",", ":")).encode())


def meta_digest(meta: dict) -> str:
    """sha256 of a frame array's value fields (:func:`value_fields`), canonical JSON: recorded beside
    each shard's checksum, so that an edit of its dtype, codecs, fill value or chunks is found."""
    return _digest(value_fields(meta))


def ragged_meta_digest(values_meta: dict, offsets_meta: dict) -> str:
    """:func:`meta_digest` of a ragged array: its ``values`` (without their growing length) and ``offsets``."""
    return _digest({"values": value_fields(values_meta, rows_grow=True), "offsets": value_fields(offsets_meta)})


def grid_digest(grid, range_bins) -> str:
    """sha256 of the dataset's beam grid and range bins (H, W, elevation limits; n, dr): what the
    radar and gt arrays' values are laid out on, recorded beside their shard checksums."""
    return _digest({"H": int(grid.H), "W": int(grid.W),
                    "elev_deg": [float(grid.elev_max_deg), float(grid.elev_min_deg)],
                    "n": int(range_bins.n), "dr": float(range_bins.dr)})


def compressor(codec: str = "zstd", clevel: int | None = None):
    """zarr v3 Blosc codec with byte shuffle: ``codec`` 'zstd' (default, clevel 3) or 'lz4' (clevel 5)."""
    from zarr.codecs import BloscCodec

    if codec not in ("zstd", "lz4", "lz4hc", "zlib", "blosclz"):
        from ..errors import DatasetError

        raise DatasetError(f"unknown codec {codec!r} (use zstd or lz4)")
    level = clevel if clevel is not None else (3 if codec == "zstd" else 5)
    return BloscCodec(cname=codec, clevel=level, shuffle="shuffle")  # type: ignore[arg-type]  # a checked name
