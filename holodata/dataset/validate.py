"""``holodata validate``: attributes against the JSON Schemas, array presence/shape/dtype from the
grid attributes, every shard read once (sha256 against its commit record, decoded, value rules),
ragged offsets, splits. Streams shard by shard: memory is a few shards, flat in dataset size.

Value rules (docs/format.md §2/§3): gt/range finite >= 0 or NaN, R1 < R2 < R3 where finite (and no return
after a missing one); gt/label in 0..4 and 0 exactly where gt/range is NaN; gt/normal unit length
(±1e-3; ±2e-3 when stored as float16) where gt/range is finite; time/timestamp_ns int64 strictly
increasing; pose/* rigid and NaN-free; radar/heatmap finite >= 0 (linear amplitude); ragged offsets
start at 0, never decrease and end at len(values).
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from ..conventions import Label, is_rigid
from . import shards as sh
from .info import stored_bytes
from .layout import (CAMERA_POINTS, GT_HUMAN_CENTER, GT_LABEL, GT_NORMAL, GT_POINT, GT_RANGE, HUMAN_FACES,
                     HUMAN_VERTICES, LIDAR_POINTS, MESH_FACES, MESH_VERTICES, POSE_PREFIX, RADAR_HEATMAP,
                     TIME_TIMESTAMP_NS, spec)
from .reader import Dataset, Scene, list_nodes, open_dataset, unfinished_line
from .schemas import schema_errors
from .writer import ragged_digest

MAX_LINES_PER_RULE = 10
GT_CORE = (GT_RANGE, GT_LABEL, GT_NORMAL, GT_POINT)
RAGGED_KNOWN = {LIDAR_POINTS: 3, CAMERA_POINTS: 3, HUMAN_VERTICES: 3, HUMAN_FACES: 3}


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
        return f"{' '.join(where)}: {self.message}"


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

    def add(self, scene, array, frame, rule, message) -> None:
        key = (scene, array, rule)
        n = self._count.get(key, 0) + 1
        self._count[key] = n
        if n <= MAX_LINES_PER_RULE:
            self.problems.append(Problem(scene, array, None if frame is None else int(frame), rule, message))

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
    for split, names in (ds.splits or {}).items():
        for n in names if isinstance(names, list) else []:
            if n not in scenes:
                rep.add(None, None, None, "splits", f"split {split!r} names scene {n!r}, which does not exist")
    plans = []
    for sid in scenes:
        plans.append(_scene_plan(ds, sid, rep))
    total = sum(p[2] for p in plans if p)
    from ..progress import track

    bar = iter(track(range(total), total=total, description="validate", quiet=quiet))
    for p in plans:
        if p:
            _check_scene(ds, *p[:2], rep, bar)
    probs = rep.problems + rep.suppressed()
    return {
        "dataset": ds.url, "format_version": ds.format_version, "ok": not probs,
        "n_problems": sum(rep._count.values()),
        "problems": [{**asdict(p), "line": p.line()} for p in probs],
        "scenes": scenes, "shards_checked": rep.shards,
        "bytes_decoded": rep.bytes_decoded, "bytes_stored": rep.bytes_stored,
        "seconds": round(time.perf_counter() - t0, 3),
    }


def _scene_plan(ds: Dataset, sid: str, rep: _Report) -> tuple[str, dict, int] | None:
    store = ds.store
    path = f"scenes/{sid}"
    meta = sh_json(store, f"{path}/zarr.json")
    attrs = meta.get("attributes", {})
    for e in schema_errors("scene", attrs):
        rep.add(sid, None, None, "schema", f"scene attributes: {e}")
    for stage, rec in sorted(Scene(ds, sid, meta).unfinished.items()):
        rep.add(sid, None, None, "unfinished", unfinished_line(stage, rec))
    T = attrs.get("n_frames")
    if not isinstance(T, int) or T < 0:
        return None
    nodes = list_nodes(store, path)
    if TIME_TIMESTAMP_NS not in nodes:
        rep.add(sid, TIME_TIMESTAMP_NS, None, "presence", "missing (every scene needs frame timestamps)")
    present_gt = [n for n in GT_CORE if n in nodes]
    if present_gt:
        for n in GT_CORE:
            if n not in nodes:
                rep.add(sid, n, None, "presence", f"missing while {', '.join(present_gt)} exist")
    B = None
    for name, (kind, m) in nodes.items():
        a = m.get("attributes", {})
        if kind == "ragged":
            continue
        shape, dtype = tuple(m.get("shape", ())), str(m.get("data_type"))
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
            cfg = m.get("codecs", [{}])[0]
            inner = cfg.get("configuration", {}).get("chunk_shape") if cfg.get("name") == "sharding_indexed" else None
            if not inner or inner[0] != 1:
                rep.add(sid, name, None, "layout", "not sharded with one frame per chunk")
    for name, (kind, m) in nodes.items():
        if kind == "ragged":
            a = m.get("attributes", {})
            if "dims" not in a or "units" not in a:
                rep.add(sid, name, None, "attrs", "attrs['dims'] or attrs['units'] missing")
            else:
                _check_layout(rep, sid, name, a)
    work = sum(_n_shards(m) for kind, m in nodes.values() if kind in ("frame", "ragged"))
    return sid, nodes, work


def sh_json(store, key):
    import json

    b = store.get(key)
    try:
        return json.loads(b) if b is not None else {}
    except ValueError:
        return {}


def _n_shards(m: dict) -> int:
    hd = m.get("attributes", {}).get("holodata", {})
    if "n_shards" in hd:
        return int(hd["n_shards"])
    S = m.get("chunk_grid", {}).get("configuration", {}).get("chunk_shape", [1])[0] or 1
    return -(-int(m.get("shape", [0])[0]) // S)


BLOCK_BYTES = 64 << 20  # shards decoding to more than this are decoded and checked in frame blocks
PREFETCH = 2  # shards read + decoded ahead in worker threads (blosc and numpy release the GIL)
CROSS = (GT_RANGE, GT_LABEL, GT_NORMAL)  # arrays whose rules look at another array's shard


class _Deferred:
    """Problems and counters of one shard, found in a worker thread, replayed in order."""

    def __init__(self):
        self.calls: list[tuple] = []
        self.shards = self.bytes_stored = self.bytes_decoded = 0

    def add(self, *args) -> None:
        self.calls.append(args)

    def replay(self, rep: _Report) -> None:
        for c in self.calls:
            rep.add(*c)
        rep.shards += self.shards
        rep.bytes_stored += self.bytes_stored
        rep.bytes_decoded += self.bytes_decoded


def _check_scene(ds: Dataset, sid: str, nodes: dict, rep: _Report, bar) -> None:
    from collections import deque
    from concurrent.futures import ThreadPoolExecutor

    T = int(sh_json(ds.store, f"scenes/{sid}/zarr.json")["attributes"]["n_frames"])
    frame_arrays = {n: m for n, (k, m) in nodes.items() if k == "frame"}
    # arrays sharing a shard size are walked together, so cross-array rules see each shard once
    groups: dict[int, list[str]] = {}
    for n, m in frame_arrays.items():
        groups.setdefault(int(m["chunk_grid"]["configuration"]["chunk_shape"][0]), []).append(n)
    tasks: list = []
    for S, names in groups.items():
        order = sorted(names, key=lambda n: (n not in (GT_RANGE,), n))
        for k in range(-(-T // S)):
            fr = slice(k * S, min((k + 1) * S, T))
            tasks.extend((S, k, fr, name) for name in order)

    def load(task):
        S, k, fr, name = task
        local = _Deferred()
        return local, _read_shard(ds, sid, name, frame_arrays[name], k, fr, local)

    state: dict = {}
    decoded: dict = {}
    cur = None
    it = iter(tasks)
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
            next(bar, None)
            if (S, k) != cur:
                decoded, cur = {}, (S, k)
            if isinstance(arr, np.ndarray):
                decoded[name] = arr
                _value_rules(ds, sid, name, arr, fr, decoded, rep, state)
    for name, (kind, m) in nodes.items():
        if kind != "frame":   # frame shards are counted as read; the rest as stored (the same bytes info counts)
            rep.bytes_stored += stored_bytes(ds.store, f"scenes/{sid}/{name}", kind, m)
        if kind == "array":
            _check_small(ds, sid, name, m, rep)
        elif kind == "zarr":
            _check_foreign(ds, sid, name, rep)
        elif kind == "ragged":
            _check_ragged(ds, sid, name, m, T, rep, bar)


def _read_shard(ds, sid, name, meta, k, fr, rep) -> np.ndarray | None:
    """Read shard k once: record, checksum, decode. Returns the decoded shard, or None when it
    cannot be used or was checked here in frame blocks (large shards of per-frame-rule arrays)."""
    path = f"scenes/{sid}/{name}"
    rec = sh_json(ds.store, sh.manifest_key(path, k)) or None
    if rec is None:
        rep.add(sid, name, fr.start, "incomplete", f"shard {k} (frames {fr.start}-{fr.stop - 1}) not written "
                                                   f"(half-written dataset: rerun the writer to resume)")
        return None
    hd = meta.get("attributes", {}).get("holodata", {})
    cons = hd.get("shards")
    if isinstance(cons, list) and k < len(cons) and cons[k].get("sha256") != rec.get("sha256"):
        rep.add(sid, name, fr.start, "checksum", f"shard {k}: attrs checksum differs from its manifest record")
    if rec.get("dtype") != meta.get("data_type") or tuple(rec.get("shape", ())) != tuple(meta.get("shape", ())):
        rep.add(sid, name, fr.start, "dtype", f"shard {k}: metadata says {tuple(meta.get('shape', ()))} "
                                              f"{meta.get('data_type')}, shard was written as "
                                              f"{tuple(rec.get('shape', ()))} {rec.get('dtype')}")
        return None
    blob = ds.store.get(sh.shard_key(path, k, len(meta["shape"])))
    rep.shards += 1
    if blob is None:
        rep.add(sid, name, fr.start, "missing", f"shard {k} (frames {fr.start}-{fr.stop - 1}) is missing")
        return None
    rep.bytes_stored += len(blob)
    if len(blob) != rec.get("nbytes", len(blob)):
        rep.add(sid, name, fr.start, "checksum", f"shard {k}: {len(blob)} bytes, recorded {rec.get('nbytes')} "
                                                 f"(truncated?)")
    elif sh.sha256(blob) != rec.get("sha256"):
        rep.add(sid, name, fr.start, "checksum", f"shard {k}: sha256 mismatch (corrupted bytes)")
    n = fr.stop - fr.start
    frame_bytes = int(np.prod(meta["shape"][1:], dtype=np.int64)) * np.dtype(meta["data_type"]).itemsize
    try:
        if name in CROSS or name.startswith("time/") or n * frame_bytes <= BLOCK_BYTES:
            arr = sh.decode_shard(meta, n, blob)
            rep.bytes_decoded += arr.nbytes
            return arr
        block = max(1, BLOCK_BYTES // max(1, frame_bytes))
        for i, part in sh.decode_shard_blocks(meta, n, blob, block):
            rep.bytes_decoded += part.nbytes
            _value_rules(ds, sid, name, part, slice(fr.start + i, fr.start + i + len(part)), {}, rep, {})
        return None
    except Exception as err:  # noqa: BLE001 - any decoder failure is a finding
        rep.add(sid, name, fr.start, "decode", f"shard {k} cannot be decoded ({err.__class__.__name__})")
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
    hd = meta.get("attributes", {}).get("holodata", {})
    try:
        a = np.asarray(ds.scene(sid)[name][...])
    except Exception as err:  # noqa: BLE001
        rep.add(sid, name, None, "decode", f"cannot be decoded ({err.__class__.__name__})")
        return
    rep.bytes_decoded += a.nbytes
    if "sha256" not in hd:
        rep.add(sid, name, None, "incomplete", "no checksum in attrs (write interrupted?)")
    elif hd.get("dtype") != str(a.dtype) or tuple(hd.get("shape", ())) != a.shape:
        rep.add(sid, name, None, "dtype", f"metadata says {a.shape} {a.dtype}, written as "
                                          f"{tuple(hd.get('shape', ()))} {hd.get('dtype')}")
    elif sh.sha256(np.ascontiguousarray(a).tobytes()) != hd["sha256"]:
        rep.add(sid, name, None, "checksum", "sha256 mismatch (corrupted)")
    if name == MESH_FACES and a.size and MESH_VERTICES in ds.scene(sid):
        nv = ds.scene(sid)[MESH_VERTICES].shape[0]
        if a.min() < 0 or a.max() >= nv:
            rep.add(sid, name, None, "mesh", f"face indices outside 0..{nv - 1}")


def _check_foreign(ds, sid, name, rep) -> None:
    try:
        z = ds.scene(sid)[name]
        step = max(1, (z.chunks[0] if z.ndim else 1))
        n = z.shape[0] if z.ndim else 1
        for i in range(0, n, step * 8):
            rep.bytes_decoded += np.asarray(z[i:i + step * 8] if z.ndim else z[...]).nbytes
    except Exception as err:  # noqa: BLE001
        rep.add(sid, name, None, "decode", f"cannot be decoded ({err.__class__.__name__})")


def _check_ragged(ds, sid, name, meta, T, rep, bar) -> None:
    path = f"scenes/{sid}/{name}"
    hd = meta.get("attributes", {}).get("holodata", {})
    S = int(hd.get("shard_frames", 1))
    n_shards = -(-T // S)
    try:
        g = ds.zgroup
        values, offsets = g[f"{path}/values"], g[f"{path}/offsets"]
        off = np.asarray(offsets[...])
    except Exception as err:  # noqa: BLE001
        rep.add(sid, name, None, "decode", f"values/offsets unreadable ({err.__class__.__name__})")
        for _ in range(n_shards):
            next(bar, None)
        return
    width = hd.get("width")
    if values.ndim != 2 or (width is not None and values.shape[1] != width):
        rep.add(sid, name, None, "shape", f"values shape {values.shape}, expected (N, {width})")
    if name in RAGGED_KNOWN and values.ndim == 2 and values.shape[1] != RAGGED_KNOWN[name]:
        rep.add(sid, name, None, "shape", f"values width {values.shape[1]}, expected {RAGGED_KNOWN[name]}")
    if off.shape != (T + 1,) or off.dtype != np.int64:
        rep.add(sid, name, None, "offsets", f"offsets {off.shape} {off.dtype}, expected ({T + 1},) int64")
        return
    if off[0] != 0:
        rep.add(sid, name, 0, "offsets", f"offsets start at {off[0]}, not 0")
    dec = np.flatnonzero(np.diff(off) < 0)
    for i in dec:
        rep.add(sid, name, int(i), "offsets", f"offsets decrease ({off[i]} -> {off[i + 1]})")
    if off[-1] != values.shape[0]:
        rep.add(sid, name, None, "offsets", f"offsets end at {off[-1]}, values has {values.shape[0]} rows")
    for k in range(n_shards):
        next(bar, None)
        fr = slice(k * S, min((k + 1) * S, T))
        rec = sh_json(ds.store, sh.manifest_key(path, k)) or None
        rep.shards += 1
        if rec is None:
            rep.add(sid, name, fr.start, "incomplete", f"shard {k} (frames {fr.start}-{fr.stop - 1}) not written "
                                                       f"(half-written dataset: rerun the writer to resume)")
            continue
        r0, r1 = int(off[fr.start]), int(off[fr.stop])
        if [r0, r1] != list(rec.get("rows", [])) or len(dec):
            rep.add(sid, name, fr.start, "offsets", f"shard {k}: offsets give rows {r0}..{r1}, "
                                                    f"record says {rec.get('rows')}")
            continue
        try:
            v = np.asarray(values[r0:r1])
        except Exception as err:  # noqa: BLE001
            rep.add(sid, name, fr.start, "decode", f"shard {k} values cannot be decoded ({err.__class__.__name__})")
            continue
        rep.bytes_decoded += v.nbytes
        if ragged_digest(v, off[fr.start:fr.stop + 1]) != rec.get("sha256"):
            rep.add(sid, name, fr.start, "checksum", f"shard {k}: sha256 mismatch (corrupted values)")
        if v.dtype.kind == "f" and not np.isfinite(v).all():
            rep.add(sid, name, fr.start, "ragged", f"shard {k}: values hold NaN/inf")


def format_report(report: dict) -> str:
    lines = [p["line"] for p in report["problems"]]
    mb = report["bytes_decoded"] / 1e6
    status = "ok" if report["ok"] else f"{report['n_problems']} problem(s)"
    tail = (f"{report['dataset']}: {status} — "
            f"{len(report['scenes'])} scene(s), {report['shards_checked']} shards, {mb:.1f} MB decoded "
            f"in {report['seconds']:.2f} s")
    return "\n".join(lines + [tail])


__all__ = ["validate_dataset", "format_report", "Problem", "expected_spec", "schema_errors"]
