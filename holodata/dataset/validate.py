"""``holodata validate``, the CI gate: attributes against the JSON Schemas; the arrays a scene must hold
given what it declares (:func:`holodata.dataset.layout.required_arrays`); array presence/shape/dtype
from the grid attributes; the zarr.json fields that decide decoded values against the digests recorded
beside the shard checksums (:func:`shards.meta_digest`, :func:`shards.grid_digest`); every shard read
once (sha256 against its commit record, decoded, value rules); ragged offsets, values dtype; splits.

Sizes the metadata declares are checked against what the store holds before anything is allocated:
the shards walked are those the store lists a commit record of (the declared ones it lacks are
counted, not walked), a shard object's size is asked of the store before it is read, a frame's
declared size is checked against every chunk's Blosc header before the frames are allocated, small
arrays and ragged values are read a chunk at a time after their declared shape is checked against
the writer's record. Streams shard by shard: memory is a few shards, flat in dataset size.

Value rules (docs/format.md §2/§3): gt/range finite >= 0 or NaN, R1 < R2 < R3 where finite (and no return
after a missing one); gt/label in 0..4 and 0 exactly where gt/range is NaN; gt/normal unit length
(±1e-3; ±2e-3 when stored as float16) where gt/range is finite; time/timestamp_ns int64 strictly
increasing; pose/* rigid and NaN-free; radar/heatmap finite >= 0 (linear amplitude); ragged offsets
start at 0, never decrease and end at len(values).
"""
from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from ..conventions import Label, is_rigid
from . import shards as sh
from .bounded import READ_BYTES, Rows, is_int, read_offsets
from .heatmap import code_of_meta
from .info import stored_bytes
from .inputs import gt_inputs, stale_inputs
from .layout import (CAMERA_POINTS, GT_HUMAN_CENTER, GT_LABEL, GT_NORMAL, GT_POINT, GT_RANGE, HUMAN_FACES,
                     HUMAN_VERTICES, LIDAR_POINTS, MESH_FACES, MESH_VERTICES, POSE_PREFIX, RADAR_HEATMAP,
                     TIME_TIMESTAMP_NS, required_arrays, spec)
from .reader import Dataset, Scene, list_nodes, open_dataset, unfinished_line
from .schemas import schema_errors

MAX_LINES_PER_RULE = 10
GT_CORE = (GT_RANGE, GT_LABEL, GT_NORMAL, GT_POINT)
RAGGED_KNOWN = {LIDAR_POINTS: 3, CAMERA_POINTS: 3, HUMAN_VERTICES: 3, HUMAN_FACES: 3}
MAX_FRAME_BYTES = 2**31 - 16   # the most one Blosc chunk (one frame of a frame array) can hold
FOREIGN_RATIO = 1000           # arrays holodata did not write: declared bytes at most this x stored (+ 1 GiB)


@dataclass
class Problem:
    scene: str | None
    array: str | None
    frame: int | None
    rule: str
    message: str

    def line(self) -> str:
        where = [self.scene if self.scene is not None else "(dataset)"]
        if self.array:
            where.append(self.array)
        if self.frame is not None:
            where.append(f"frame {self.frame}")
        return " ".join(f"{' '.join(where)}: {self.message}".split())   # one line, whatever the message held


def expected_spec(name: str, T: int, grid, rb) -> tuple[tuple | None, tuple[str, ...] | None]:
    """(shape pattern with None = any, allowed dtypes) of a frame or static array of the layout
    (:mod:`holodata.dataset.layout`); (None, None) for names it does not know and ragged arrays."""
    s = spec(name)
    if s is None or s.kind == "ragged":
        return None, None
    return s.resolve(T=T, R=rb.n, H=grid.H, W=grid.W), s.dtypes


def _check_layout(rep, sid, name: str, attrs: dict) -> None:
    """An array the layout knows carries the layout's dimension names and units."""
    s = spec(name)
    if s is None:
        return
    if list(attrs.get("dims") or []) != list(s.dims) or attrs.get("units") != s.units:
        rep.add(sid, name, None, "attrs", f"dims {attrs.get('dims')} units {attrs.get('units')!r}, the layout has "
                                          f"{list(s.dims)} {s.units!r} (holodata.dataset.layout)")


def _shape_ok(shape, pattern) -> bool:
    return len(shape) == len(pattern) and all(p is None or p == s for s, p in zip(shape, pattern))


