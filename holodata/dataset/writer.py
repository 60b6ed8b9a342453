"""Dataset writer: whole shards, written atomically, with a sha256 commit record per shard; resume.

Commit protocol of a frame array shard ``k`` (docs/format.md §3):
1. encode the whole shard in memory (:func:`shards.encode_shard`), put it under ``c/k/0/...`` in
   one atomic step (temp file + rename locally; one PUT on object stores);
2. put ``<array>/manifest/<k>.json`` = {shard, frames, sha256, nbytes, shape, dtype, meta_sha256
   (of the zarr.json fields that decide the decoded values: :func:`shards.meta_digest`), and for the
   ``radar/`` and ``gt/`` arrays grid_sha256 (the dataset's grid and range bins: :func:`shards.grid_digest`)}.
A shard is *done* iff its manifest record exists; a killed writer leaves at most an uncommitted
shard object, which the rerun rewrites. Done shards are never rewritten. Per-shard records (not
one attribute rewritten per shard) keep concurrent shard writers (Dask workers) from losing each
other's records; once every shard of an array is done, the records are also folded into the
array's ``attrs["holodata"]["shards"]`` (one atomic ``zarr.json`` rewrite, idempotent).

Ragged arrays (``lidar/points``, ``camera/points``, ``human/vertices`` ...): a group holding
``values`` (N, width) and ``offsets`` (T+1,) int64, frame ``i`` = ``values[offsets[i]:offsets[i+1]]``;
``offsets[0] = 0`` and ``offsets[T] = N``. Shards (same frame grouping) are appended in order:
resize + write the new rows, rewrite ``offsets`` (one chunk), then the manifest record
{rows: [r0, r1], sha256 of the rows' bytes + their offsets, dtype, meta_sha256 of values' and offsets'
zarr.json (:func:`shards.ragged_meta_digest`)}. Readers trust only committed shards. The two array
writers are in :mod:`holodata.dataset.array_writers`.

Unfinished stages (docs/format.md §3, "Unfinished scenes"): every command that writes a scene marks it
unfinished before its first write and finished after its last, in the scene attribute ``unfinished``
= {stage: {since, rerun}} (:meth:`SceneWriter.begin` / :meth:`SceneWriter.finish`, or
:meth:`SceneWriter.stage`; a command writing the dataset root too, e.g. its splits, marks the root
attribute ``holodata.unfinished`` the same way). ``validate`` rejects a marked scene and names the
stage; the stage's rerun resumes and clears its mark, other stages refuse the scene until then. Every
write of this module, the marks included, is one atomic :meth:`Store.put` (or a delete): scene and
root attributes are rewritten as a whole ``zarr.json`` (read-modify-write), never through zarr's
in-place writes, so a writer killed at any point leaves the store exactly as its completed puts made it.
"""
from __future__ import annotations

import json
import math
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from ..conventions import FORMAT_VERSION, Grid, RangeBins
from ..errors import DatasetError
from . import shards as sh
from .array_writers import (
    GRID_ARRAYS,
    FrameArrayWriter,
    RaggedWriter,
    _json,
    ragged_digest,  # noqa: F401 - re-exported
)
from .store import Store

DEFAULT_SHARD_FRAMES = 32
RAGGED_CHUNK_BYTES = 1 << 20
SMALL_CHUNK_BYTES = 8 << 20


@dataclass(frozen=True)
class FrameStorage:
    """How a new frame array's shards are stored (:meth:`SceneWriter.frame_array`): ``shard_frames``
    frames per shard (None: the dataset's) and ``codec``, the shards' compressor (None: the dataset's
    codec at its level; a named codec at that codec's own default level)."""

    shard_frames: int | None = None
    codec: str | None = None


