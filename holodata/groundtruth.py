"""raytrace-gt stage: per-frame multi-bounce ground truth written shard by shard (docs/format.md §2-§4).

For frame ``k`` with radar pose ``T_world_radar[k]`` the beams of the grid (``Grid.directions()``)
start at the beam origin and are traced through the static scene mesh plus the human of that
frame (:class:`holodata.raytrace.RayScene`). Outputs per scene (T frames, B bounces):

  gt/range (T,B,H,W) float32 m, NaN = none    gt/normal (T,B,H,W,3) float16 unit, world frame
  gt/point (T,B,H,W,3) float32 world frame    gt/label (T,B,H,W) uint8 (conventions.Label)
  gt/semantic (T,B,H,W) uint8 class id        gt/human_center (T,1,3) float32, NaN when absent

Beam origins (:mod:`holodata.beams`, recorded in scene attrs ``gt.origin_model``): by default the
model the recording states (scene attrs ``sensors.radar.beam_origin``, written by ingest), else
docs/format.md §2's default — the rotation centre, each column at its own time within the rotation (from
``radar/cycle_ns`` when stored) with the pose SLERP-interpolated from the trajectory. A
``GTConfig.origin`` (the CLI's ``--rotation-radius``/``--column-time``) overrides it.

Arrays are Blosc lz4 + shuffle by default (this stage is CPU-bound; ``codec="zstd"`` gives ~25%
smaller files at ~2x the encoding time).

Human sources: none; one mesh for all frames (``--human``); a directory with one mesh per frame
*index* ``{k:06d}.ply`` (``.obj``/``.stl`` also accepted; k = 0-based row of the TUM file);
in a dataset, ragged ``human/vertices`` + ``human/faces`` (per frame, world frame) or, failing
that, the registered human cloud ``human/points`` (map frame, from ``register``) turned into small
octahedra (3 cm). ``camera/points`` is never used: it is in the camera frame until registered.
"""
from __future__ import annotations

import hashlib
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
import numpy as np

from .conventions import (
    DEFAULT_MAX_BOUNCES,
    DEFAULT_MAX_RANGE_M,
    LOS_TOLERANCE_M,
    Grid,
    RangeBins,
)
from .beams import OriginModel, beam_rays, column_poses, column_times, local_origins, scene_origin_model
from .dataset.layout import GT_ARRAYS
from .errors import HolodataError, InputError
from .meshio import read_mesh
from .parallel import cpus
from .progress import track
from .trajectory import Trajectory, read_tum

MESH_EXTS = (".ply", ".obj", ".stl")
HUMAN_SPLAT_RADIUS_M = 0.03


class TracingError(HolodataError, RuntimeError):
    """Tracing stopped part-way (a worker process died); written shards are kept for a resume."""


@dataclass
class GTConfig:
    grid: Grid = field(default_factory=Grid)
    max_bounces: int = DEFAULT_MAX_BOUNCES
    max_range: float = DEFAULT_MAX_RANGE_M
    backend: str = "open3d"
    origin: OriginModel | None = None  # None: the scene's recorded model (ingest), else the default
    shard_frames: int | None = None  # frames per shard of new arrays (None: the dataset's, 32 when new)
    nthreads: int = 0
    codec: str | None = "lz4"  # Blosc codec of the gt arrays: lz4 encodes ~2x faster than zstd, ~30% larger
                               # (raytrace-gt is CPU-bound; None = the dataset's default, zstd)


# ---------------------------------------------------------------------------- beams
_GRID_SOA: dict = {}
_GRID_DIRS: dict = {}


def _grid_soa(grid: Grid) -> np.ndarray:
    """(3, H*W) float32 radar-frame beam directions (cached per grid)."""
    if grid not in _GRID_SOA:
        _GRID_SOA[grid] = np.ascontiguousarray(grid.directions().reshape(-1, 3).T, dtype=np.float32)
    return _GRID_SOA[grid]


def _grid_dirs(grid: Grid) -> np.ndarray:
    """(H, W, 3) float64 radar-frame beam directions (cached per grid)."""
    if grid not in _GRID_DIRS:
        _GRID_DIRS[grid] = grid.directions()
    return _GRID_DIRS[grid]