class _Report:
    def __init__(self, url: str):
        self.url = url
        self.problems: list[Problem] = []
        self._count: dict[tuple, int] = {}
        self.bytes_decoded = 0
        self.bytes_stored = 0
        self.shards = 0
        self.grid_changed = 0   # shards whose record names another grid than the root's

    def add(self, scene, array, frame, rule, message) -> None:
        key = (scene, array, rule)
        n = self._count.get(key, 0) + 1
        self._count[key] = n
        if n <= MAX_LINES_PER_RULE:
            self.problems.append(Problem(scene, array, None if frame is None else int(frame), rule, message))

    def bump(self, scene, array, rule, n: int) -> None:
        """Count ``n`` more problems of a rule without a line each (the tail line says how many)."""
        if n > 0:
            key = (scene, array, rule)
            self._count[key] = self._count.get(key, 0) + n

    def suppressed(self) -> list[Problem]:
        return [Problem(s, a, None, r, f"... and {n - MAX_LINES_PER_RULE} more {r} problems")
                for (s, a, r), n in self._count.items() if n > MAX_LINES_PER_RULE]


def validate_dataset(path_or_url, quiet: bool = True) -> dict:
    """Validate a dataset; returns the report {dataset, ok, problems: [{scene, array, frame, rule,
    message, line}], ...}. A path that is not a dataset raises :class:`DatasetError`."""
    t0 = time.perf_counter()
    ds = open_dataset(path_or_url)
    rep = _Report(ds.url)
    for e in schema_errors("dataset", ds.meta):
        rep.add(None, None, None, "schema", f"root attributes: {e}")
    for stage, rec in sorted(ds.unfinished.items()):
        rep.add(None, None, None, "unfinished", unfinished_line(stage, rec))
    scenes = ds.scenes
    if not scenes:
        rep.add(None, None, None, "presence", "no scenes (an ingest that did not get as far as its first scene, "
                                              "or nothing written yet)")
    _check_splits(ds, scenes, rep)
    plans = [p for p in (_scene_plan(ds, sid, rep) for sid in scenes) if p is not None]
    total = sum(p.work for p in plans)
    from ..progress import track

    bar = iter(track(range(total), total=total, description="validate", quiet=quiet))
    grid = sh.grid_digest(ds.grid, ds.range_bins)
    for p in plans:
        _check_scene(ds, p, rep, bar, grid)
    if rep.grid_changed:
        rep.add(None, None, None, "grid", f"the root's grid / range_bins ({ds.grid}; {ds.range_bins}) are not those "
                                          f"{rep.grid_changed} radar/gt shard(s) were written on (root zarr.json "
                                          f"edited? the values would be placed on other beams or ranges)")
    probs = rep.problems + rep.suppressed()
    return {
        "dataset": ds.url, "format_version": ds.format_version, "ok": not probs,
        "n_problems": sum(rep._count.values()),
        "problems": [{**asdict(p), "line": p.line()} for p in probs],
        "scenes": scenes, "shards_checked": rep.shards,
        "bytes_decoded": rep.bytes_decoded, "bytes_stored": rep.bytes_stored,
        "seconds": round(time.perf_counter() - t0, 3),
    }


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


@dataclass
class _Plan:
    sid: str
    T: int
    nodes: dict
    frame: dict[str, _Walk] = field(default_factory=dict)
    ragged: dict[str, _Walk] = field(default_factory=dict)

    @property
    def work(self) -> int:
        return sum(len(w.listed) for w in (*self.frame.values(), *self.ragged.values()))


def _listed(store, path: str) -> list[int]:
    """Indices of the shards whose manifest record the store lists (what it holds, not what is declared)."""
    return sorted(int(n[:-5]) for n in store.list(f"{path}/{sh.MANIFEST_DIR}") if n.endswith(".json")
                  and n[:-5].isdigit())


def _check_splits(ds: Dataset, scenes: list[str], rep: _Report) -> None:
    """Splits name existing data passes (no mapping pass: :mod:`holodata.dataset.splits`). A scene in
    both train and test is not a fault of the data (a one-scene check, an oracle run): train refuses it."""
    from .splits import MAPPING, scene_role

    splits = {k: v for k, v in (ds.splits or {}).items() if isinstance(v, list)}
    for split, names in splits.items():
        for n in names:
            if n not in scenes:
                rep.add(None, None, None, "splits", f"split {split!r} names scene {n!r}, which does not exist")
            elif scene_role(ds.scene(n).attrs) == MAPPING:
                rep.add(None, None, None, "splits", f"split {split!r} holds mapping pass {n!r} (LiDAR only: nothing to "
                                                    f"train or score on)")