def _layout_facts(name: str, dims=None, units=None, dtype=None, fill=None) -> tuple:
    """(dims, units, dtype, fill) of array ``name``: the caller's where given (a test writing an
    array off the layout, an array the layout does not know), else the layout's
    (:mod:`holodata.dataset.layout`: the one place they are stated); for an array the layout does
    not know dims None, units "1", dtype None and fill None (the writers' own defaults)."""
    from .layout import spec

    s = spec(name)
    if s is None:
        return dims, units if units is not None else "1", dtype, fill
    dtype = s.dtype if dtype is None else dtype
    if fill is None:   # NaN is the float arrays' "no data"; an integer dtype (a uint8 heatmap's codes) has 0
        fill = 0 if isinstance(s.fill, float) and s.fill != s.fill and np.dtype(dtype).kind in "iu" else s.fill
    return (list(s.dims) if dims is None else dims, s.units if units is None else units, dtype, fill)


def _fresh_node(store: Store, path: str) -> None:
    """Remove what a killed writer left at ``path`` before the node's ``zarr.json`` (what zarr's
    ``mode="w"`` / ``overwrite=True`` do), but only what holodata can prove it wrote: Zarr node
    objects (``zarr.json``, chunks under ``c/``), shard records (``manifest/``) and put temps
    (``.*.partial``), no symlink among them. Anything else (a user's folder that shares a scene's
    name) is one :class:`DatasetError` line, and stays."""
    if not store.is_dir(path):
        return
    files, links = store.walk(path)
    foreign = links or [f for f in files if not _node_object(f)]
    if foreign:
        raise DatasetError(f"{store.url}: {path} holds {foreign[0]!r}, which holodata did not write; it will not "
                           f"delete it (move it out of the dataset, or choose another scene id)")
    store.delete_tree(path)


def _node_object(rel: str) -> bool:
    """``rel`` (a path under a node's folder) is an object a holodata writer puts there."""
    parts = rel.split("/")
    name = parts[-1]
    if name.startswith(".") and name.endswith(".partial"):
        return True
    if name == "zarr.json":
        return True
    if "c" in parts[:-1]:                               # chunk / shard objects: c/<i>/<j>...
        return all(p.isdigit() for p in parts[parts.index("c") + 1:])
    return len(parts) >= 2 and parts[-2] == sh.MANIFEST_DIR and name.endswith(".json")


def _put_group(store: Store, path: str, attributes: dict) -> None:
    """A new group's ``zarr.json`` (Zarr v3: node_type group + attributes), one atomic put
    (``path`` "": the root group)."""
    store.put(f"{path}/zarr.json" if path else "zarr.json",
              json.dumps({"attributes": attributes, "zarr_format": 3, "node_type": "group"}, indent=2).encode())


def _update_group_attrs(store: Store, key: str, update, url: str) -> dict:
    """Rewrite the group metadata ``key`` (a ``zarr.json``) with its attributes passed through
    ``update`` (dict -> new dict): one read and one atomic put of the whole document. Returns the new
    attributes."""
    meta = _json(store, key)
    if meta is None or not isinstance(meta.get("attributes", {}), dict):
        raise DatasetError(f"{url}: {key} is missing or has no attributes (damaged group metadata)")
    attrs = update(dict(meta.get("attributes") or {}))
    meta["attributes"] = attrs
    store.put(key, json.dumps(meta, indent=2).encode())
    return attrs


UNFINISHED = "unfinished"   # scene attribute / root ``holodata`` key: {stage: {since, rerun}}


def unfinished_mark(stage: str, rerun: str | None = None) -> dict:
    """The record of stage ``stage`` in an ``unfinished`` attribute: when it started (UTC) and what
    finishes it (``rerun``; default "rerun holodata <stage>")."""
    return {"since": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "rerun": rerun or f"rerun holodata {stage}"}


def _with_mark(attrs: dict, stage: str, rerun: str | None) -> dict:
    marks = dict(attrs.get(UNFINISHED) or {})
    marks[stage] = unfinished_mark(stage, rerun)
    return {**attrs, UNFINISHED: marks}


