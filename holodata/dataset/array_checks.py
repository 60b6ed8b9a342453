"""Array checks of ``holodata validate`` beside the frame-array shard walk
(:mod:`holodata.dataset.validate`): whole arrays (mesh, calibration) against their sha256 and face
indices, plain zarr arrays holodata did not write (decodable, declared bytes capped against what their
chunks hold), ragged arrays (offsets, values width/dtype, each shard's rows against its commit record);
each read a chunk or a shard at a time, never whole. Also the shard bookkeeping the frame walk shares
with them: :class:`_Walk` (the shards the store lists a commit record of), :func:`_missing_shards`,
:func:`sh_json`, :func:`_metadata_line`.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass

import numpy as np

from . import shards as sh
from .bounded import READ_BYTES, Rows, is_int, read_offsets
from .info import stored_bytes
from .layout import CAMERA_POINTS, HUMAN_FACES, HUMAN_VERTICES, LIDAR_POINTS, MESH_FACES, MESH_VERTICES, spec

MAX_LINES_PER_RULE = 10
RAGGED_KNOWN = {LIDAR_POINTS: 3, CAMERA_POINTS: 3, HUMAN_VERTICES: 3, HUMAN_FACES: 3}
FOREIGN_RATIO = 1000           # arrays holodata did not write: declared bytes at most this x stored (+ 1 GiB)


@dataclass
class _Walk:
    """A frame or ragged array's shards to read: those the store lists a commit record of."""
    meta: dict
    S: int                       # frames per shard
    n: int                       # frames (a frame array's frame axis; n_frames for a ragged one)
    listed: list[int]            # shard indices with a manifest record, ascending (any index)
    frame_bytes: int = 0
    digest: str | None = None    # shards.meta_digest of the zarr.json now
    changed: int = 0             # shards whose record's meta digest differs