def _scene_plan(ds: Dataset, sid: str, rep: _Report) -> _Plan | None:
    store = ds.store
    path = f"scenes/{sid}"
    meta = sh_json(store, f"{path}/zarr.json")
    attrs = meta.get("attributes", {})
    if not isinstance(attrs, dict):
        attrs = {}
    for e in schema_errors("scene", attrs):
        rep.add(sid, None, None, "schema", f"scene attributes: {e}")
    unfinished = Scene(ds, sid, meta).unfinished if isinstance(meta.get("attributes"), dict) else {}
    for stage, rec in sorted(unfinished.items()):
        rep.add(sid, None, None, "unfinished", unfinished_line(stage, rec))
    T = attrs.get("n_frames")
    if not isinstance(T, int) or isinstance(T, bool) or T < 0:
        return None
    nodes = list_nodes(store, path)
    # what the scene declares it holds (an unfinished stage is named above: its arrays may be missing yet)
    required = required_arrays(attrs) if not unfinished else {TIME_TIMESTAMP_NS: "every scene needs frame timestamps"}
    for name, why in required.items():
        if name not in nodes:
            rep.add(sid, name, None, "presence", f"missing ({why})")
    gt: dict = attrs["gt"] if isinstance(attrs.get("gt"), dict) else {}
    if not unfinished and isinstance(gt.get("inputs"), dict) and any(n.startswith("gt/") for n in nodes):
        changed = stale_inputs(gt["inputs"], gt_inputs(nodes, gt))
        if changed:   # e.g. a person registered after the GT was traced: the GT does not hold them
            rep.add(sid, None, None, "stale", f"gt/* was traced from other inputs than the scene holds now "
                                              f"({', '.join(changed)} changed): rerun holodata raytrace-gt")
    present_gt = [n for n in GT_CORE if n in nodes]
    if present_gt:
        for n in GT_CORE:
            if n not in nodes and n not in required:
                rep.add(sid, n, None, "presence", f"missing while {', '.join(present_gt)} exist")
    plan = _Plan(sid, T, nodes)
    B = None
    for name, (kind, m) in nodes.items():
        a = m.get("attributes", {})
        if kind == "ragged":
            continue
        shape = m.get("shape")
        if not isinstance(shape, list) or not all(is_int(v) and v >= 0 for v in shape):
            rep.add(sid, name, None, "shape", f"shape {shape!r} in zarr.json is not a list of sizes")
            continue
        shape, dtype = tuple(shape), str(m.get("data_type"))
        dims = a.get("dims")
        if not isinstance(dims, list) or len(dims) != len(shape):
            rep.add(sid, name, None, "attrs", f"attrs['dims'] missing or not {len(shape)} names")
        if not isinstance(a.get("units"), str):
            rep.add(sid, name, None, "attrs", "attrs['units'] missing")
        _check_layout(rep, sid, name, a)
        pat, dts = expected_spec(name, T, ds.grid, ds.range_bins)
        if pat is not None and dts is not None:
            if not _shape_ok(shape, pat):
                want = "(" + ", ".join("*" if p is None else str(p) for p in pat) + ")"
                rep.add(sid, name, None, "shape", f"shape {shape}, expected {want} from n_frames and the grid")
            if dtype not in dts:
                rep.add(sid, name, None, "dtype", f"dtype {dtype}, expected {' or '.join(dts)}")
            elif name == RADAR_HEATMAP:
                try:   # uint8 codes need their LogCode, linear amplitude must not claim one
                    code_of_meta(m)
                except ValueError as err:
                    rep.add(sid, name, None, "attrs", f"heatmap {err}")
            if name.startswith("gt/") and pat[1] is None and len(shape) > 1 and name != GT_HUMAN_CENTER:
                if B is None:
                    B = shape[1]
                elif shape[1] != B:
                    rep.add(sid, name, None, "shape", f"{shape[1]} bounces, gt/* has {B}")
        elif kind == "frame" and (not shape or shape[0] != T):
            rep.add(sid, name, None, "shape", f"shape {shape}: frame axis is not n_frames={T}")
        hd = a.get("holodata", {})
        if kind == "frame" and "dtype" in hd and (hd["dtype"] != dtype or tuple(hd.get("shape", ())) != shape):
            rep.add(sid, name, None, "dtype", f"metadata says {shape} {dtype}, attrs record "
                                              f"{tuple(hd.get('shape', ()))} {hd['dtype']} (metadata changed?)")
        if kind == "frame":
            w = _frame_walk(ds, sid, name, m, shape, rep)
            if w is not None:
                plan.frame[name] = w
    for name, (kind, m) in nodes.items():
        if kind == "ragged":
            a = m.get("attributes", {})
            if "dims" not in a or "units" not in a:
                rep.add(sid, name, None, "attrs", "attrs['dims'] or attrs['units'] missing")
            else:
                _check_layout(rep, sid, name, a)
            S = a.get("holodata", {}).get("shard_frames", 1)
            if not is_int(S) or S < 1:
                rep.add(sid, name, None, "layout", f"shard_frames {S!r} is not a frame count")
                continue
            plan.ragged[name] = _Walk(m, S, T, _listed(store, f"{path}/{name}"))
    return plan


