"""The array writers of a scene: :class:`FrameArrayWriter` (made by :meth:`SceneWriter.frame_array
<holodata.dataset.writer.SceneWriter.frame_array>`) writes a frame array shard by shard, each shard whole
and atomic with its sha256 commit record; :class:`RaggedWriter` (made by ``SceneWriter.ragged_array``)
appends a ragged array's shards in order (values rows, offsets, then the record: :func:`ragged_digest`).
The commit protocol, resume and the record fields are in :mod:`holodata.dataset.writer`'s docstring.

They take the scene writer as a :class:`SceneLike` (what they use of it): the writer module imports this
one, so naming its class here would be an import cycle.
"""
from __future__ import annotations

import json
import math
from typing import Any, Protocol

import numpy as np

from ..errors import DatasetError
from . import shards as sh
from .store import Store

GRID_ARRAYS = ("radar/", "gt/")  # arrays shaped by the radar grid: a dataset holding any keeps its grid


class SceneLike(Protocol):
    """What the array writers use of a :class:`holodata.dataset.writer.SceneWriter`."""
    ds: Any        # its DatasetWriter: store, url, grid, range_bins, zstore
    id: str
    path: str
    n_frames: int


def _json(store: Store, key: str) -> Any:
    """``key``'s parsed JSON (a dict: zarr.json, a manifest record), None if there is no such key."""
    b = store.get(key)
    return None if b is None else json.loads(b)


class _Sharded:
    """Shard bookkeeping shared by frame and ragged arrays."""

    def _init_shards(self, sc: SceneLike, name: str, S: int):
        self.scene, self.name = sc, name
        self.store = sc.ds.store
        self.path = f"{sc.path}/{name}"
        self.n_frames = sc.n_frames
        self.shard_frames = S
        self.n_shards = math.ceil(self.n_frames / S)
        self._done = {int(n[:-5]) for n in self.store.list(f"{self.path}/{sh.MANIFEST_DIR}")
                      if n.endswith(".json") and n[:-5].isdigit()}
        if len(self._done) < self.n_shards:   # resuming: temp files of a writer killed mid-put go
            self.store.sweep_partials(self.path)

    def frames(self, k: int) -> slice:
        """Frame indices of shard ``k``."""
        if not 0 <= k < self.n_shards:
            raise DatasetError(f"scene {self.scene.id!r} array {self.name!r}: shard {k} out of range 0..{self.n_shards - 1}")
        return slice(k * self.shard_frames, min((k + 1) * self.shard_frames, self.n_frames))

    def is_done(self, k: int) -> bool:
        if k in self._done:
            return True
        if self.store.exists(sh.manifest_key(self.path, k)):
            self._done.add(k)
            return True
        return False

    @property
    def complete(self) -> bool:
        return all(self.is_done(k) for k in range(self.n_shards))

    def record(self, k: int) -> Any:
        """Shard ``k``'s manifest record (a dict), None while it is not written."""
        return _json(self.store, sh.manifest_key(self.path, k))

    def _consolidate(self) -> None:
        """All shards done: fold the manifest records into attrs (idempotent): the same
        read-modify-write of ``zarr.json`` that zarr's ``attrs.update`` does, as one atomic put without
        a round trip through zarr's event loop per array."""
        if not self.complete:
            return
        recs = [self.record(k) for k in range(self.n_shards)]
        shards = [{"sha256": r["sha256"], "nbytes": r.get("nbytes"), **({"rows": r["rows"]} if "rows" in r else {})}
                  for r in recs]
        key = f"{self.path}/zarr.json"
        meta = _json(self.store, key)
        if meta is None or not isinstance(meta.get("attributes"), dict):
            raise DatasetError(f"{self.scene.ds.url}: {key} is missing or has no attributes (damaged array metadata)")
        hd = dict(meta["attributes"].get("holodata", {}))
        hd["shards"] = shards
        meta["attributes"]["holodata"] = hd
        self.store.put(key, json.dumps(meta, indent=2).encode())