def column_rays_soa(grid: Grid, origin: OriginModel, col: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`holodata.beams.beam_rays` with ``column_poses`` = ``col`` (W,4,4), as (3, H*W) float32
    origins and directions, equal to the bit to ``beam_rays``'s float64 arrays cast to float32.

    beam_rays's ``einsum("wij,hwj->hwi")`` costs a frame ~7 ms; the same float64 products summed
    in the same order, ``(R_i0 d_0 + R_i2 d_2) + R_i1 d_1`` (numpy's einsum order for this
    contraction; tests/test_groundtruth.py checks it), cost ~1 ms."""
    H, W = grid.H, grid.W
    R, t = col[:, :3, :3], col[:, :3, 3]
    o = np.einsum("wij,wj->wi", R, local_origins(grid, origin)) + t  # (W,3), as beam_rays
    dirs = _grid_dirs(grid)
    d = np.empty((3, H, W), dtype=np.float32)
    for i in range(3):
        d[i] = (R[None, :, i, 0] * dirs[..., 0] + R[None, :, i, 2] * dirs[..., 2]) + R[None, :, i, 1] * dirs[..., 1]
    o32 = np.ascontiguousarray(np.broadcast_to(o.T.astype(np.float32)[:, None, :], (3, H, W)))
    return o32.reshape(3, H * W), d.reshape(3, H * W)


# ---------------------------------------------------------------------------- humans
def points_to_mesh(points: np.ndarray, radius: float = HUMAN_SPLAT_RADIUS_M) -> tuple[np.ndarray, np.ndarray]:
    """A surface for a human point cloud: one octahedron of ``radius`` per (voxel-thinned) point."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int32)
    _, keep = np.unique(np.floor(pts / radius).astype(np.int64), axis=0, return_index=True)
    pts = pts[np.sort(keep)]
    ov = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float) * radius
    of = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    v = (pts[:, None, :] + ov[None]).reshape(-1, 3)
    f = (of[None] + 6 * np.arange(len(pts))[:, None, None]).reshape(-1, 3)
    return v, f.astype(np.int32)


class HumanSource:
    """Per-frame human mesh (world frame) or None: ``source(k) -> (vertices, faces) | None``."""

    kind = "none"

    def __call__(self, k: int):
        return None

    def describe(self) -> dict:
        return {"kind": self.kind}


class HumanFile(HumanSource):
    kind = "file"

    def __init__(self, path: str | Path):
        self.path = Path(path)
        m = read_mesh(self.path)
        self.mesh = (m.vertices, m.faces)

    def __call__(self, k: int):
        return self.mesh

    def describe(self) -> dict:
        return {"kind": self.kind, "path": str(self.path), "sha256": file_sha256(self.path)}


class HumanDir(HumanSource):
    """``DIR/{k:06d}.(ply|obj|stl)`` for every frame index k (checked up front)."""

    kind = "dir"

    def __init__(self, path: str | Path, n_frames: int):
        self.path = Path(path)
        if not self.path.is_dir():
            raise InputError(f"{self.path}: human directory does not exist")
        present = {p.stem: p for p in self.path.iterdir() if p.suffix.lower() in MESH_EXTS}
        self.files = []
        for k in range(n_frames):
            p = present.get(f"{k:06d}")
            if p is None:
                raise InputError(f"{self.path / f'{k:06d}.ply'}: human mesh for frame {k} is missing "
                                 f"(--human-dir needs one mesh per frame index, {n_frames} frames)")
            self.files.append(p)

    def __call__(self, k: int):
        m = read_mesh(self.files[k])
        return (m.vertices, m.faces)

    def describe(self) -> dict:
        return {"kind": self.kind, "path": str(self.path), "naming": "{frame_index:06d}.ply|obj|stl"}


class HumanDataset(HumanSource):
    """Ragged ``human/vertices`` + ``human/faces`` of a dataset scene, else ``human/points`` splats."""

    def __init__(self, url: str, scene_id: str, scene=None):
        self.url, self.scene_id = url, scene_id
        if scene is None:
            from .dataset import open_dataset

            scene = open_dataset(url).scene(scene_id)
        self.scene = scene
        names = set(scene.arrays())
        if {"human/vertices", "human/faces"} <= names:
            self.kind = "dataset:human/vertices+faces"
        elif "human/points" in names:
            self.kind = "dataset:human/points"
        else:
            self.kind = "none"

    def __getstate__(self):  # worker processes reopen the dataset read-only
        return {**self.__dict__, "scene": None}

    def __call__(self, k: int):
        if self.scene is None and self.kind != "none":
            from .dataset import open_dataset

            self.scene = open_dataset(self.url).scene(self.scene_id)
        if self.kind == "dataset:human/vertices+faces":
            v = np.asarray(self.scene.ragged("human/vertices", k), dtype=np.float64)
            f = np.asarray(self.scene.ragged("human/faces", k), dtype=np.int64)
            return (v, f) if len(f) else None
        if self.kind == "dataset:human/points":
            v, f = points_to_mesh(self.scene.ragged("human/points", k))
            return (v, f) if len(f) else None
        return None