def _frame_walk(ds, sid, name, m: dict, shape: tuple, rep) -> _Walk | None:
    """The shards of frame array ``name`` to read, once its declared sizes are sane: a dtype numpy
    knows, a shard size, frames a chunk can hold; None (with the problem reported) otherwise."""
    try:
        dt = np.dtype(m.get("data_type"))
    except TypeError:
        rep.add(sid, name, None, "dtype", f"data_type {m.get('data_type')!r} is not a dtype")
        return None
    cfg = (m.get("codecs") or [{}])[0]
    inner = cfg.get("configuration", {}).get("chunk_shape") if cfg.get("name") == "sharding_indexed" else None
    if not inner or inner[0] != 1:
        rep.add(sid, name, None, "layout", "not sharded with one frame per chunk")
        return None
    S = ((m.get("chunk_grid") or {}).get("configuration") or {}).get("chunk_shape", [None])[0]
    if not shape or not isinstance(S, int) or isinstance(S, bool) or S < 1:
        rep.add(sid, name, None, "layout", f"shard shape {S!r} has no frame count")
        return None
    frame_bytes = int(np.prod(shape[1:], dtype=object)) * dt.itemsize
    if frame_bytes > MAX_FRAME_BYTES:
        rep.add(sid, name, None, "shape", f"declares frames of {frame_bytes} bytes ({shape[1:]} {dt}): more than a "
                                          f"chunk can hold ({MAX_FRAME_BYTES} bytes); not read")
        return None
    return _Walk(m, S, shape[0], _listed(ds.store, f"scenes/{sid}/{name}"), frame_bytes, sh.meta_digest(m))


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


BLOCK_BYTES = 64 << 20  # shards decoding to more than this are decoded and checked in frame blocks
PREFETCH = 2  # shards read + decoded ahead in worker threads (blosc and numpy release the GIL)
CROSS = (GT_RANGE, GT_LABEL, GT_NORMAL)  # arrays whose rules look at another array's shard


class _Deferred:
    """Problems and counters of one shard, found in a worker thread, replayed in order."""

    def __init__(self):
        self.calls: list[tuple] = []
        self.shards = self.bytes_stored = self.bytes_decoded = 0
        self.meta_changed = self.grid_changed = False

    def add(self, *args) -> None:
        self.calls.append(args)

    def replay(self, rep: _Report) -> None:
        for c in self.calls:
            rep.add(*c)
        rep.shards += self.shards
        rep.bytes_stored += self.bytes_stored
        rep.bytes_decoded += self.bytes_decoded
        rep.grid_changed += self.grid_changed


def _tasks(frame: dict[str, _Walk], todo: dict[str, list[int]]):
    """(S, k, frames, name) of every listed shard, arrays of one shard size walked together (so that
    cross-array rules see each shard once); made lazily, one per shard the store holds."""
    groups: dict[int, list[str]] = {}
    for n, w in frame.items():
        groups.setdefault(w.S, []).append(n)
    for S, names in groups.items():
        order = sorted(names, key=lambda n: (n not in (GT_RANGE,), n))
        sets = {n: set(todo[n]) for n in names}
        for k in sorted(set().union(*sets.values())):
            for name in order:
                if k in sets[name]:
                    yield S, k, slice(k * S, min((k + 1) * S, frame[name].n)), name


def _metadata_line(rep, sid, name, n: int) -> None:
    rep.add(sid, name, None, "metadata", f"zarr.json differs from the metadata {n} shard(s) were written with "
                                         f"(data_type, codecs, fill_value or chunk grid edited?): the stored bytes "
                                         f"would decode to other values; not decoded")