class FrameArrayWriter(_Sharded):
    def __init__(self, sc: SceneLike, name: str, meta: dict):
        self.meta = meta
        self.shape = tuple(meta["shape"])
        self.dtype = np.dtype(meta["data_type"])
        self._init_shards(sc, name, int(meta["attributes"]["holodata"]["shard_frames"]))
        # the arrays laid out on the radar grid record the grid (and range bins) they were written on
        self._grid_sha256 = sh.grid_digest(sc.ds.grid, sc.ds.range_bins) if name.startswith(GRID_ARRAYS) else None

    def write_shard(self, k: int, data) -> bool:
        """Write shard ``k`` whole: ``data`` (len(frames(k)),) + per-frame shape, or a list of
        len(frames(k)) per-frame arrays (no stacked copy). Atomic; a done shard is left untouched
        (returns False)."""
        sl = self.frames(k)
        if self.is_done(k):
            return False
        want = (sl.stop - sl.start,) + self.shape[1:]
        if isinstance(data, (list, tuple)):   # one array per frame: encoded frame by frame, never stacked
            frames = [np.asarray(f) for f in data]
            shapes = {f.shape for f in frames}
            dtypes = {f.dtype for f in frames}
            if len(frames) != want[0] or (frames and shapes != {want[1:]}):
                raise DatasetError(f"scene {self.scene.id!r} array {self.name!r} shard {k}: {len(frames)} frames of "
                                   f"shape(s) {sorted(shapes)}, expected {want}")
        else:
            data = np.asarray(data)
            if data.shape != want:
                raise DatasetError(f"scene {self.scene.id!r} array {self.name!r} shard {k}: data shape {data.shape}, "
                                   f"expected {want}")
            frames, dtypes = None, {data.dtype}
        for dt in dtypes:
            if dt != self.dtype and not np.can_cast(dt, self.dtype, casting="same_kind"):
                raise DatasetError(f"scene {self.scene.id!r} array {self.name!r} shard {k}: dtype {dt} "
                                   f"cannot be stored as {self.dtype}")
        blob = sh.encode_shard_parts(self.meta, [f.astype(self.dtype, copy=False) for f in frames]
                                     if frames is not None else data.astype(self.dtype, copy=False))
        self.store.put(sh.shard_key(self.path, k, len(self.shape)), blob)
        rec = sh.manifest_record(k, sl, blob, self.shape, self.dtype, meta=self.meta, grid=self._grid_sha256)
        self.store.put(sh.manifest_key(self.path, k), json.dumps(rec).encode())
        self._done.add(k)
        if len(self._done) == self.n_shards:
            self._consolidate()
        return True


def ragged_digest(values: np.ndarray, offsets: np.ndarray) -> str:
    """sha256 of a ragged shard: its rows' C-order bytes then its offsets (int64, len frames+1)."""
    import hashlib

    h = hashlib.sha256(np.ascontiguousarray(values).tobytes())
    h.update(np.ascontiguousarray(offsets, dtype="<i8").tobytes())
    return h.hexdigest()


