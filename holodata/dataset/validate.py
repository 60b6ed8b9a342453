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
start at 0, never decrease and end at len(values). The frame arrays' value rules are in
:mod:`holodata.dataset.value_rules`, the whole, foreign and ragged arrays' checks in
:mod:`holodata.dataset.array_checks`.
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np

from . import shards as sh
from .array_checks import (
    MAX_LINES_PER_RULE,
    _check_foreign,
    _check_ragged,
    _check_small,
    _metadata_line,
    _missing_shards,
    _Walk,
    sh_json,
)
from .bounded import is_int
from .heatmap import code_of_meta
from .info import stored_bytes
from .inputs import gt_inputs, stale_inputs
from .layout import (
    GT_HUMAN_CENTER,
    GT_LABEL,
    GT_NORMAL,
    GT_POINT,
    GT_RANGE,
    RADAR_HEATMAP,
    TIME_TIMESTAMP_NS,
    required_arrays,
    spec,
)
from .reader import Dataset, Scene, list_nodes, open_dataset, unfinished_line
from .schemas import schema_errors
from .value_rules import _value_rules, frames_not_finite_nonneg  # noqa: F401 - re-exported (ingest)

GT_CORE = (GT_RANGE, GT_LABEL, GT_NORMAL, GT_POINT)
MAX_FRAME_BYTES = 2**31 - 16   # the most one Blosc chunk (one frame of a frame array) can hold


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
class _Plan:
    """What :func:`_check_scene` reads of scene ``sid`` (``T`` frames, its ``nodes``): the shards of its
    frame and ragged arrays; ``bounces``: the bounce axis of the first gt/* array planned (the others
    must agree)."""
    sid: str
    T: int
    nodes: dict
    frame: dict[str, _Walk] = field(default_factory=dict)
    ragged: dict[str, _Walk] = field(default_factory=dict)
    bounces: int | None = None

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
    """Check scene ``sid``'s attributes and which arrays it holds, each array's declared shape, dtype
    and attributes against the layout; the shards to read (None when its frame count is unusable)."""
    store = ds.store
    path = f"scenes/{sid}"
    meta = sh_json(store, f"{path}/zarr.json")
    attrs, unfinished = _scene_attrs(ds, sid, meta, rep)
    T = attrs.get("n_frames")
    if not isinstance(T, int) or isinstance(T, bool) or T < 0:
        return None
    nodes = list_nodes(store, path)
    _check_presence(rep, sid, attrs, unfinished, nodes)
    plan = _Plan(sid, T, nodes)
    for name, (kind, m) in nodes.items():
        if kind != "ragged":
            _plan_array(ds, plan, name, kind, m, rep)
    for name, (kind, m) in nodes.items():
        if kind == "ragged":
            _plan_ragged(store, plan, name, m, rep)
    return plan


def _scene_attrs(ds: Dataset, sid: str, meta: dict, rep: _Report) -> tuple[dict, dict]:
    """The scene's attributes (checked against the schema) and its unfinished stages (each named); ({}
    when its zarr.json holds none)."""
    attrs = meta.get("attributes", {})
    if not isinstance(attrs, dict):
        attrs = {}
    for e in schema_errors("scene", attrs):
        rep.add(sid, None, None, "schema", f"scene attributes: {e}")
    unfinished = Scene(ds, sid, meta).unfinished if isinstance(meta.get("attributes"), dict) else {}
    for stage, rec in sorted(unfinished.items()):
        rep.add(sid, None, None, "unfinished", unfinished_line(stage, rec))
    return attrs, unfinished


def _check_presence(rep: _Report, sid: str, attrs: dict, unfinished: dict, nodes: dict) -> None:
    """The arrays the scene declares it holds are there (an unfinished stage is named already: its
    arrays may be missing yet), its GT was traced from the inputs it holds now, and gt/* is whole."""
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