def _check_scene(ds: Dataset, plan: _Plan, rep: _Report, bar, grid: str) -> None:
    from collections import deque
    from concurrent.futures import ThreadPoolExecutor

    sid, T, nodes = plan.sid, plan.T, plan.nodes
    frame = plan.frame
    todo = {n: _missing_shards(rep, sid, n, w) for n, w in frame.items()}

    def load(task):
        S, k, fr, name = task
        local = _Deferred()
        return local, _read_shard(ds, sid, name, frame[name], k, fr, local, grid)

    state: dict = {}
    decoded: dict = {}
    cur = None
    it = _tasks(frame, todo)
    with ThreadPoolExecutor(PREFETCH) as ex:
        pending: deque = deque()

        def submit() -> None:
            t = next(it, None)
            if t is not None:
                pending.append((t, ex.submit(load, t)))

        for _ in range(PREFETCH):
            submit()
        while pending:
            (S, k, fr, name), fut = pending.popleft()
            local, arr = fut.result()
            submit()
            local.replay(rep)
            frame[name].changed += local.meta_changed
            next(bar, None)
            if (S, k) != cur:
                decoded, cur = {}, (S, k)
            if isinstance(arr, np.ndarray):
                if name == GT_RANGE:   # the one array other arrays' rules look at
                    decoded[name] = arr
                _value_rules(ds, sid, name, arr, fr, decoded, rep, state)
            del arr
    for name, w in frame.items():
        if w.changed:
            _metadata_line(rep, sid, name, w.changed)
    for name, (kind, m) in nodes.items():
        if kind != "frame":   # frame shards are counted as read; the rest as stored (the same bytes info counts)
            rep.bytes_stored += stored_bytes(ds.store, f"scenes/{sid}/{name}", kind, m)
        if kind == "array":
            _check_small(ds, sid, name, m, rep)
        elif kind == "zarr":
            _check_foreign(ds, sid, name, m, rep)
        elif kind == "ragged" and name in plan.ragged:
            _check_ragged(ds, sid, name, plan.ragged[name], T, rep, bar)