class RaggedWriter(_Sharded):
    def __init__(self, sc: SceneLike, name: str, meta: dict):
        hd = meta["attributes"]["holodata"]
        self.width = int(hd["width"])
        vm = _json(sc.ds.store, f"{sc.path}/{name}/values/zarr.json")
        self.dtype = np.dtype(vm["data_type"])
        self._init_shards(sc, name, int(hd["shard_frames"]))

    def _put_rows(self, vmeta: dict, codec, r0: int, r1: int, vals: np.ndarray) -> None:
        """Store rows ``r0:r1`` of ``values`` chunk by chunk, as zarr would (edge chunks padded with
        the fill value; the chunk holding ``r0`` read back and completed), without zarr's per-chunk
        asyncio path: each chunk one Blosc encode (releases the GIL) and one atomic put."""
        rows = int(vmeta["chunk_grid"]["configuration"]["chunk_shape"][0])
        fill = vmeta.get("fill_value", 0)
        vals = np.ascontiguousarray(vals, dtype=self.dtype)
        for c in range(r0 // rows, (r1 - 1) // rows + 1):
            lo, hi = c * rows, (c + 1) * rows
            key = f"{self.path}/values/c/{c}/0"
            if lo >= r0 and hi <= r1:
                chunk = vals[lo - r0:hi - r0]
            else:
                chunk = np.full((rows, self.width), float(fill) if isinstance(fill, str) else fill, self.dtype)
                if lo < r0:
                    old = self.store.get(key)
                    if old is not None:
                        chunk[:r0 - lo] = np.frombuffer(codec.decode(old), self.dtype).reshape(rows, self.width)[:r0 - lo]
                a, b = max(lo, r0), min(hi, r1)
                chunk[a - lo:b - lo] = vals[a - r0:b - r0]
            self.store.put(key, codec.encode(chunk))

    def write_shard(self, k: int, per_frame: list) -> bool:
        """Append shard ``k``: a list of (Ni, width) arrays, one per frame of ``frames(k)``; shards
        go in order (0, 1, ...). A done shard is left untouched (returns False)."""
        import zarr

        sl = self.frames(k)
        if self.is_done(k):
            return False
        if k > 0 and not self.is_done(k - 1):
            raise DatasetError(f"scene {self.scene.id!r} ragged {self.name!r}: write shard {k - 1} before shard {k}")
        if len(per_frame) != sl.stop - sl.start:
            raise DatasetError(f"scene {self.scene.id!r} ragged {self.name!r} shard {k}: {len(per_frame)} frames, "
                               f"expected {sl.stop - sl.start}")
        parts = []
        for i, a in enumerate(per_frame):
            a = np.asarray(a)
            if a.ndim != 2 or a.shape[1] != self.width:
                if a.size == 0:
                    a = a.reshape(0, self.width)
                else:
                    raise DatasetError(f"scene {self.scene.id!r} ragged {self.name!r} frame {sl.start + i}: shape "
                                       f"{a.shape}, expected (N, {self.width})")
            if a.dtype != self.dtype and not np.can_cast(a.dtype, self.dtype, casting="same_kind"):
                raise DatasetError(f"scene {self.scene.id!r} ragged {self.name!r} frame {sl.start + i}: dtype "
                                   f"{a.dtype} cannot be stored as {self.dtype}")
            parts.append(a.astype(self.dtype, copy=False))
        lens = np.array([len(a) for a in parts], dtype=np.int64)
        r0 = int(self.record(k - 1)["rows"][1]) if k > 0 else 0
        r1 = r0 + int(lens.sum())
        vals = np.concatenate(parts, axis=0) if parts else np.zeros((0, self.width), self.dtype)
        zs = self.scene.ds.zstore
        vkey = f"{self.path}/values/zarr.json"
        vmeta = _json(self.store, vkey)
        codec = sh.chunk_codec(vmeta)
        fast = codec is not None and list(vmeta["chunk_grid"]["configuration"]["chunk_shape"])[1:] == [self.width]
        va = None
        if vmeta["shape"][0] != r1:
            if fast and r1 > vmeta["shape"][0]:   # growing is a metadata change only: one atomic put
                self.store.put(vkey, json.dumps({**vmeta, "shape": [r1, self.width]}, indent=2).encode())
            elif fast:   # shrinking (resume after a torn append): the chunks past the end go, as zarr's resize
                rows = int(vmeta["chunk_grid"]["configuration"]["chunk_shape"][0])
                self.store.put(vkey, json.dumps({**vmeta, "shape": [r1, self.width]}, indent=2).encode())
                for c in range(-(-r1 // rows), -(-int(vmeta["shape"][0]) // rows)):
                    self.store.delete(f"{self.path}/values/c/{c}/0")
            else:
                va = zarr.open_array(zs, path=f"{self.path}/values", mode="r+")
                va.resize((r1, self.width))   # shrinking (resume after a torn append): zarr drops chunks
        if r1 > r0:
            if fast:
                self._put_rows(vmeta, codec, r0, r1, vals)
            else:
                va = va or zarr.open_array(zs, path=f"{self.path}/values", mode="r+")
                va[r0:r1] = vals
        seg = r0 + np.concatenate([[0], np.cumsum(lens)])
        okey = f"{self.path}/offsets/c/0"
        ometa = _json(self.store, f"{self.path}/offsets/zarr.json")
        ocodec = sh.chunk_codec(ometa)
        oa = None
        if ocodec is not None and ometa["chunk_grid"]["configuration"]["chunk_shape"] == ometa["shape"]:
            old = self.store.get(okey)
            off = np.zeros(self.n_frames + 1, "<i8") if old is None else \
                np.frombuffer(ocodec.decode(old), "<i8").copy()
        else:
            oa = zarr.open_array(zs, path=f"{self.path}/offsets", mode="r+")
            off = np.asarray(oa[...])
        off[sl.start:sl.stop + 1] = seg
        off[sl.stop + 1:] = 0
        if oa is None:
            self.store.put(okey, ocodec.encode(off))   # one chunk: one atomic put
        else:
            oa[...] = off
        rec = {"shard": k, "frames": [sl.start, sl.stop], "rows": [r0, r1], "sha256": ragged_digest(vals, seg),
               "nbytes": int(vals.nbytes), "shape": [r1, self.width], "dtype": str(self.dtype),
               "meta_sha256": sh.ragged_meta_digest(vmeta, ometa)}
        self.store.put(sh.manifest_key(self.path, k), json.dumps(rec).encode())
        self._done.add(k)
        if len(self._done) == self.n_shards:
            self._consolidate()
        return True