def _without_mark(attrs: dict, stage: str) -> dict:
    marks = {k: v for k, v in (attrs.get(UNFINISHED) or {}).items() if k != stage}
    out = {k: v for k, v in attrs.items() if k != UNFINISHED}
    if marks:
        out[UNFINISHED] = marks
    return out


def _put_array(store: Store, path: str, **kw) -> None:
    """A new array's ``zarr.json``: made by ``zarr.create_array`` in a MemoryStore (zarr writes the
    metadata) and put with one atomic write. Creating it on the dataset's store directly costs more
    (directory deletes and checks through zarr's event loop, per array of every scene;
    benchmarks/results/ingest.md)."""
    import zarr

    ms = zarr.storage.MemoryStore()
    zarr.create_array(ms, name="a", **kw)
    store.put(f"{path}/zarr.json", ms._store_dict["a/zarr.json"].to_bytes())


def _put_small_array(store: Store, path: str, data: np.ndarray, **kw) -> None:
    """A whole small array: encoded by zarr into a MemoryStore (its chunks and ``zarr.json``, the
    ``holodata`` checksum attributes included), then put object by object, chunks first and the
    metadata last (an array without its ``zarr.json`` is no node: readers skip it). What
    ``zarr.create_array`` + ``a[...] = data`` + ``attrs.update`` write, through atomic puts."""
    import zarr

    ms = zarr.storage.MemoryStore()
    a = zarr.create_array(ms, name="a", **kw)
    if data.size:
        a[...] = data
    objs = {k[2:]: v.to_bytes() for k, v in ms._store_dict.items() if k.startswith("a/")}
    _fresh_node(store, path)
    for k, b in sorted(objs.items()):
        if k != "zarr.json":
            store.put(f"{path}/{k}", b)
    store.put(f"{path}/zarr.json", objs["zarr.json"])


def create_dataset(url, grid: Grid | None = None, range_bins: RangeBins | None = None,
                   created_by: str = "holodata", provenance: dict | None = None,
                   shard_frames: int = DEFAULT_SHARD_FRAMES, codec: str = "zstd", clevel: int | None = None
                   ) -> DatasetWriter:
    """Create a dataset at ``url`` (local path or fsspec URL), or reopen it for resuming.

    ``grid=None``: no radar grid is known yet (a LiDAR-only dataset): the root records the conventions'
    default grid with ``grid_source: "default"``, and the first writer that gives a grid while no
    scene holds radar or gt arrays replaces it. Otherwise reopening needs the same grid and range
    bins (else :class:`DatasetError`), and ``grid=None`` takes the dataset's. ``shard_frames`` and
    ``codec`` apply to arrays created from now on (existing arrays keep theirs)."""
    return DatasetWriter(url, grid, range_bins, created_by, provenance or {}, shard_frames, codec, clevel)