# ---------------------------------------------------------------------------- core
def file_sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def mesh_sha256(vertices: np.ndarray, faces: np.ndarray) -> str:
    h = hashlib.sha256(np.ascontiguousarray(vertices, dtype="<f8").tobytes())
    h.update(np.ascontiguousarray(faces, dtype="<i8").tobytes())
    return h.hexdigest()


def trace_frame(scene, cfg: GTConfig, traj: Trajectory, k: int, human, human_vertices=None, cycles=None) -> dict:
    """Ground truth of frame ``k``: dict of per-frame arrays in the gt/* layout (B-major). ``human``:
    (vertices, faces) world frame, or ``scene.prepare_dynamic(...)``, or None. ``cycles`` (T,2) int64
    rotation start/end per frame (radar/cycle_ns) for per-column times, or None."""
    grid, B = cfg.grid, cfg.max_bounces
    origin = cfg.origin or OriginModel()
    pose = traj.poses[k]
    col = column_poses(traj, k, grid, origin, None if cycles is None else cycles[k])
    if col is None and origin.rotation_radius == 0:  # fast path: one origin, rotated grid
        d = pose[:3, :3].astype(np.float32) @ _grid_soa(grid)
        res = scene.trace_soa(pose[:3, 3:4].astype(np.float32), d, max_bounces=B, max_range=cfg.max_range,
                              dynamic=human)
    elif col is not None:  # one pose per column: beam_rays's rays, built straight into (3,N) float32
        o, d = column_rays_soa(grid, origin, col)
        res = scene.trace_soa(o, d, max_bounces=B, max_range=cfg.max_range, dynamic=human)
    else:
        o, d = beam_rays(grid, pose, origin, col)
        res = scene.trace(o, d, max_bounces=B, max_range=cfg.max_range, dynamic=human)
    H, W = grid.H, grid.W
    center = np.full((1, 3), np.nan, dtype=np.float32)
    hv = human_vertices if human_vertices is not None else (human[0] if isinstance(human, tuple) else None)
    if hv is not None and len(hv):
        center[0] = np.asarray(hv, dtype=np.float64).mean(axis=0)
    return {
        "gt/range": res.range.T.reshape(B, H, W),
        "gt/normal": res.normal.transpose(1, 0, 2).reshape(B, H, W, 3).astype(np.float16),
        "gt/point": res.point.transpose(1, 0, 2).reshape(B, H, W, 3),
        "gt/label": res.label.T.reshape(B, H, W),
        "gt/semantic": res.semantic.T.reshape(B, H, W),
        "gt/human_center": center,
    }


def gt_array_specs(grid: Grid, B: int) -> dict:
    """{name: frame_array arguments} of the gt arrays (:data:`holodata.dataset.layout.GT_ARRAYS`) for
    ``B`` bounces on ``grid``; one human centre per frame."""
    from .dataset.layout import LAYOUT

    out = {}
    for name in GT_ARRAYS:
        s = LAYOUT[name]
        out[name] = dict(per_frame_shape=s.per_frame(B=B, H=grid.H, W=grid.W, K=1), dtype=s.dtype, dims=list(s.dims),
                         units=s.units, fill_value=s.fill)
    return out


def gt_attrs(scene, cfg: GTConfig, mesh_hash: str, human: HumanSource, origin_source: str | None = None,
             cycles: bool = False) -> dict:
    """Scene attrs ``gt``: how the ground truth was traced. ``origin_source``: where the beam-origin
    model came from ("flags", "recording" or "default"; :func:`holodata.beams.scene_origin_model`);
    ``cycles``: column times were taken from radar/cycle_ns."""
    origin = cfg.origin or OriginModel()
    return {
        "backend": cfg.backend, "max_bounces": int(cfg.max_bounces), "max_range_m": float(cfg.max_range),
        "origin_model": origin.to_attrs(),
        "origin_source": origin_source or ("flags" if cfg.origin is not None else "default"),
        "column_times_from": ("radar/cycle_ns" if cycles else "frame stamps") if origin.column_time else None,
        "mesh_sha256": mesh_hash, "human": human.describe(),
        "los_tolerance_m": LOS_TOLERANCE_M, "class_source": scene.class_source,
        "class_table": {str(k): v for k, v in scene.class_names.items()}, "human_class": int(scene.human_class),
        "grid": cfg.grid.to_attrs(), "normal_dtype": "float16", "codec": cfg.codec or "dataset default (zstd)",
    }