def _plan_array(ds: Dataset, plan: _Plan, name: str, kind: str, m: dict, rep: _Report) -> None:
    """A frame or whole array: its declared shape a list of sizes, its attributes, its shape and dtype
    against the layout (:func:`_check_declared`) and the writer's record; a frame array's shards join
    the plan once its sizes are sane (:func:`_frame_walk`)."""
    sid = plan.sid
    a = m.get("attributes", {})
    shape = m.get("shape")
    if not isinstance(shape, list) or not all(is_int(v) and v >= 0 for v in shape):
        rep.add(sid, name, None, "shape", f"shape {shape!r} in zarr.json is not a list of sizes")
        return
    shape, dtype = tuple(shape), str(m.get("data_type"))
    dims = a.get("dims")
    if not isinstance(dims, list) or len(dims) != len(shape):
        rep.add(sid, name, None, "attrs", f"attrs['dims'] missing or not {len(shape)} names")
    if not isinstance(a.get("units"), str):
        rep.add(sid, name, None, "attrs", "attrs['units'] missing")
    _check_layout(rep, sid, name, a)
    _check_declared(ds, plan, name, kind, m, rep)
    hd = a.get("holodata", {})
    if kind == "frame" and "dtype" in hd and (hd["dtype"] != dtype or tuple(hd.get("shape", ())) != shape):
        rep.add(sid, name, None, "dtype", f"metadata says {shape} {dtype}, attrs record "
                                          f"{tuple(hd.get('shape', ()))} {hd['dtype']} (metadata changed?)")
    if kind == "frame":
        w = _frame_walk(ds, sid, name, m, shape, rep)
        if w is not None:
            plan.frame[name] = w


def _check_declared(ds: Dataset, plan: _Plan, name: str, kind: str, m: dict, rep: _Report) -> None:
    """Array ``name``'s shape (a list of sizes) and dtype against what the layout expects from n_frames
    and the grid (a heatmap's code with them, gt/* arrays' bounce axes against each other); an array the
    layout does not know: a frame array's frame axis is n_frames."""
    sid, T = plan.sid, plan.T
    shape, dtype = tuple(m["shape"]), str(m.get("data_type"))
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
            if plan.bounces is None:
                plan.bounces = shape[1]
            elif shape[1] != plan.bounces:
                rep.add(sid, name, None, "shape", f"{shape[1]} bounces, gt/* has {plan.bounces}")
    elif kind == "frame" and (not shape or shape[0] != T):
        rep.add(sid, name, None, "shape", f"shape {shape}: frame axis is not n_frames={T}")


def _plan_ragged(store, plan: _Plan, name: str, m: dict, rep: _Report) -> None:
    """A ragged array's attributes; its shards join the plan when it declares a shard size."""
    sid = plan.sid
    a = m.get("attributes", {})
    if "dims" not in a or "units" not in a:
        rep.add(sid, name, None, "attrs", "attrs['dims'] or attrs['units'] missing")
    else:
        _check_layout(rep, sid, name, a)
    S = a.get("holodata", {}).get("shard_frames", 1)
    if not is_int(S) or S < 1:
        rep.add(sid, name, None, "layout", f"shard_frames {S!r} is not a frame count")
        return
    plan.ragged[name] = _Walk(m, S, plan.T, _listed(store, f"scenes/{sid}/{name}"))


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


def format_report(report: dict) -> str:
    lines = [p["line"] for p in report["problems"]]
    mb = report["bytes_decoded"] / 1e6
    status = "ok" if report["ok"] else f"{report['n_problems']} problem(s)"
    tail = (f"{report['dataset']}: {status} — "
            f"{len(report['scenes'])} scene(s), {report['shards_checked']} shards, {mb:.1f} MB decoded "
            f"in {report['seconds']:.2f} s")
    return "\n".join(lines + [tail])


__all__ = ["validate_dataset", "format_report", "Problem", "expected_spec", "schema_errors"]