class DatasetWriter:
    def __init__(self, url, grid, range_bins, created_by, provenance, shard_frames, codec, clevel):
        if shard_frames < 1:
            raise DatasetError(f"{url}: shard_frames must be >= 1, got {shard_frames}")
        self.store = Store(url)
        self.url = str(url)
        given = grid is not None
        grid, range_bins = grid or Grid(), range_bins or RangeBins()
        self.grid, self.range_bins = grid, range_bins
        self.shard_frames, self.codec, self.clevel = int(shard_frames), codec, clevel
        sh.compressor(codec, clevel)  # fail early on a bad codec
        if self.store.local and self.store.root.is_file():
            raise DatasetError(f"{self.url}: is a file, not a dataset folder")
        root = _json(self.store, "zarr.json")
        self.zstore = self.store.zarr_store(read_only=False)
        self.created_run: str | None = None   # this writer created the dataset: its token in the root
        if root is None:
            if self.store.is_dir() and self.store.list(""):
                raise DatasetError(f"{self.url}: folder exists, is not empty and is not a holodata dataset")
            import uuid

            self.created_run = uuid.uuid4().hex
            self._made_folder = self.store.local and not self.store.root.exists()
            meta = {"format_version": FORMAT_VERSION, "created_by": created_by, "grid": grid.to_attrs(),
                    "range_bins": range_bins.to_attrs(), "grid_source": "given" if given else "default",
                    "splits": {"train": [], "test": []}, "provenance": provenance, "shard_frames": self.shard_frames,
                    "created_run": self.created_run}
            _put_group(self.store, "", {"holodata": meta})
            _put_group(self.store, "scenes", {})
        else:
            from .reader import check_root

            meta = check_root(self.url, root)
            have_g, have_rb = Grid.from_attrs(meta["grid"]), RangeBins.from_attrs(meta["range_bins"])
            adopt = given and (have_g, have_rb) != (grid, range_bins) and self._grid_unset(meta)
            if not given:
                self.grid, self.range_bins = have_g, have_rb
            elif not adopt and have_g != grid:
                raise DatasetError(f"{self.url}: dataset grid is {have_g}, writer asked for {grid}")
            elif not adopt and have_rb != range_bins:
                raise DatasetError(f"{self.url}: dataset has {have_rb}, writer asked for {range_bins}")
            if not self.store.is_file("scenes/zarr.json"):
                _put_group(self.store, "scenes", {})
            if provenance and meta.get("provenance") != provenance:
                hist = dict(meta.get("provenance") or {})
                runs = hist.setdefault("later_runs", [])
                if {"created_by": created_by, **provenance} not in runs:
                    runs.append({"created_by": created_by, **provenance})
                    self._set_root({"provenance": hist})
            if adopt:   # the first radar of a LiDAR-only dataset sets its grid
                self._set_root({"grid": grid.to_attrs(), "range_bins": range_bins.to_attrs(), "grid_source": "given"})

    def discard(self) -> bool:
        """Delete the dataset again when this writer created it (its ``created_run`` token is still the
        root's: no other writer re-created it meanwhile) and it holds no scene, e.g. an ingest whose every
        recording failed; only the two group documents it put go. Returns whether it was deleted; a
        dataset this writer did not create, or that another writer put a scene into, is never touched."""
        root = _json(self.store, "zarr.json")
        token = ((root or {}).get("attributes") or {}).get("holodata", {}).get("created_run")
        if self.created_run is None or token != self.created_run or self.store.list("scenes") != ["zarr.json"]:
            return False
        self.store.delete("scenes/zarr.json")
        self.store.delete("zarr.json")
        if self.store.local:   # the folders it made, once empty (never a folder holding anything else)
            for d in (self.store.root / "scenes", self.store.root)[:2 if self._made_folder else 1]:
                try:
                    d.rmdir()
                except OSError:
                    break
        return True

    def _grid_unset(self, meta: dict) -> bool:
        """The dataset's grid is the default nobody chose and no array is shaped by it yet."""
        if meta.get("grid_source") != "default":
            return False
        from .reader import list_nodes

        for sid in self.store.list("scenes"):
            if any(n.startswith(GRID_ARRAYS) for n in list_nodes(self.store, f"scenes/{sid}")):
                return False
        return True

    # -- root attributes --------------------------------------------------------------------------
    def _update_root(self, fn) -> dict:
        """Root attribute ``holodata`` passed through ``fn`` (dict -> dict): one atomic ``zarr.json`` put."""
        return _update_group_attrs(self.store, "zarr.json",
                                   lambda a: {**a, "holodata": fn(dict(a.get("holodata") or {}))}, self.url)

    def _set_root(self, updates: dict) -> None:
        self._update_root(lambda meta: {**meta, **updates})

    @property
    def attrs(self) -> dict:
        return dict((_json(self.store, "zarr.json") or {}).get("attributes") or {})

    def begin(self, stage: str, rerun: str | None = None) -> None:
        """Mark the dataset unfinished by ``stage`` (root attribute ``holodata.unfinished``; one
        atomic put) before the first write of a command that also writes the root (its splits):
        ``validate`` rejects the dataset until :meth:`finish`. ``rerun``: what finishes it."""
        self._update_root(lambda meta: _with_mark(meta, stage, rerun))

    def finish(self, stage: str) -> None:
        """Clear ``stage``'s root mark (:meth:`begin`) after the command's last write."""
        self._update_root(lambda meta: _without_mark(meta, stage))

    @property
    def unfinished(self) -> dict:
        """{stage: {since, rerun}} of the commands that marked the root and have not finished."""
        return dict((self.attrs.get("holodata") or {}).get(UNFINISHED) or {})

    def set_splits(self, **splits: list[str]) -> None:
        """``set_splits(train=[...], test=[...])``; every name must be an existing scene."""
        have = set(self.scene_ids())
        for split, names in splits.items():
            missing = [n for n in names if n not in have]
            if missing:
                raise DatasetError(f"{self.url}: split {split!r} names unknown scene(s) {', '.join(missing)}")
        self._update_root(lambda meta: {**meta, "splits": {**(meta.get("splits") or {}),
                                                            **{k: list(v) for k, v in splits.items()}}})

    def set_provenance(self, provenance: dict) -> None:
        self._set_root({"provenance": provenance})

    def scene_ids(self) -> list[str]:
        return [n for n in self.store.list("scenes") if self.store.is_file(f"scenes/{n}/zarr.json")]

    def scene(self, scene_id: str, n_frames: int | None = None, attrs: dict | None = None, stage: str | None = None,
              rerun: str | None = None) -> SceneWriter:
        """Create scene ``scene_id`` with ``n_frames`` frames, or reopen it (same ``n_frames``).
        ``stage``: the command about to write it marks it unfinished (:meth:`SceneWriter.begin`) in the
        same atomic put that creates the scene or merges ``attrs``; it calls
        :meth:`SceneWriter.finish` after its last write."""
        if not scene_id or "/" in scene_id or scene_id.startswith("."):
            raise DatasetError(f"{self.url}: bad scene id {scene_id!r} (no '/', not empty)")
        path = f"scenes/{scene_id}"
        cur = _json(self.store, f"{path}/zarr.json")
        if cur is None:
            if n_frames is None or n_frames < 0:
                raise DatasetError(f"{self.url}: new scene {scene_id!r} needs n_frames >= 0")
            a = {"n_frames": int(n_frames), **(attrs or {})}
            if stage is not None:
                a = _with_mark(a, stage, rerun)
            _check_scene_attrs(self.url, scene_id, a)
            _fresh_node(self.store, path)   # (what a killed writer left before the scene's zarr.json)
            _put_group(self.store, path, a)
        else:
            have = cur.get("attributes", {}).get("n_frames")
            if n_frames is not None and have != n_frames:
                raise DatasetError(f"{self.url}: scene {scene_id!r} has {have} frames, writer asked for {n_frames}")
        sc = SceneWriter(self, scene_id)
        if cur is not None and (attrs or stage is not None):
            sc._update(attrs or {}, mark=stage, rerun=rerun)
        return sc

    def open(self):
        from .reader import open_dataset

        return open_dataset(self.url)