class FrameTracer:
    """Traces frames of one scene; built in this process or once per worker process.
    ``mesh`` = (vertices, faces, face_class | None, class_names | None); ``cycles`` (T,2) int64
    rotation start/end per frame, or None (see :func:`trace_frame`)."""

    def __init__(self, mesh: tuple, cfg: GTConfig, traj: Trajectory, human: HumanSource, cycles=None):
        self.scene = _make_scene(*mesh, cfg)
        self.cfg, self.traj, self.human, self.cycles = cfg, traj, human, cycles
        self._last = (None, None)

    def __call__(self, f: int) -> dict:
        h = self.human(f)
        if h is None:
            return trace_frame(self.scene, self.cfg, self.traj, f, None, cycles=self.cycles)
        if h is not self._last[0]:  # build the human BVH once per distinct mesh
            self._last = (h, self.scene.prepare_dynamic(*h))
        return trace_frame(self.scene, self.cfg, self.traj, f, self._last[1], human_vertices=h[0], cycles=self.cycles)


_WORKER: dict = {}


def _slot_views(buf, specs: dict) -> dict:
    """Numpy views of one frame's gt arrays laid out back to back in ``buf``."""
    out, off = {}, 0
    for name, spec in specs.items():
        shape, dt = tuple(spec["per_frame_shape"]), np.dtype(spec["dtype"])
        n = int(np.prod(shape, dtype=np.int64)) * dt.itemsize
        out[name] = np.ndarray(shape, dtype=dt, buffer=buf, offset=off)
        off += (n + 63) // 64 * 64
    return out


def _slot_bytes(specs: dict) -> int:
    return sum((int(np.prod(s["per_frame_shape"], dtype=np.int64)) * np.dtype(s["dtype"]).itemsize + 63) // 64 * 64
               for s in specs.values())


def _worker_init(mesh, cfg, traj, human, shm_name, n_slots, cycles=None) -> None:
    from multiprocessing import shared_memory

    specs = gt_array_specs(cfg.grid, cfg.max_bounces)
    shm = shared_memory.SharedMemory(name=shm_name)
    size = _slot_bytes(specs)
    _WORKER.update(tracer=FrameTracer(mesh, cfg, traj, human, cycles), shm=shm,
                   slots=[_slot_views(shm.buf[i * size:(i + 1) * size], specs) for i in range(n_slots)])


def _worker_frame(f: int, slot: int) -> int:
    """Trace frame ``f`` into shared-memory slot ``slot`` (results do not travel through pipes)."""
    out = _WORKER["tracer"](f)
    for name, view in _WORKER["slots"][slot].items():
        view[...] = out[name]
    return slot


def trace_shard(tracer: FrameTracer, frames, names=GT_ARRAYS) -> dict:
    """All gt arrays of ``frames`` (one shard): {name: (n_frames,) + per-frame shape} — the unit of
    work for distributed runs (a task traces one shard, then ``write_shard`` writes it idempotently)."""
    specs = gt_array_specs(tracer.cfg.grid, tracer.cfg.max_bounces)
    out = {n: np.empty((len(frames),) + tuple(specs[n]["per_frame_shape"]), dtype=specs[n]["dtype"]) for n in names}
    for i, f in enumerate(frames):
        res = tracer(f)
        for n in names:
            out[n][i] = res[n]
    return out


POOL_MIN_FRAMES = 1000


def auto_processes(n_frames: int) -> int:
    """Tracing processes for ``n_frames``: one per core (max 4) from POOL_MIN_FRAMES frames on, else
    in-process (open3d's casts use every core in-process too). A worker costs an interpreter, the
    imports and the static scene (~1.5 s of CPU each, docs/design/raytrace.md), which shorter runs
    do not earn back."""
    n_cpus = cpus()
    return 1 if n_frames < POOL_MIN_FRAMES or n_cpus < 2 else min(n_cpus, 4)