def _read_shard(ds, sid, name, w: _Walk, k, fr, rep: _Deferred, grid: str) -> np.ndarray | None:
    """Read shard k once: record, size, checksum, decode. Returns the decoded shard, or None when it
    cannot be used or was checked here in frame blocks (large shards of per-frame-rule arrays)."""
    path = f"scenes/{sid}/{name}"
    meta = w.meta
    rec = sh_json(ds.store, sh.manifest_key(path, k)) or None
    if rec is None:
        rep.add(sid, name, fr.start, "incomplete", f"shard {k} (frames {fr.start}-{fr.stop - 1}) not written "
                                                   f"(half-written dataset: rerun the writer to resume)")
        return None
    hd = meta.get("attributes", {}).get("holodata", {})
    cons = hd.get("shards")
    if isinstance(cons, list) and k < len(cons) and isinstance(cons[k], dict) and cons[k].get("sha256") != rec.get("sha256"):
        rep.add(sid, name, fr.start, "checksum", f"shard {k}: attrs checksum differs from its manifest record")
    if rec.get("dtype") != meta.get("data_type") or tuple(rec.get("shape", ())) != tuple(meta.get("shape", ())):
        rep.add(sid, name, fr.start, "dtype", f"shard {k}: metadata says {tuple(meta.get('shape', ()))} "
                                              f"{meta.get('data_type')}, shard was written as "
                                              f"{tuple(rec.get('shape', ()))} {rec.get('dtype')}")
        return None
    changed = "meta_sha256" in rec and rec["meta_sha256"] != w.digest
    rep.meta_changed = changed
    rep.grid_changed = "grid_sha256" in rec and rec["grid_sha256"] != grid
    key = sh.shard_key(path, k, len(meta["shape"]))
    rep.shards += 1
    try:
        size = ds.store.size(key)   # asked before reading: the object, not the record, bounds what is read
    except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
        size = None
    if size is None:
        rep.add(sid, name, fr.start, "missing", f"shard {k} (frames {fr.start}-{fr.stop - 1}) is missing")
        return None
    nbytes = rec.get("nbytes")
    if is_int(nbytes) and size != nbytes:
        rep.bytes_stored += size
        rep.add(sid, name, fr.start, "checksum", f"shard {k}: {size} bytes, recorded {nbytes} (truncated?)")
        return None
    blob = ds.store.get(key)
    if blob is None:
        rep.add(sid, name, fr.start, "missing", f"shard {k} (frames {fr.start}-{fr.stop - 1}) is missing")
        return None
    rep.bytes_stored += len(blob)
    if sh.sha256(blob) != rec.get("sha256"):
        rep.add(sid, name, fr.start, "checksum", f"shard {k}: sha256 mismatch (corrupted bytes)")
    if changed:
        return None
    n = fr.stop - fr.start
    try:
        if name in CROSS or name.startswith("time/") or n * w.frame_bytes <= BLOCK_BYTES:
            arr = sh.decode_shard(meta, n, blob)
            rep.bytes_decoded += arr.nbytes
            return arr
        block = max(1, BLOCK_BYTES // max(1, w.frame_bytes))
        for i, part in sh.decode_shard_blocks(meta, n, blob, block):
            rep.bytes_decoded += part.nbytes
            _value_rules(ds, sid, name, part, slice(fr.start + i, fr.start + i + len(part)), {}, rep, {})
        return None
    except Exception as err:  # noqa: BLE001 - any decoder failure is a finding
        why = f": {err}" if isinstance(err, ValueError) else ""
        rep.add(sid, name, fr.start, "decode", f"shard {k} cannot be decoded ({err.__class__.__name__}{why})")
        return None


def _frames_where(bad: np.ndarray) -> np.ndarray:
    """Indices (within the shard) of frames with any True in ``bad`` (frame axis first)."""
    return np.flatnonzero(bad.reshape(bad.shape[0], -1).any(axis=1))


def _report_frames(rep, sid, name, fr, bad, rule, msg_fn) -> None:
    for i in _frames_where(bad):
        rep.add(sid, name, fr.start + i, rule, msg_fn(i))


def _aligned(ds, sid, name, fr, decoded) -> np.ndarray | None:
    """``name`` over frames ``fr`` (from this shard walk, else read via zarr)."""
    if name in decoded:
        return decoded[name]
    try:
        return np.asarray(ds.scene(sid)[name][fr])
    except Exception:  # noqa: BLE001 - its own problems are reported when it is walked
        return None


_EXP_BITS = {2: (np.uint16, 0x7C00), 4: (np.uint32, 0x7F800000), 8: (np.uint64, 0x7FF0000000000000)}


def frames_not_finite_nonneg(a: np.ndarray) -> np.ndarray:
    """Frame indices where a float array holds NaN, inf or negative values. Fast path: as unsigned
    bits, a positive finite float is below the exponent mask, so one integer max per frame decides
    (float16 min/max in numpy is slow); flagged frames are re-checked exactly (-0.0 is fine)."""
    n = a.shape[0]
    ut, exp = _EXP_BITS[a.dtype.itemsize]
    cand = np.flatnonzero(a.view(ut).reshape(n, -1).max(axis=1) >= exp)
    out = []
    for i in cand:
        f = a[i]
        with np.errstate(invalid="ignore"):
            if not (np.isfinite(f).all() and (f >= 0).all()):
                out.append(i)
    return np.asarray(out, dtype=np.int64)


def _value_rules(ds, sid, name, a, fr, decoded, rep, state) -> None:
    n = a.shape[0] if a.ndim else 0
    if name == GT_RANGE:
        if a.dtype.kind != "f":
            return
        a2 = a.reshape(n, -1)
        with np.errstate(invalid="ignore"):
            badf = (np.fmin.reduce(a2, axis=1) < 0) | (np.fmax.reduce(a2, axis=1) == np.inf)
        for i in np.flatnonzero(badf):
            with np.errstate(invalid="ignore"):
                cnt = int(((a[i] < 0) | np.isinf(a[i])).sum())
            rep.add(sid, name, fr.start + i, "range", f"{cnt} ranges not finite >= 0 or NaN "
                                                      f"(min {np.nanmin(a[i]):.3g})")
        nan = np.isnan(a)
        decoded["gt/range:nan"] = nan
        if a.ndim == 4 and a.shape[1] > 1:
            with np.errstate(invalid="ignore"):
                order = ~(a[:, 1:] > a[:, :-1])
            order &= ~nan[:, 1:]
            if order.any():
                _report_frames(rep, sid, name, fr, order, "bounce_order",
                               lambda i: f"{int(order[i].sum())} beams break R1 < R2 < R3 (a later bounce "
                                         f"not beyond the previous one, or after a missing one)")
    elif name == GT_LABEL:
        if a.dtype.kind not in "ui":
            return
        a2 = a.reshape(n, -1)
        badf = a2.max(axis=1) > max(Label)
        if a.dtype.kind == "i":
            badf |= a2.min(axis=1) < 0
        for i in np.flatnonzero(badf):
            rep.add(sid, name, fr.start + i, "label",
                    f"{int(((a[i] > max(Label)) | (a[i] < 0)).sum())} labels outside 0..4")
        nan = _range_nan(ds, sid, fr, decoded)
        if nan is not None and nan.shape == a.shape:
            mism = np.not_equal(a == 0, nan)
            if mism.any():
                _report_frames(rep, sid, name, fr, mism, "label_range",
                               lambda i: f"{int(mism[i].sum())} beams where label is 0 but range is not NaN, "
                                         f"or label is set without a range")
    elif name == GT_NORMAL:
        nan = _range_nan(ds, sid, fr, decoded)
        if a.dtype.kind != "f" or nan is None or nan.shape != a.shape[:-1]:
            return
        tol = 1e-3 if a.dtype.itemsize >= 4 else 2e-3
        n32 = a.astype(np.float32, copy=False)
        norm2 = np.einsum("...k,...k->...", n32, n32)
        with np.errstate(invalid="ignore"):
            bad = ~((norm2 >= (1 - tol) ** 2) & (norm2 <= (1 + tol) ** 2))
        bad &= ~nan
        if bad.any():
            _report_frames(rep, sid, name, fr, bad, "normal_unit",
                           lambda i: f"{int(bad[i].sum())} normals not unit length (±{tol:g}) where range is finite")
    elif name == TIME_TIMESTAMP_NS:
        if a.dtype != np.int64:
            rep.add(sid, name, fr.start, "timestamps", f"dtype {a.dtype}, expected int64")
            return
        prev = state.get(("ts", sid))
        full = a if prev is None else np.concatenate([[prev], a])
        bad = np.flatnonzero(np.diff(full) <= 0)
        off = fr.start - (0 if prev is None else 1)
        for i in bad:
            rep.add(sid, name, off + i + 1, "timestamps", f"timestamp {full[i + 1]} not after the previous {full[i]}")
        if len(a):
            state[("ts", sid)] = a[-1]
    elif name.startswith(POSE_PREFIX):
        if a.ndim != 3 or a.shape[1:] != (4, 4):
            return
        ok = is_rigid(a)
        for i in np.flatnonzero(~ok):
            what = ("has NaN/inf" if not np.isfinite(a[i]).all()
                    else "is not rigid (rotation not orthonormal or last row not 0 0 0 1)")
            rep.add(sid, name, fr.start + i, "pose", f"pose {what}")
    elif name == RADAR_HEATMAP:
        if a.dtype.kind != "f" or a.dtype.itemsize not in _EXP_BITS:
            return
        for i in frames_not_finite_nonneg(a):
            rep.add(sid, name, fr.start + i, "heatmap", "heatmap has NaN/inf or negative amplitudes "
                                                        "(stored as linear amplitude >= 0)")


def _range_nan(ds, sid, fr, decoded) -> np.ndarray | None:
    if "gt/range:nan" in decoded:
        return decoded["gt/range:nan"]
    rng = _aligned(ds, sid, GT_RANGE, fr, decoded)
    return None if rng is None else np.isnan(rng)




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


def _check_ragged(ds, sid, name, w: _Walk, T, rep, bar) -> None:
    path = f"scenes/{sid}/{name}"
    hd = w.meta.get("attributes", {}).get("holodata", {})
    S = w.S

    def skip() -> None:
        for _ in w.listed:
            next(bar, None)

    vm, om = sh_json(ds.store, f"{path}/values/zarr.json"), sh_json(ds.store, f"{path}/offsets/zarr.json")
    vshape = vm.get("shape")
    try:
        vdt = np.dtype(vm.get("data_type"))
        if not vm or not om or not isinstance(vshape, list) or not all(is_int(v) and v >= 0 for v in vshape):
            raise TypeError
    except TypeError:
        rep.add(sid, name, None, "decode", "values/offsets zarr.json missing or unreadable")
        return skip()
    width = hd.get("width")
    if len(vshape) != 2 or (width is not None and vshape[1] != width):
        rep.add(sid, name, None, "shape", f"values shape {tuple(vshape)}, expected (N, {width})")
        return skip()
    if name in RAGGED_KNOWN and vshape[1] != RAGGED_KNOWN[name]:
        rep.add(sid, name, None, "shape", f"values width {vshape[1]}, expected {RAGGED_KNOWN[name]}")
    s = spec(name)
    if s is not None and str(vdt) not in s.dtypes:
        rep.add(sid, name, None, "dtype", f"values dtype {vdt}, expected {' or '.join(s.dtypes)} (the layout)")
    if om.get("shape") != [T + 1] or om.get("data_type") != "int64":
        rep.add(sid, name, None, "offsets", f"offsets {tuple(om.get('shape') or ())} {om.get('data_type')}, "
                                            f"expected ({T + 1},) int64")
        return skip()
    try:
        off = read_offsets(ds, path, om, T)
    except Exception as err:  # noqa: BLE001
        why = f": {err}" if isinstance(err, ValueError) else ""
        rep.add(sid, name, None, "offsets", f"offsets cannot be read ({err.__class__.__name__}{why})")
        return skip()
    if off[0] != 0:
        rep.add(sid, name, 0, "offsets", f"offsets start at {off[0]}, not 0")
    dec = np.flatnonzero(np.diff(off) < 0)
    for i in dec[:MAX_LINES_PER_RULE]:
        rep.add(sid, name, int(i), "offsets", f"offsets decrease ({off[i]} -> {off[i + 1]})")
    rep.bump(sid, name, "offsets", len(dec) - MAX_LINES_PER_RULE)
    if off[-1] != vshape[0]:
        rep.add(sid, name, None, "offsets", f"offsets end at {off[-1]}, values has {vshape[0]} rows")
    rows = Rows(ds, f"{path}/values", vm)
    digest = sh.ragged_meta_digest(vm, om)
    changed = 0
    ks = _missing_shards(rep, sid, name, w)
    skip_bar = len(w.listed) - len(ks)
    for _ in range(skip_bar):
        next(bar, None)
    for k in ks:
        next(bar, None)
        fr = slice(k * S, min((k + 1) * S, T))
        rec = sh_json(ds.store, sh.manifest_key(path, k)) or None
        rep.shards += 1
        if rec is None:
            rep.add(sid, name, fr.start, "incomplete", f"shard {k} (frames {fr.start}-{fr.stop - 1}) not written "
                                                       f"(half-written dataset: rerun the writer to resume)")
            continue
        if "meta_sha256" in rec and rec["meta_sha256"] != digest:
            changed += 1
            continue
        if "dtype" in rec and rec["dtype"] != str(vdt):
            rep.add(sid, name, fr.start, "dtype", f"shard {k}: values written as {rec['dtype']}, zarr.json says {vdt}")
            continue
        r0, r1 = int(off[fr.start]), int(off[fr.stop])
        if [r0, r1] != list(rec.get("rows", [])) or len(dec) or r1 > vshape[0]:
            rep.add(sid, name, fr.start, "offsets", f"shard {k}: offsets give rows {r0}..{r1}, "
                                                    f"record says {rec.get('rows')}")
            continue
        h = hashlib.sha256()
        finite = True
        try:
            for v in rows.read(r0, r1):
                h.update(v)
                rep.bytes_decoded += v.nbytes
                if finite and v.dtype.kind == "f" and not np.isfinite(v).all():
                    finite = False
        except Exception as err:  # noqa: BLE001
            why = f": {err}" if isinstance(err, ValueError) else ""
            rep.add(sid, name, fr.start, "decode", f"shard {k} values cannot be decoded ({err.__class__.__name__}{why})")
            continue
        h.update(np.ascontiguousarray(off[fr.start:fr.stop + 1], dtype="<i8").tobytes())   # writer.ragged_digest
        if h.hexdigest() != rec.get("sha256"):
            rep.add(sid, name, fr.start, "checksum", f"shard {k}: sha256 mismatch (corrupted values)")
        if not finite:
            rep.add(sid, name, fr.start, "ragged", f"shard {k}: values hold NaN/inf")
    if changed:
        _metadata_line(rep, sid, name, changed)


def format_report(report: dict) -> str:
    lines = [p["line"] for p in report["problems"]]
    mb = report["bytes_decoded"] / 1e6
    status = "ok" if report["ok"] else f"{report['n_problems']} problem(s)"
    tail = (f"{report['dataset']}: {status} — "
            f"{len(report['scenes'])} scene(s), {report['shards_checked']} shards, {mb:.1f} MB decoded "
            f"in {report['seconds']:.2f} s")
    return "\n".join(lines + [tail])


__all__ = ["validate_dataset", "format_report", "Problem", "expected_spec", "schema_errors"]