def _check_scene_attrs(url: str, scene_id: str, attrs: dict) -> None:
    from .schemas import schema_errors

    errs = schema_errors("scene", attrs)
    if errs:
        raise DatasetError(f"{url}: scene {scene_id!r} attributes: {errs[0]}")


class SceneWriter:
    def __init__(self, ds: DatasetWriter, scene_id: str):
        self.ds, self.id = ds, scene_id
        self.path = f"scenes/{scene_id}"
        self.n_frames = int(_json(ds.store, f"{self.path}/zarr.json")["attributes"]["n_frames"])

    @property
    def attrs(self) -> dict:
        return dict((_json(self.ds.store, f"{self.path}/zarr.json") or {}).get("attributes") or {})

    def set_attrs(self, attrs: dict) -> None:
        """Merge ``attrs`` into the scene attributes (checked against schemas/scene.schema.json): one
        atomic put of the scene's ``zarr.json``."""
        self._update(attrs)

    def _update(self, attrs: dict, mark: str | None = None, unmark: str | None = None, rerun: str | None = None) -> None:
        """Merge ``attrs``, add the unfinished mark of stage ``mark`` and/or drop that of ``unmark``, in
        one read-modify-write of the scene's ``zarr.json`` (one atomic put)."""
        if UNFINISHED in attrs:
            raise DatasetError(f"{self.ds.url}: scene {self.id!r}: the {UNFINISHED!r} attribute is set by "
                               f"begin()/finish() only")

        def update(cur: dict) -> dict:
            new = {**cur, **attrs}
            if unmark is not None:
                new = _without_mark(new, unmark)
            if mark is not None:
                new = _with_mark(new, mark, rerun)
            if new.get("n_frames") != self.n_frames:
                raise DatasetError(f"{self.ds.url}: scene {self.id!r}: n_frames cannot change")
            _check_scene_attrs(self.ds.url, self.id, new)
            return new

        _update_group_attrs(self.ds.store, f"{self.path}/zarr.json", update, self.ds.url)

    # -- unfinished stages (module docstring) ------------------------------------------------------
    def begin(self, stage: str, rerun: str | None = None, attrs: dict | None = None) -> None:
        """Mark the scene unfinished by ``stage`` before the stage's first write (scene attribute
        ``unfinished[stage]``, with ``attrs`` merged in the same atomic put): ``validate`` rejects the
        scene, and other stages refuse it, until :meth:`finish`. ``rerun``: what finishes it (shown by
        validate; default "rerun holodata <stage>")."""
        self._update(attrs or {}, mark=stage, rerun=rerun)

    def finish(self, stage: str, attrs: dict | None = None) -> None:
        """Clear ``stage``'s mark after its last write, merging ``attrs`` (the stage's own record of
        its result) in the same atomic put."""
        self._update(attrs or {}, unmark=stage)

    @contextmanager
    def stage(self, stage: str, rerun: str | None = None) -> Iterator[SceneWriter]:
        """``with sc.stage("raytrace-gt"): ...writes...``: :meth:`begin` on entry, :meth:`finish` when
        the block completes (unless it finished the stage itself); an exception or a kill leaves the
        mark."""
        self.begin(stage, rerun)
        yield self
        if stage in self.unfinished:
            self.finish(stage)

    @property
    def unfinished(self) -> dict:
        """{stage: {since, rerun}} of the stages that marked the scene and have not finished."""
        return dict(self.attrs.get(UNFINISHED) or {})

    def _parents(self, name: str) -> None:
        parts = name.split("/")[:-1]
        for i in range(1, len(parts) + 1):
            p = f"{self.path}/{'/'.join(parts[:i])}"
            if not self.ds.store.is_file(f"{p}/zarr.json"):
                _put_group(self.ds.store, p, {})

    def _check_name(self, name: str) -> None:
        if not name or name.startswith("/") or name.endswith("/") or any(p in ("", ".", "..", "c", sh.MANIFEST_DIR)
                                                                         for p in name.split("/")):
            raise DatasetError(f"{self.ds.url}: scene {self.id!r}: bad array name {name!r}")

    def frame_array(self, name: str, per_frame_shape=(), dtype=None, dims=None, units=None,
                    fill_value=None, attrs: dict | None = None,
                    storage: FrameStorage | None = None) -> FrameArrayWriter:
        """Create (or reopen, same shape/dtype) a frame array (T,) + per_frame_shape: one frame per
        chunk, ``storage.shard_frames`` frames per shard (:class:`FrameStorage`). ``dtype``, ``dims``,
        ``units`` and ``fill_value`` are the layout's (:mod:`holodata.dataset.layout`) for the arrays it
        knows (a caller passes ``dtype`` only where the layout allows several, e.g. ``radar/heatmap``
        float16 or float32); for others float32, ``frame, dim_1, ...``, "1" and NaN (float) or 0.
        ``attrs``: more attributes of the array."""
        self._check_name(name)
        path = f"{self.path}/{name}"
        per_frame_shape = tuple(int(s) for s in per_frame_shape)
        shape = (self.n_frames,) + per_frame_shape
        dims, units, dtype, fill_value = _layout_facts(name, dims, units, dtype, fill_value)
        dtype = np.dtype("float32" if dtype is None else dtype)
        cur = _json(self.ds.store, f"{path}/zarr.json")
        if cur is not None:
            if tuple(cur.get("shape", ())) != shape or np.dtype(cur.get("data_type")) != dtype:
                raise DatasetError(f"{self.ds.url}: scene {self.id!r} array {name!r} exists as "
                                   f"{tuple(cur.get('shape', ()))} {cur.get('data_type')}, asked for {shape} {dtype}")
            return FrameArrayWriter(self, name, cur)
        dims = list(dims) if dims is not None else ["frame"] + [f"dim_{i}" for i in range(1, len(shape))]
        if len(dims) != len(shape):
            raise DatasetError(f"{self.ds.url}: scene {self.id!r} array {name!r}: {len(dims)} dims for a "
                               f"{len(shape)}-d array")
        storage = storage or FrameStorage()
        S = int(storage.shard_frames or self.ds.shard_frames)
        codec = storage.codec
        if fill_value is None:
            fill_value = float("nan") if dtype.kind == "f" else 0
        self._parents(name)
        _fresh_node(self.ds.store, path)
        _put_array(self.ds.store, path, shape=shape, dtype=dtype, chunks=(1,) + per_frame_shape,
                   shards=(S,) + per_frame_shape, fill_value=fill_value,
                   compressors=sh.compressor(codec or self.ds.codec, self.ds.clevel if codec is None else None),
                   attributes={"dims": dims, "units": units, **(attrs or {}),
                               "holodata": {"kind": "frame", "shard_frames": S,
                                            "n_shards": math.ceil(self.n_frames / S),
                                            "shape": list(shape), "dtype": str(dtype)}})
        return FrameArrayWriter(self, name, _json(self.ds.store, f"{path}/zarr.json"))

    def write_array(self, name: str, data, dims=None, units: str | None = None, attrs: dict | None = None,
                    dtype=None) -> None:
        """Write a small non-frame array (mesh, calibration) whole; replaces an existing one. Its
        sha256 (of the C-order bytes) is in its ``zarr.json``, which is put after the chunks: a torn
        write leaves no array (validate finds its chunks unchecked otherwise).
        ``data`` is stored as ``dtype``; ``dtype``, ``dims`` and ``units`` are the layout's for the
        arrays it knows (for others the data's dtype, ``dim_0, ...`` and "1")."""
        self._check_name(name)
        dims, units, dtype, _ = _layout_facts(name, dims, units, dtype)
        data = np.ascontiguousarray(data if dtype is None else np.asarray(data).astype(dtype, copy=False))
        dims = [f"dim_{i}" for i in range(data.ndim)] if dims is None else dims
        if len(dims) != data.ndim:
            raise DatasetError(f"{self.ds.url}: scene {self.id!r} array {name!r}: {len(dims)} dims for a "
                               f"{data.ndim}-d array")
        path = f"{self.path}/{name}"
        row = max(1, int(np.prod(data.shape[1:], dtype=np.int64)) * data.dtype.itemsize)
        chunks = (max(1, min(len(data) if data.ndim else 1, SMALL_CHUNK_BYTES // row)),) + data.shape[1:] \
            if data.ndim else ()
        self._parents(name)
        base = {"dims": list(dims), "units": units, **(attrs or {}),
                "holodata": {"kind": "array", "sha256": sh.sha256(data.tobytes()), "shape": list(data.shape),
                             "dtype": str(data.dtype)}}
        _put_small_array(self.ds.store, path, data, shape=data.shape, dtype=data.dtype,
                         chunks=chunks if data.ndim and data.size else None,  # type: ignore[arg-type]
                         compressors=sh.compressor(self.ds.codec, self.ds.clevel), attributes=base, fill_value=0)

    def ragged_array(self, name: str, width: int | None = None, dtype=None, units: str | None = None, dims=None,
                     shard_frames: int | None = None, codec: str | None = None) -> RaggedWriter:
        """Create (or reopen) ragged array ``name``: values (N, width) + offsets (T+1,) int64.
        ``codec``: of the values (default: the dataset's); ``width``, ``dtype``, ``dims`` and ``units``:
        the layout's for the arrays it knows (for others float32, ``point, xyz|component`` and "1";
        ``width`` must be given)."""
        from .layout import spec

        self._check_name(name)
        path = f"{self.path}/{name}"
        dims, units, dtype, _ = _layout_facts(name, dims, units, dtype)
        dtype = np.dtype("float32" if dtype is None else dtype)
        if width is None:
            s = spec(name)
            if s is None:
                raise DatasetError(f"{self.ds.url}: scene {self.id!r}: ragged array {name!r} is not in the layout; "
                                   f"give its width")
            width = int(s.shape[0])
        cur = _json(self.ds.store, f"{path}/zarr.json")
        if cur is not None:
            hd = cur.get("attributes", {}).get("holodata", {})
            vm = _json(self.ds.store, f"{path}/values/zarr.json") or {}
            if hd.get("kind") != "ragged" or hd.get("width") != width or np.dtype(vm.get("data_type")) != dtype:
                raise DatasetError(f"{self.ds.url}: scene {self.id!r} {name!r} exists with another layout "
                                   f"(asked for ragged width {width} {dtype})")
            return RaggedWriter(self, name, cur)
        S = int(shard_frames or self.ds.shard_frames)
        dims = list(dims) if dims is not None else ["point", "xyz" if width == 3 else "component"]
        self._parents(name)
        hd = {"kind": "ragged", "width": int(width), "shard_frames": S, "n_shards": math.ceil(self.n_frames / S),
              "n_frames": self.n_frames}
        _fresh_node(self.ds.store, path)
        rows = max(1, RAGGED_CHUNK_BYTES // (dtype.itemsize * max(1, width)))
        comp = sh.compressor(self.ds.codec, self.ds.clevel)
        _put_array(self.ds.store, f"{path}/values", shape=(0, width), dtype=dtype, chunks=(rows, width),
                   compressors=sh.compressor(codec, None) if codec else comp, fill_value=0,
                   attributes={"dims": dims, "units": units})
        _put_array(self.ds.store, f"{path}/offsets", shape=(self.n_frames + 1,), dtype="int64",
                   chunks=(self.n_frames + 1,), compressors=comp, fill_value=0,
                   attributes={"dims": ["frame_edge"], "units": "1"})
        _put_group(self.ds.store, path, {"dims": dims, "units": units, "holodata": hd})   # last: marks it made
        return RaggedWriter(self, name, _json(self.ds.store, f"{path}/zarr.json"))

    def remove(self, name: str) -> None:
        """Delete array ``name`` (frame, ragged or whole) so that a later stage can write it anew,
        e.g. slam replacing the odometry poses that ingest took from TF."""
        self._check_name(name)
        self.ds.store.delete_tree(f"{self.path}/{name}")

    def arrays(self) -> list[str]:
        from .reader import list_nodes

        return sorted(list_nodes(self.ds.store, self.path))