def write_scene_gt(sc, mesh: tuple, cfg: GTConfig, traj: Trajectory, human: HumanSource, attrs: dict,
                   quiet: bool = True, label: str = "raytrace-gt", processes: int = 1, client=None,
                   cycles=None) -> dict:
    """Trace every frame of ``traj`` and write gt/* shard by shard into dataset scene ``sc``
    (skipping shards already written; a shard's arrays are written only once all its frames are
    traced). ``processes`` > 1 traces in that many spawned processes (the static scene is built once
    per worker); writing stays in this process, with a bounded number of frames in flight, so
    memory does not grow with the frame count. ``client`` (a ``distributed.Client``): one Dask task
    per shard instead, each worker writing its shards (:mod:`holodata.distributed`). ``cycles``
    (T,2) int64: each frame's rotation start/end for per-column times. Returns a summary dict."""
    specs = gt_array_specs(cfg.grid, cfg.max_bounces)
    extra = {"codec": cfg.codec} if cfg.codec else {}
    arrays = {name: sc.frame_array(name, **spec, **extra) for name, spec in specs.items()}
    sc.set_attrs({"gt": attrs})
    first = arrays["gt/range"]
    all_frames = range(len(traj))
    plan = []  # (shard, names to write, frames)
    for k in range(first.n_shards):
        todo = [name for name, a in arrays.items() if not a.is_done(k)]
        if todo:
            plan.append((k, todo, all_frames[first.frames(k)]))
    skipped = first.n_shards - len(plan)
    n_traced = sum(len(p[2]) for p in plan)
    workers = auto_processes(n_traced) if processes <= 0 else processes
    t0 = time.perf_counter()
    clock: dict = {}
    dask_info = None
    if client is not None:
        if n_traced:
            dask_info = trace_scene_dask(client, sc, mesh, cfg, traj, human, plan, quiet=quiet, label=label,
                                         cycles=cycles)
        for a in arrays.values():  # fold the workers' manifest records into attrs (idempotent)
            a._consolidate()
    elif workers == 1 or n_traced == 0:
        tracer = FrameTracer(mesh, cfg, traj, human, cycles) if n_traced else None
        results = (tracer(f) for _, _, frames in plan for f in frames)
        _write_plan(plan, results, arrays, specs, quiet, label, first.n_shards, clock)
    else:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor
        from concurrent.futures.process import BrokenProcessPool
        from multiprocessing import shared_memory

        wcfg = GTConfig(**{**cfg.__dict__, "nthreads": cfg.nthreads or max(1, cpus() // workers)})
        n_slots = 2 * workers + 2
        size = _slot_bytes(specs)
        shm = shared_memory.SharedMemory(create=True, size=size * n_slots)
        try:
            slots = [_slot_views(shm.buf[i * size:(i + 1) * size], specs) for i in range(n_slots)]
            # concurrent.futures, not multiprocessing.Pool: a worker killed by a signal or the OOM killer
            # breaks the executor (BrokenProcessPool) where Pool would wait forever for its task
            with ProcessPoolExecutor(workers, mp.get_context("spawn"), initializer=_worker_init,
                                     initargs=(mesh, wcfg, traj, human, shm.name, n_slots, cycles)) as pool:
                frames = [f for _, _, fr in plan for f in fr]
                try:
                    _write_plan(plan, _bounded_imap(pool, frames, slots), arrays, specs, quiet, label,
                                first.n_shards, clock)
                except BrokenProcessPool as err:
                    done = sum(first.is_done(k) for k in range(first.n_shards))
                    raise TracingError(f"{label}: a tracing process died (killed by a signal or out of memory); "
                                       f"{done} of {first.n_shards} shards are written and kept — rerun to resume, "
                                       f"or use --processes 1") from err
            del slots
        finally:
            shm.close()
            shm.unlink()
    dt = time.perf_counter() - t0
    extra_info = {}
    if client is not None:
        workers = 0
        extra_info = {"dask_workers": dask_info["workers"] if dask_info else None,
                      "ray_threads_per_worker": dask_info["ray_threads"] if dask_info else None}
    return {"frames": len(traj), "shards": first.n_shards, "shards_written": len(plan), "shards_skipped": skipped,
            "frames_traced": n_traced, "processes": workers, **extra_info, "seconds": round(dt, 3),
            "frames_per_s": round(n_traced / dt, 3) if n_traced and dt > 0 else None,
            "first_frame_s": round(clock["first"] - t0, 3) if "first" in clock else None}


def _bounded_imap(pool, frames: list, slots: list):
    """Ordered per-frame results (views into shared-memory ``slots``, valid until the next item)
    with at most ``len(slots)`` frames in flight; ``pool`` a ``ProcessPoolExecutor`` whose workers ran
    :func:`_worker_init`."""
    from collections import deque

    pending: deque = deque()
    free = list(range(len(slots)))
    it = iter(frames)

    def submit():
        f = next(it, None)
        if f is not None:
            slot = free.pop()
            pending.append(pool.submit(_worker_frame, f, slot))
        return f is not None

    while free and submit():
        pass
    while pending:
        slot = pending.popleft().result()
        yield slots[slot]
        free.append(slot)
        submit()


def _write_plan(plan, results, arrays, specs, quiet, label, n_shards, clock: dict | None = None) -> None:
    results = iter(results)
    for k, todo, frames in track(plan, total=len(plan), description=label, quiet=quiet, unit="shards"):
        bufs = {name: np.empty((len(frames),) + tuple(specs[name]["per_frame_shape"]), dtype=specs[name]["dtype"])
                for name in todo}
        for i in range(len(frames)):
            out = next(results)
            if clock is not None and "first" not in clock:
                clock["first"] = time.perf_counter()
            for name in todo:
                bufs[name][i] = out[name]
        for name in todo:
            arrays[name].write_shard(k, bufs[name])


def _make_scene(vertices, faces, face_class, class_names, cfg: GTConfig):
    from .raytrace import RayScene

    try:
        return RayScene(vertices, faces, backend=cfg.backend, face_class=face_class, class_names=class_names,
                        nthreads=cfg.nthreads)
    except ValueError as err:
        raise InputError(f"scene mesh: {err}") from err


def raytrace_standalone(mesh_path: str | Path, poses_path: str | Path, out: str, *,
                        human: str | Path | HumanSource | None = None, human_dir: str | Path | None = None,
                        scene_id: str = "scene", cfg: GTConfig | None = None, quiet: bool = True, processes: int = 0,
                        client=None) -> dict:
    """``holodata raytrace-gt --mesh --poses --out``: validate all inputs, then write a docs/format.md §3 dataset
    (time/timestamp_ns, pose/T_world_radar, mesh/*, gt/*). Resumable: rerunning skips done shards.
    ``human``: one mesh file for every frame, or (Python API) any :class:`HumanSource`, e.g. a
    dataset scene's per-frame surfaces (:class:`HumanDataset`) indexed by the TUM rows."""
    cfg = cfg or GTConfig()
    from .raytrace import available_backends

    if cfg.backend not in available_backends():
        raise InputError(f"ray-tracing backend {cfg.backend!r} is not available (have: {', '.join(available_backends())})")
    if human is not None and human_dir is not None:
        raise InputError("give either --human or --human-dir, not both")
    mesh = read_mesh(mesh_path)
    traj = read_tum(poses_path)
    hsrc: HumanSource = HumanSource()
    if isinstance(human, HumanSource):
        hsrc = human
    elif human is not None:
        hsrc = HumanFile(human)
    elif human_dir is not None:
        hsrc = HumanDir(human_dir, len(traj))
    mesh_args = (mesh.vertices, mesh.faces, mesh.face_class, mesh.class_names)
    scene = _make_scene(*mesh_args, cfg)
    # inputs are valid: only now create (or reopen) the output
    from .dataset import create_dataset

    mhash = file_sha256(mesh_path) if Path(mesh_path).is_file() else mesh_sha256(mesh.vertices, mesh.faces)
    w = create_dataset(out, grid=cfg.grid, range_bins=RangeBins(), created_by="holodata raytrace-gt",
                       provenance={"mesh": str(mesh_path), "mesh_sha256": mhash, "poses": str(poses_path),
                                   "poses_sha256": file_sha256(poses_path)},
                       shard_frames=cfg.shard_frames or 32)
    T = len(traj)
    sc = w.scene(scene_id, n_frames=T, attrs={"frame_sensor": "radar", "source": "raytrace-gt standalone"})
    _write_frame_meta(sc, traj)
    sc.write_array("mesh/vertices", mesh.vertices.astype(np.float32), dims=["vertex", "xyz"], units="m")
    sc.write_array("mesh/faces", mesh.faces.astype(np.int32), dims=["face", "corner"], units="1")
    if mesh.face_class is not None:
        sc.write_array("mesh/face_class", mesh.face_class, dims=["face"], units="1")
    summary = write_scene_gt(sc, mesh_args, cfg, traj, hsrc, gt_attrs(scene, cfg, mhash, hsrc), quiet=quiet,
                             processes=processes, client=client)
    return {"out": str(out), "scenes": [{"scene": scene_id, "origin_model": (cfg.origin or OriginModel()).describe(),
                                         **summary}]}


def _write_frame_meta(sc, traj: Trajectory) -> None:
    ta = sc.frame_array("time/timestamp_ns", per_frame_shape=(), dtype="int64", dims=["frame"], units="ns", fill_value=0)
    pa = sc.frame_array("pose/T_world_radar", per_frame_shape=(4, 4), dtype="float64", dims=["frame", "row", "col"],
                        units="m", fill_value=float("nan"))
    for k in range(ta.n_shards):
        sl = ta.frames(k)
        if not ta.is_done(k):
            ta.write_shard(k, np.asarray(traj.timestamp_ns[sl], dtype=np.int64))
        if not pa.is_done(k):
            pa.write_shard(k, np.asarray(traj.poses[sl], dtype=np.float64))


def _missing_hint(missing: list[str]) -> str:
    """What to do about the arrays raytrace-gt needs but a scene lacks."""
    if any(m.startswith("mesh/") for m in missing):
        return "run holodata slam first"
    if "pose/T_world_radar" in missing:
        return ("no radar poses: slam derives them from the LiDAR poses only when the recording's static TF "
                "gives the radar extrinsic; otherwise use the standalone form --mesh/--poses")
    return "ingest the recording again"


def raytrace_dataset(url: str, scene_ids: list[str] | None = None, cfg: GTConfig | None = None,
                     quiet: bool = True, processes: int = 0, client=None) -> dict:
    """``holodata raytrace-gt DATASET [--scene ID]``: for each scene with mesh/* and pose/T_world_radar,
    trace with the dataset's grid and write gt/* (resumable)."""
    from .dataset import create_dataset, open_dataset

    cfg = cfg or GTConfig()
    ds = open_dataset(url)
    grid = ds.grid
    ids = list(scene_ids) if scene_ids else list(ds.scenes)
    plans = []
    for sid in ids:
        if sid not in ds.scenes:
            raise InputError(f"{url}: no scene {sid!r} (have: {', '.join(ds.scenes)})")
        s = ds.scene(sid)
        s.require_complete("raytrace-gt")
        names = set(s.arrays())
        missing = [n for n in ("mesh/vertices", "mesh/faces", "pose/T_world_radar", "time/timestamp_ns") if n not in names]
        if missing:
            if scene_ids:
                raise InputError(f"{url}: scene {sid!r} lacks {', '.join(missing)} ({_missing_hint(missing)})")
            continue
        v = np.asarray(s["mesh/vertices"][...], dtype=np.float64)
        f = np.asarray(s["mesh/faces"][...], dtype=np.int64)
        if len(f) == 0 or len(v) == 0:
            raise InputError(f"{url}: scene {sid!r} mesh is empty")
        if f.min() < 0 or f.max() >= len(v):
            raise InputError(f"{url}: scene {sid!r} mesh/faces index out of range")
        fc = np.asarray(s["mesh/face_class"][...], dtype=np.uint8) if "mesh/face_class" in names else None
        poses = np.asarray(s["pose/T_world_radar"][...], dtype=np.float64)
        ts = np.asarray(s["time/timestamp_ns"][...], dtype=np.int64)
        if not np.all(np.isfinite(poses)):
            raise InputError(f"{url}: scene {sid!r} pose/T_world_radar has non-finite poses")
        cycles = np.asarray(s["radar/cycle_ns"][...], dtype=np.int64) if "radar/cycle_ns" in names else None
        plans.append((sid, s, v, f, fc, Trajectory(ts, poses), cycles))
    if not plans:
        raise InputError(f"{url}: no scene has mesh/* and pose/T_world_radar (run slam first)")
    meta = getattr(ds, "meta", None) or (ds.attrs or {}).get("holodata", {})
    sf = cfg.shard_frames or int(meta.get("shard_frames") or 32)
    w = create_dataset(url, grid=grid, range_bins=ds.range_bins, created_by="holodata raytrace-gt", shard_frames=sf)
    out = []
    for sid, s, v, f, fc, traj, cycles in plans:
        origin, origin_source = scene_origin_model(s.attrs, cfg.origin)
        scfg = GTConfig(**{**cfg.__dict__, "grid": grid, "origin": origin})
        mesh_args = (v, f, fc, s.attrs.get("class_names"))
        scene = _make_scene(*mesh_args, scfg)
        sc = w.scene(sid, n_frames=len(traj))
        hsrc = HumanDataset(url, sid, s)
        attrs = gt_attrs(scene, scfg, mesh_sha256(v, f), hsrc, origin_source, cycles is not None)
        summary = write_scene_gt(sc, mesh_args, scfg, traj, hsrc, attrs, quiet=quiet, label=f"raytrace-gt {sid}",
                                 processes=processes, client=client, cycles=cycles)
        out.append({"scene": sid, "origin_model": origin.describe(), "origin_source": origin_source, **summary})
    return {"out": str(url), "scenes": out}


# -- Dask task (holodata.distributed runs it): one per shard ---------------------------------------------
_LOCAL = threading.local()  # per worker thread: (token, FrameTracer)


def _tracer(token: str, payload: dict):
    cur = getattr(_LOCAL, "tracer", None)
    if cur is None or cur[0] != token:
        _LOCAL.tracer = None  # drop the previous scene before building the next
        _LOCAL.tracer = (token, FrameTracer(payload["mesh"], payload["cfg"], payload["traj"], payload["human"],
                                                payload.get("cycles")))
    return _LOCAL.tracer[1]


def _gt_shard_task(token: str, payload: dict, k: int, names: list[str], start: int, stop: int) -> dict:
    """Worker side: trace frames ``start:stop`` (= shard ``k``) and write shard ``k`` of ``names``."""
    from .dataset import create_dataset
    from .distributed import tune_malloc

    tune_malloc()
    t0 = time.perf_counter()
    arrays = getattr(_LOCAL, "arrays", None)
    if arrays is None or arrays[0] != token:  # the scene's array writers, opened once per worker thread
        cfg = payload["cfg"]
        w = create_dataset(payload["url"], grid=payload["grid"], range_bins=payload["range_bins"])
        sc = w.scene(payload["scene_id"])
        extra = {"codec": cfg.codec} if cfg.codec else {}
        arrays = _LOCAL.arrays = (token, {name: sc.frame_array(name, **spec, **extra)
                                          for name, spec in gt_array_specs(cfg.grid, cfg.max_bounces).items()})
    # a rerun of a task whose shard was committed meanwhile (its worker died after the commit) is
    # cheap: is_done asks the store for the manifest record, not only this writer's memory
    todo = [name for name in names if not arrays[1][name].is_done(k)]
    written = []
    if todo:
        out = trace_shard(_tracer(token, payload), range(start, stop), todo)
        t1 = time.perf_counter()
        written = [name for name in todo if arrays[1][name].write_shard(k, out[name])]
    else:
        t1 = time.perf_counter()
    try:
        from distributed import get_worker

        where = get_worker().address
    except (ImportError, ValueError):
        where = "local"
    return {"shard": k, "frames": stop - start, "written": written, "trace_s": t1 - t0,
            "write_s": time.perf_counter() - t1, "worker": where}


def trace_scene_dask(client, sc, mesh: tuple, cfg, traj, human, plan: list, quiet: bool = True,
                     label: str = "raytrace-gt", cycles=None) -> dict:
    """Run a raytrace-gt ``plan`` [(shard, names, frames)] of dataset scene ``sc`` (a SceneWriter)
    as one Dask task per shard (``cycles``: per-frame rotation start/end, see
    :class:`holodata.groundtruth.FrameTracer`). Returns {workers, ray_threads, tasks: [...]}."""
    from dataclasses import replace

    from .distributed import for_workers, n_workers, run_tasks, worker_path

    local = getattr(client, "holodata_local_workers", 0)
    threads = cfg.nthreads or (max(1, cpus() // local) if local else 0)
    wcfg = replace(cfg, nthreads=threads)
    payload = {"mesh": mesh, "cfg": wcfg, "traj": traj, "human": for_workers(human), "url": worker_path(sc.ds.url),
               "grid": sc.ds.grid, "range_bins": sc.ds.range_bins, "scene_id": sc.id, "cycles": cycles}
    token = uuid.uuid4().hex
    [fut] = client.scatter([payload], broadcast=True, hash=False)
    calls = [(token, fut, k, list(names), frames.start, frames.stop) for k, names, frames in plan]
    keys = [f"raytrace-gt-{sc.id}-shard{k}-{token[:8]}" for k, _, _ in plan]
    try:
        tasks = run_tasks(client, _gt_shard_task, calls, keys, description=label, quiet=quiet)
    finally:
        client.cancel([fut])
    return {"workers": n_workers(client), "ray_threads": threads, "tasks": tasks}


__all__ = ["OriginModel", "GTConfig", "beam_rays", "column_times", "points_to_mesh", "trace_frame",
           "write_scene_gt", "trace_shard", "FrameTracer", "gt_array_specs", "raytrace_standalone", "raytrace_dataset",
           "HumanSource", "HumanDir", "HumanFile",
           "HumanDataset", "GT_ARRAYS"]
