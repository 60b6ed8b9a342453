"""Shard bytes: encode one whole shard in memory (so it can be put atomically and hashed), decode
one shard read as bytes, and the per-shard manifest records.

A shard is encoded by a scratch zarr array in a ``MemoryStore`` that has the target array's exact
metadata (codecs, chunk and shard shape) but a frame axis of the shard's length; its single shard
object is byte-for-byte what zarr would store at ``c/k/0/...`` of the real array. Decoding goes
the other way, so ``validate`` reads every shard object exactly once (checksum + decode).
"""
from __future__ import annotations

import hashlib
import json

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


def encode_shard(meta: dict, data: np.ndarray) -> bytes:
    """Bytes of the shard object holding ``data`` (frames of one shard) for an array with zarr
    metadata ``meta`` (the parsed ``zarr.json``)."""
    import zarr

    with zarr.config.set({"array.write_empty_chunks": True}):  # every chunk stored: a shard always exists
        ms, a = _scratch(meta, data.shape[0])
        a[...] = data
    return ms._store_dict[shard_key("", 0, data.ndim).lstrip("/")].to_bytes()


def decode_shard(meta: dict, n: int, blob: bytes) -> np.ndarray:
    """Inverse of :func:`encode_shard`: ``(n,) + per-frame shape`` array. Raises on corrupt bytes."""
    from zarr.core.buffer.cpu import Buffer

    ms, a = _scratch(meta, n)
    ms._store_dict[shard_key("", 0, len(meta["shape"])).lstrip("/")] = Buffer.from_bytes(blob)
    return a[...]


def decode_shard_blocks(meta: dict, n: int, blob: bytes, block: int):
    """Like :func:`decode_shard` but yields ``(start, frames[start:start+block])`` so a large shard
    (e.g. radar heatmaps) is never decoded whole."""
    from zarr.core.buffer.cpu import Buffer

    ms, a = _scratch(meta, n)
    ms._store_dict[shard_key("", 0, len(meta["shape"])).lstrip("/")] = Buffer.from_bytes(blob)
    for i in range(0, n, block):
        yield i, a[i:i + block]


def manifest_record(k: int, frames: slice, blob: bytes, shape: tuple, dtype) -> dict:
    return {"shard": k, "frames": [frames.start, frames.stop], "sha256": sha256(blob), "nbytes": len(blob),
            "shape": list(shape), "dtype": str(np.dtype(dtype))}


def compressor(codec: str = "zstd", clevel: int | None = None):
    """zarr v3 Blosc codec with byte shuffle: ``codec`` 'zstd' (default, clevel 3) or 'lz4' (clevel 5)."""
    from zarr.codecs import BloscCodec

    if codec not in ("zstd", "lz4", "lz4hc", "zlib", "blosclz"):
        from ..errors import DatasetError

        raise DatasetError(f"unknown codec {codec!r} (use zstd or lz4)")
    level = clevel if clevel is not None else (3 if codec == "zstd" else 5)
    return BloscCodec(cname=codec, clevel=level, shuffle="shuffle")