def _missing_shards(rep, sid: str, name: str, w: _Walk) -> list[int]:
    """Report the declared shards without a commit record (the first few by line, the rest counted,
    never one step per declared shard) and records past the declared ones; the shards to read."""
    n_decl = -(-w.n // w.S)
    ks = [k for k in w.listed if k < n_decl]
    beyond = len(w.listed) - len(ks)
    if beyond:
        rep.add(sid, name, None, "shape", f"{beyond} shard record(s) past the {n_decl} shards of {w.n} frames "
                                          f"(the frame axis in zarr.json shrunk?)")
    missing = n_decl - len(ks)
    if missing > MAX_LINES_PER_RULE:   # one line, counted: never a step per declared shard
        first = next(k for k in range(len(ks) + 1) if k >= len(ks) or ks[k] != k)
        rep.add(sid, name, first * w.S, "incomplete", f"{missing} of {n_decl} shards not written, the first shard "
                                                      f"{first} (frames from {first * w.S}): a half-written dataset "
                                                      f"(rerun the writer to resume), or a frame axis of {w.n} in "
                                                      f"zarr.json longer than what was written")
        return ks
    have, k = set(ks), 0
    while missing:
        if k not in have:
            rep.add(sid, name, k * w.S, "incomplete", f"shard {k} (frames {k * w.S}-{min((k + 1) * w.S, w.n) - 1}) "
                                                      f"not written (half-written dataset: rerun the writer to resume)")
            missing -= 1
        k += 1
    return ks


def sh_json(store, key):
    b = store.get(key)
    try:
        d = json.loads(b) if b is not None else {}
    except ValueError:
        return {}
    return d if isinstance(d, dict) else {}


def _metadata_line(rep, sid, name, n: int) -> None:
    rep.add(sid, name, None, "metadata", f"zarr.json differs from the metadata {n} shard(s) were written with "
                                         f"(data_type, codecs, fill_value or chunk grid edited?): the stored bytes "
                                         f"would decode to other values; not decoded")


def _check_small(ds, sid, name, meta, rep) -> None:
    """A whole array (mesh, calibration): its declared shape and dtype against the writer's record
    first, then read a chunk at a time into its sha256 (never whole)."""
    hd = meta.get("attributes", {}).get("holodata", {})
    shape, dtype = meta.get("shape"), meta.get("data_type")
    if "sha256" not in hd:
        rep.add(sid, name, None, "incomplete", "no checksum in attrs (write interrupted?)")
        return
    if str(hd.get("dtype")) != str(dtype) or list(hd.get("shape") or []) != list(shape or []):
        rep.add(sid, name, None, "dtype", f"metadata says {tuple(shape or ())} {dtype}, written as "
                                          f"{tuple(hd.get('shape') or ())} {hd.get('dtype')}; not read")
        return
    h = hashlib.sha256()
    lo = hi = None
    try:
        z = ds.zgroup[f"scenes/{sid}/{name}"]
        if z.ndim == 0:
            blocks = iter([np.asarray(z[...])])
        else:
            row = int(np.prod(z.shape[1:], dtype=np.int64)) * z.dtype.itemsize
            step = max(1, min(int(z.chunks[0]), READ_BYTES // max(1, row)))
            blocks = (np.asarray(z[i:i + step]) for i in range(0, z.shape[0], step))
        for a in blocks:
            a = np.ascontiguousarray(a)
            h.update(a.data if a.ndim else a.tobytes())
            rep.bytes_decoded += a.nbytes
            if name == MESH_FACES and a.size:
                lo = a.min() if lo is None else min(lo, a.min())
                hi = a.max() if hi is None else max(hi, a.max())
    except Exception as err:  # noqa: BLE001
        rep.add(sid, name, None, "decode", f"cannot be decoded ({err.__class__.__name__})")
        return
    if h.hexdigest() != hd["sha256"]:
        rep.add(sid, name, None, "checksum", "sha256 mismatch (corrupted)")
    if lo is not None and MESH_VERTICES in ds.scene(sid):
        nv = (ds.scene(sid).nodes()[MESH_VERTICES][1].get("shape") or [0])[0]
        if lo < 0 or hi >= nv:
            rep.add(sid, name, None, "mesh", f"face indices outside 0..{nv - 1}")


def _check_foreign(ds, sid, name, meta, rep) -> None:
    """A plain zarr array holodata did not write: decodable, in blocks; declared bytes capped against
    the bytes its chunks hold (no checksum to compare with)."""
    path = f"scenes/{sid}/{name}"
    try:
        shape = [int(v) for v in meta.get("shape") or []]
        declared = int(np.prod(shape, dtype=object)) * np.dtype(meta.get("data_type")).itemsize
    except (TypeError, ValueError):
        rep.add(sid, name, None, "decode", f"zarr.json declares shape {meta.get('shape')!r} "
                                           f"{meta.get('data_type')!r}: not an array")
        return
    stored = stored_bytes(ds.store, path, "zarr", meta)
    if declared > FOREIGN_RATIO * stored + (1 << 30):
        rep.add(sid, name, None, "shape", f"declares {declared} bytes, its chunks hold {stored} bytes; not read")
        return
    try:
        z = ds.zgroup[path]
        if z.ndim == 0:
            rep.bytes_decoded += np.asarray(z[...]).nbytes
            return
        row = int(np.prod(z.shape[1:], dtype=np.int64)) * z.dtype.itemsize
        step = max(1, min(int(z.chunks[0]) * 8, READ_BYTES // max(1, row)))
        for i in range(0, z.shape[0], step):
            rep.bytes_decoded += np.asarray(z[i:i + step]).nbytes
    except Exception as err:  # noqa: BLE001
        rep.add(sid, name, None, "decode", f"cannot be decoded ({err.__class__.__name__})")


@dataclass
class _Ragged:
    """A ragged array's metadata once its checks passed: ``path`` in the store, values zarr.json ``vm``
    (shape ``vshape``, dtype ``vdt``), offsets ``off`` (T+1,) and the indices ``dec`` where they
    decrease, the values' reader ``rows``, the metadata ``digest`` its shard records name
    (:func:`shards.ragged_meta_digest`), ``S`` frames per shard and ``T`` frames."""
    path: str
    vm: dict
    vshape: list
    vdt: np.dtype
    off: np.ndarray
    dec: np.ndarray
    rows: Rows
    digest: str
    S: int
    T: int


def _check_ragged(ds, sid, name, w: _Walk, T, rep, bar) -> None:
    """A ragged array: its values/offsets metadata and offsets (:func:`_ragged_head`), then every shard
    the store lists a commit record of (:func:`_check_ragged_shard`); ``bar`` advances a step per
    listed shard either way."""
    rg = _ragged_head(ds, sid, name, w, T, rep)
    if rg is None:
        for _ in w.listed:
            next(bar, None)
        return
    changed = 0
    ks = _missing_shards(rep, sid, name, w)
    skip_bar = len(w.listed) - len(ks)
    for _ in range(skip_bar):
        next(bar, None)
    for k in ks:
        next(bar, None)
        changed += _check_ragged_shard(ds, sid, name, k, rg, rep)
    if changed:
        _metadata_line(rep, sid, name, changed)


def _ragged_head(ds, sid, name, w: _Walk, T, rep) -> _Ragged | None:
    """Check a ragged array's values and offsets metadata against the layout and each other, then its
    offsets (start at 0, never decrease, end at the values' rows); None when its shards cannot be
    read (the problem reported)."""
    path = f"scenes/{sid}/{name}"
    hd = w.meta.get("attributes", {}).get("holodata", {})
    vm, om = sh_json(ds.store, f"{path}/values/zarr.json"), sh_json(ds.store, f"{path}/offsets/zarr.json")
    vshape = vm.get("shape")
    try:
        vdt = np.dtype(vm.get("data_type"))
        if not vm or not om or not isinstance(vshape, list) or not all(is_int(v) and v >= 0 for v in vshape):
            raise TypeError
    except TypeError:
        rep.add(sid, name, None, "decode", "values/offsets zarr.json missing or unreadable")
        return None
    width = hd.get("width")
    if len(vshape) != 2 or (width is not None and vshape[1] != width):
        rep.add(sid, name, None, "shape", f"values shape {tuple(vshape)}, expected (N, {width})")
        return None
    if name in RAGGED_KNOWN and vshape[1] != RAGGED_KNOWN[name]:
        rep.add(sid, name, None, "shape", f"values width {vshape[1]}, expected {RAGGED_KNOWN[name]}")
    s = spec(name)
    if s is not None and str(vdt) not in s.dtypes:
        rep.add(sid, name, None, "dtype", f"values dtype {vdt}, expected {' or '.join(s.dtypes)} (the layout)")
    if om.get("shape") != [T + 1] or om.get("data_type") != "int64":
        rep.add(sid, name, None, "offsets", f"offsets {tuple(om.get('shape') or ())} {om.get('data_type')}, "
                                            f"expected ({T + 1},) int64")
        return None
    try:
        off = read_offsets(ds, path, om, T)
    except Exception as err:  # noqa: BLE001
        why = f": {err}" if isinstance(err, ValueError) else ""
        rep.add(sid, name, None, "offsets", f"offsets cannot be read ({err.__class__.__name__}{why})")
        return None
    if off[0] != 0:
        rep.add(sid, name, 0, "offsets", f"offsets start at {off[0]}, not 0")
    dec = np.flatnonzero(np.diff(off) < 0)
    for i in dec[:MAX_LINES_PER_RULE]:
        rep.add(sid, name, int(i), "offsets", f"offsets decrease ({off[i]} -> {off[i + 1]})")
    rep.bump(sid, name, "offsets", len(dec) - MAX_LINES_PER_RULE)
    if off[-1] != vshape[0]:
        rep.add(sid, name, None, "offsets", f"offsets end at {off[-1]}, values has {vshape[0]} rows")
    return _Ragged(path, vm, vshape, vdt, off, dec, Rows(ds, f"{path}/values", vm), sh.ragged_meta_digest(vm, om),
                   w.S, T)


def _check_ragged_shard(ds, sid, name, k: int, rg: _Ragged, rep) -> bool:
    """Shard ``k`` of a ragged array against its commit record: written, with this metadata (True when
    the record names other metadata: counted into one line by the caller, not read), values dtype, rows
    the offsets give, then its values read into the sha256 (with the shard's offsets) and checked finite."""
    fr = slice(k * rg.S, min((k + 1) * rg.S, rg.T))
    rec = sh_json(ds.store, sh.manifest_key(rg.path, k)) or None
    rep.shards += 1
    if rec is None:
        rep.add(sid, name, fr.start, "incomplete", f"shard {k} (frames {fr.start}-{fr.stop - 1}) not written "
                                                   f"(half-written dataset: rerun the writer to resume)")
        return False
    if "meta_sha256" in rec and rec["meta_sha256"] != rg.digest:
        return True
    if "dtype" in rec and rec["dtype"] != str(rg.vdt):
        rep.add(sid, name, fr.start, "dtype", f"shard {k}: values written as {rec['dtype']}, zarr.json says {rg.vdt}")
        return False
    r0, r1 = int(rg.off[fr.start]), int(rg.off[fr.stop])
    if [r0, r1] != list(rec.get("rows", [])) or len(rg.dec) or r1 > rg.vshape[0]:
        rep.add(sid, name, fr.start, "offsets", f"shard {k}: offsets give rows {r0}..{r1}, "
                                                f"record says {rec.get('rows')}")
        return False
    h = hashlib.sha256()
    finite = True
    try:
        for v in rg.rows.read(r0, r1):
            h.update(v)
            rep.bytes_decoded += v.nbytes
            if finite and v.dtype.kind == "f" and not np.isfinite(v).all():
                finite = False
    except Exception as err:  # noqa: BLE001
        why = f": {err}" if isinstance(err, ValueError) else ""
        rep.add(sid, name, fr.start, "decode", f"shard {k} values cannot be decoded ({err.__class__.__name__}{why})")
        return False
    h.update(np.ascontiguousarray(rg.off[fr.start:fr.stop + 1], dtype="<i8").tobytes())   # writer.ragged_digest
    if h.hexdigest() != rec.get("sha256"):
        rep.add(sid, name, fr.start, "checksum", f"shard {k}: sha256 mismatch (corrupted values)")
    if not finite:
        rep.add(sid, name, fr.start, "ragged", f"shard {k}: values hold NaN/inf")
    return False
