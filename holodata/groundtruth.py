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
``GTConfig.origin`` (the CLI's ``--rotation-radius``/``--column-time``) overrides it. In the
standalone form (a TUM trajectory, no rotation cycles) each row's stamp is the start of its frame's
rotation and the columns span the time to the next row, or ``1/rotation_hz`` when the rate is given
(:func:`standalone_cycles`).

Arrays are Blosc lz4 + shuffle by default (this stage is CPU-bound; ``codec="zstd"`` gives smaller
files at a higher encoding cost: docs/design/performance.md).

Human sources (:mod:`holodata.raytrace.humans`): none, one mesh for all frames, one per frame, or a
dataset's human. This module runs the stage: inputs, the executors (in-process, the local process
pool of :mod:`holodata.raytrace.pool`, one Dask task per shard) and writing; the per-frame trace is
:mod:`holodata.raytrace.frames`. Its names are re-exported here.
"""
from __future__ import annotations

import threading
import time
import uuid
from concurrent.futures import ThreadPoolExecutor
from dataclasses import KW_ONLY, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .beams import OriginModel, beam_rays, column_times, scene_origin_model
from .conventions import RangeBins
from .dataset.inputs import gt_inputs, stale_inputs
from .dataset.layout import (
    GT_ARRAYS,
    GT_RANGE,
    MESH_FACE_CLASS,
    MESH_FACES,
    MESH_VERTICES,
    POSE_T_WORLD_RADAR,
    RADAR_CYCLE_NS,
    TIME_TIMESTAMP_NS,
)
from .dataset.writer import FrameStorage
from .errors import HolodataError, InputError
from .meshio import read_mesh
from .parallel import cpus
from .progress import track
from .raytrace.frames import (
    FrameTracer,
    GTConfig,
    _make_scene,
    column_rays_soa,
    gt_array_specs,
    gt_attrs,
    trace_frame,
    trace_shard,
)
from .raytrace.humans import (
    HUMAN_SPLAT_RADIUS_M,
    MESH_EXTS,
    HumanDataset,
    HumanDir,
    HumanFile,
    HumanSource,
    file_sha256,
    mesh_sha256,
    points_to_mesh,
)
from .raytrace.pool import Helper, _bounded_imap, _slot_bytes, _slot_views, _worker_init, can_fork, run_with_helper
from .safe_io import check_name
from .trajectory import Trajectory, read_tum


class TracingError(HolodataError, RuntimeError):
    """Tracing stopped part-way (a worker process died); written shards are kept for a resume."""


POOL_MIN_FRAMES = 1000
HELPER_MIN_FRAMES = 200          # a forked helper process: its static scene to build
HELPER_SPAWN_MIN_FRAMES = 600    # a spawned one: an interpreter and the imports too (docs/design/raytrace.md)


def auto_processes(n_frames: int) -> int:
    """Tracing processes for ``n_frames``: one per core (max 4) from POOL_MIN_FRAMES frames on, else
    in-process (open3d's casts use every core in-process too). A worker costs an interpreter, the
    imports and the static scene (their CPU time: docs/design/raytrace.md), which shorter runs
    do not earn back."""
    n_cpus = cpus()
    return 1 if n_frames < POOL_MIN_FRAMES or n_cpus < 2 else min(n_cpus, 4)


def auto_helper(n_frames: int, processes: int = 0, backend: str = "open3d") -> bool:
    """Whether an in-process run of ``n_frames`` frames gets a :class:`~holodata.raytrace.pool.Helper`
    process beside its tracing threads: with the automatic choice (``processes`` 0), on two cores or
    more, up to where the pool takes over, from HELPER_MIN_FRAMES frames when this process may fork
    it (:func:`holodata.raytrace.pool.can_fork`), else from HELPER_SPAWN_MIN_FRAMES. Its start-up is
    what shorter runs do not earn back (docs/design/raytrace.md)."""
    if processes > 0 or cpus() < 2 or auto_processes(n_frames) != 1:
        return False
    return n_frames >= (HELPER_MIN_FRAMES if can_fork(backend) else HELPER_SPAWN_MIN_FRAMES)


@dataclass(frozen=True, eq=False)
class TraceInputs:
    """What one scene's frames are traced from: ``mesh`` (vertices (V,3), faces (F,3), face classes
    (F,) uint8 or None, class names or None: the static scene), ``cfg`` the trace's settings,
    ``traj`` the radar poses (one per frame), ``human`` the per-frame human surfaces and ``cycles``
    (T,2) int64 ns, each frame's rotation start/end for per-column times (None: every column at its
    frame's pose). The arguments of :class:`FrameTracer` and of its helper process."""

    mesh: tuple
    cfg: GTConfig
    traj: Trajectory
    human: HumanSource
    cycles: np.ndarray | None = None

    def args(self) -> tuple:
        """(mesh, cfg, traj, human, cycles): :class:`FrameTracer`'s and :class:`Helper`'s arguments."""
        return self.mesh, self.cfg, self.traj, self.human, self.cycles


@dataclass
class _SceneGT:
    """The gt arrays of one scene being written: ``arrays`` name → frame-array writer, ``specs``
    name → its :func:`gt_array_specs` entry (per-frame shape, dtype), the progress bar's ``label``
    (no bar when ``quiet``) and ``clock``: when the first traced frame arrived (``"first"``,
    ``time.perf_counter`` s)."""

    arrays: dict
    specs: dict
    quiet: bool
    label: str
    clock: dict = field(default_factory=dict)

    @property
    def first(self):
        """gt/range's writer: its shards stand for every array's."""
        return self.arrays[GT_RANGE]

    def plan(self, n_frames: int) -> list:
        """[(shard, names still to write, frames)] for the shards of ``n_frames`` frames not yet
        written whole."""
        first = self.first
        all_frames = range(n_frames)
        plan = []
        for k in range(first.n_shards):
            todo = [name for name, a in self.arrays.items() if not a.is_done(k)]
            if todo:
                plan.append((k, todo, all_frames[first.frames(k)]))
        return plan


def write_scene_gt(sc, inputs: TraceInputs, attrs: dict, quiet: bool = True, label: str = "raytrace-gt",
                   processes: int = 1, client=None, helper: Helper | None = None) -> dict:
    """Trace every frame of ``inputs.traj`` and write gt/* shard by shard into dataset scene ``sc``
    (skipping shards already written; a shard's arrays are written only once all its frames are
    traced); ``attrs``: the scene attrs ``gt`` (:func:`gt_attrs`). ``processes`` > 1 traces in that
    many spawned processes (the static scene is built once per worker); writing stays in this
    process, with a bounded number of frames in flight, so memory does not grow with the frame
    count. In-process runs trace in two threads and, when :func:`auto_helper` says so, with a helper
    process beside them (``helper``: one the caller started early for this scene, else one is
    started here). ``client`` (a ``distributed.Client``): one Dask task per shard instead, each
    worker writing its shards (:mod:`holodata.distributed`). Returns a summary dict."""
    cfg = inputs.cfg
    specs = gt_array_specs(cfg.grid, cfg.max_bounces)
    extra = {"storage": FrameStorage(codec=cfg.codec)} if cfg.codec else {}
    arrays = {name: sc.frame_array(name, **spec, **extra) for name, spec in specs.items()}
    sc.set_attrs({"gt": attrs})
    gt = _SceneGT(arrays, specs, quiet, label)
    first = gt.first
    plan = gt.plan(len(inputs.traj))
    skipped = first.n_shards - len(plan)
    n_traced = sum(len(p[2]) for p in plan)
    workers = auto_processes(n_traced) if processes <= 0 else processes
    t0 = time.perf_counter()
    helper_info = None
    extra_info = {}
    if client is not None:
        extra_info = _trace_dask(client, sc, inputs, gt, plan)
        workers = 0
    elif workers == 1 or n_traced == 0:
        used = _trace_in_process(inputs, gt, plan, processes, helper)
        if used is not None:
            workers, helper_info = 2, used.method
    else:
        _trace_pool(inputs, gt, plan, workers)
    dt = time.perf_counter() - t0
    clock = gt.clock
    return {"frames": len(inputs.traj), "shards": first.n_shards, "shards_written": len(plan), "shards_skipped": skipped,
            "frames_traced": n_traced, "processes": workers, "helper": helper_info, **extra_info, "seconds": round(dt, 3),
            "frames_per_s": round(n_traced / dt, 3) if n_traced and dt > 0 else None,
            "first_frame_s": round(clock["first"] - t0, 3) if "first" in clock else None}


def _trace_dask(client, sc, inputs: TraceInputs, gt: _SceneGT, plan: list) -> dict:
    """``plan`` as one Dask task per shard (:func:`trace_scene_dask`), then the workers' manifest
    records folded into the arrays' attrs; returns the summary's Dask fields."""
    dask_info = None
    if sum(len(p[2]) for p in plan):
        dask_info = trace_scene_dask(client, sc, inputs, plan, quiet=gt.quiet, label=gt.label)
    for a in gt.arrays.values():  # fold the workers' manifest records into attrs (idempotent)
        a._consolidate()
    return {"dask_workers": dask_info["workers"] if dask_info else None,
            "ray_threads_per_worker": dask_info["ray_threads"] if dask_info else None}


def _trace_in_process(inputs: TraceInputs, gt: _SceneGT, plan: list, processes: int, helper: Helper | None):
    """``plan`` traced by two threads of this process, with ``helper`` (or, when :func:`auto_helper`
    says so, one started and closed here) beside them; the shards are written as they complete.
    Returns the helper that traced with them, or None."""
    n_traced = sum(len(p[2]) for p in plan)
    own = Helper(*inputs.args()) \
        if helper is None and n_traced and auto_helper(n_traced, processes, inputs.cfg.backend) else None
    helper = helper or own
    try:
        tracer = FrameTracer(*inputs.args()) if n_traced else None
        todo = [f for _, _, frames in plan for f in frames]
        threads = min(2, cpus())
        results = (iter(()) if tracer is None else run_with_helper(tracer, todo, threads, helper) if helper
                   else tracer.run(todo, threads=threads))
        try:
            _write_plan(gt, plan, results, copy=False)
        finally:
            getattr(results, "close", lambda: None)()   # stop the tracing threads before the helper goes
    finally:
        if own is not None:
            own.close()
    return helper if helper is not None and n_traced else None


def _trace_pool(inputs: TraceInputs, gt: _SceneGT, plan: list, workers: int) -> None:
    """``plan`` traced by ``workers`` spawned processes, their results through shared-memory slots
    (at most two per worker, plus two, in flight); the shards are written in this process.
    TracingError when a worker dies (the shards written by then are kept)."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures.process import BrokenProcessPool
    from multiprocessing import shared_memory

    cfg, first = inputs.cfg, gt.first
    wcfg = GTConfig(**{**cfg.__dict__, "nthreads": cfg.nthreads or max(1, cpus() // workers)})
    n_slots = 2 * workers + 2
    size = _slot_bytes(gt.specs)
    shm = shared_memory.SharedMemory(create=True, size=size * n_slots)
    try:
        slots = [_slot_views(shm.buf[i * size:(i + 1) * size], gt.specs) for i in range(n_slots)]
        # concurrent.futures, not multiprocessing.Pool: a worker killed by a signal or the OOM killer
        # breaks the executor (BrokenProcessPool) where Pool would wait forever for its task
        initargs = (inputs.mesh, wcfg, inputs.traj, inputs.human, shm.name, n_slots, inputs.cycles)
        with ProcessPoolExecutor(workers, mp.get_context("spawn"), initializer=_worker_init,
                                 initargs=initargs) as pool:
            frames = [f for _, _, fr in plan for f in fr]
            try:
                _write_plan(gt, plan, _bounded_imap(pool, frames, slots))
            except BrokenProcessPool as err:
                done = sum(first.is_done(k) for k in range(first.n_shards))
                raise TracingError(f"{gt.label}: a tracing process died (killed by a signal or out of memory); "
                                   f"{done} of {first.n_shards} shards are written and kept — rerun to resume, "
                                   f"or use --processes 1") from err
        del slots
    finally:
        shm.close()
        shm.unlink()


def _write_plan(gt: _SceneGT, plan, results, copy: bool = True) -> None:
    """Write the shards of ``plan`` into ``gt``'s arrays from per-frame ``results`` (dicts of gt
    arrays, in plan order). ``copy``: gather each shard into one array per name (results are views
    into reused shared-memory slots); else hand the writer the frames' own arrays, which it encodes
    frame by frame (in-process results are fresh per frame: no gathering copy), and the shard is
    written by a background thread while the next shard is traced (Blosc, sha256 and file writes
    release the GIL, so writing runs on the core the tracer's single-threaded parts leave idle)."""
    arrays, specs, clock = gt.arrays, gt.specs, gt.clock
    results = iter(results)
    writer = None if copy else ThreadPoolExecutor(1, thread_name_prefix="holodata-gt-writer")
    prev = None  # the shard being written in the background
    try:
        for k, todo, frames in track(plan, total=len(plan), description=gt.label, quiet=gt.quiet, unit="shards"):
            if copy:
                bufs = {name: np.empty((len(frames),) + tuple(specs[name]["per_frame_shape"]),
                                       dtype=specs[name]["dtype"]) for name in todo}
            else:
                bufs = {name: [None] * len(frames) for name in todo}
            for i in range(len(frames)):
                out = next(results)
                if "first" not in clock:
                    clock["first"] = time.perf_counter()
                for name in todo:
                    bufs[name][i] = out[name]
            if writer is None:
                _write_shard(arrays, k, todo, bufs)
                continue
            if prev is not None:
                prev.result()  # at most one shard in the writer: memory stays at two shards; its error surfaces here
            prev = writer.submit(_write_shard, arrays, k, todo, bufs)
        if prev is not None:
            prev.result()
    finally:
        if writer is not None:
            writer.shutdown(wait=True)  # never leave a write running behind an error


def _write_shard(arrays: dict, k: int, todo: list, bufs: dict) -> None:
    for name in todo:
        arrays[name].write_shard(k, bufs[name])


def standalone_cycles(traj: Trajectory, rotation_hz: float | None = None,
                      where: str = "poses") -> tuple[np.ndarray | None, str]:
    """Each frame's rotation (start, end) in int64 ns for per-column times in the standalone form,
    and one line saying which model gave them. A TUM row's stamp is the start of its frame's
    rotation (column j at ``start + (j + 0.5)/W · (end − start)``, :func:`holodata.beams.column_times`);
    its columns span the time to the next row (the last row: the previous spacing; the pose
    interpolation holds the last pose there) unless ``rotation_hz`` is given, then
    ``1/rotation_hz`` s. Why: a trajectory of one row per frame says how often frames come, not how
    fast the radar turns; the dataset form's 2 Hz default on 0.1 s rows SLERPed each column across
    five frames (0.6 m off the stated pose). A rotation longer than the spacing of two rows would
    overlap the next frame's: InputError naming ``where``. One row: (None, every column at its pose)."""
    t = np.asarray(traj.timestamp_ns, np.int64)
    if len(t) < 2:
        return None, "one frame: every column at its pose"
    gap = np.diff(t)
    if rotation_hz is None:
        start = t
        end = np.append(t[1:], t[-1] + gap[-1])
        return np.stack([start, end], axis=1), "columns span each frame's stamp to the next frame's"
    period = int(round(1e9 / rotation_hz))
    k = int(np.argmin(gap))
    if period > gap[k] + 1000:   # 1 µs: stamps in text written to the microsecond
        raise InputError(f"{where}: a {rotation_hz:g} Hz rotation lasts {period / 1e9:g} s, longer than the "
                         f"{gap[k] / 1e9:g} s between rows {k + 1} and {k + 2}, so its columns would overlap the next "
                         f"frame's (leave out --rotation-hz to span each frame to the next)")
    return np.stack([t, t + period], axis=1), f"columns span {period / 1e9:g} s ({rotation_hz:g} Hz) from each frame's stamp"


@dataclass
class RaytraceStandalone:
    """``holodata raytrace-gt --mesh --poses --out``: :meth:`run` validates all inputs, then writes a
    docs/format.md §3 dataset (time/timestamp_ns, pose/T_world_radar, mesh/*, gt/*) at ``out`` and
    returns its summary {out, scenes: [one scene's]}. Resumable: rerunning skips done shards.

    ``mesh_path``: the static scene's mesh file; ``poses_path``: the radar's TUM trajectory, one row
    per frame; ``human``: one mesh file for every frame, or (Python API) any :class:`HumanSource`,
    e.g. a dataset scene's per-frame surfaces (:class:`HumanDataset`) indexed by the TUM rows;
    ``human_dir``: one mesh file per frame (not with ``human``); ``scene_id``: the output scene's id;
    ``cfg``: the trace's settings (None: :class:`GTConfig`'s defaults); ``quiet``: no progress bar;
    ``processes``, ``client``: as :func:`write_scene_gt` (``processes`` 0: chosen from the frame
    count, :func:`auto_processes`); ``rotation_hz``: the radar's rotation rate for per-column times
    (None: each frame's columns span the time to the next frame; :func:`standalone_cycles`)."""

    mesh_path: str | Path
    poses_path: str | Path
    out: str
    _: KW_ONLY
    human: str | Path | HumanSource | None = None
    human_dir: str | Path | None = None
    scene_id: str = "scene"
    cfg: GTConfig | None = None
    quiet: bool = True
    processes: int = 0
    client: Any = None
    rotation_hz: float | None = None

    def run(self) -> dict:
        """Read and check the inputs, start the helper process when it pays, then write the output."""
        cfg = self.cfg or GTConfig()
        self._check(cfg)
        mesh = read_mesh(self.mesh_path)
        traj = read_tum(self.poses_path)
        origin = cfg.origin or OriginModel()
        cycles, columns = None, None
        if origin.column_time:
            cycles, columns = standalone_cycles(traj, self.rotation_hz, str(self.poses_path))
        inputs = TraceInputs((mesh.vertices, mesh.faces, mesh.face_class, mesh.class_names), cfg, traj,
                             self._human_source(len(traj)), cycles)
        scene = _make_scene(*inputs.mesh, cfg)
        # inputs are valid: the helper process starts now (forked before this process casts, with the
        # compiled kernels the scene loaded), so that its start-up overlaps the output's creation
        helper = Helper(*inputs.args()) \
            if self.client is None and auto_helper(len(traj), self.processes, cfg.backend) else None
        try:
            summary = self._write(mesh, inputs, scene, columns, helper)
            return {"out": str(self.out), "scenes": [{"scene": self.scene_id, "origin_model": origin.describe(),
                                                      "column_times": columns, **summary}]}
        finally:
            if helper is not None:
                helper.close()

    def _check(self, cfg: GTConfig) -> None:
        """InputError for a backend this machine lacks, both human forms, or a scene id that would
        name a path."""
        from .raytrace import available_backends

        if cfg.backend not in available_backends():
            raise InputError(f"ray-tracing backend {cfg.backend!r} is not available "
                             f"(have: {', '.join(available_backends())})")
        if self.human is not None and self.human_dir is not None:
            raise InputError("give either --human or --human-dir, not both")
        check_name(self.scene_id, "--scene-id")   # names folders/keys under the output: never outside it

    def _human_source(self, n_frames: int) -> HumanSource:
        """The human of each of the ``n_frames`` frames: ``human`` (a source, or one file for all),
        ``human_dir``'s files, or none."""
        if isinstance(self.human, HumanSource):
            return self.human
        if self.human is not None:
            return HumanFile(self.human)
        if self.human_dir is not None:
            return HumanDir(self.human_dir, n_frames)
        return HumanSource()

    def _write(self, mesh, inputs: TraceInputs, scene, columns: str | None, helper: Helper | None) -> dict:
        """Create (or reopen) the output, write the frames' times and poses and the mesh, then trace
        the gt arrays (``scene``: the static scene :func:`gt_attrs` describes; ``columns``: where the
        column times came from). Returns :func:`write_scene_gt`'s summary."""
        # only now create (or reopen) the output
        from .dataset import create_dataset

        cfg, mesh_path, poses_path = inputs.cfg, self.mesh_path, self.poses_path
        mhash = file_sha256(mesh_path) if Path(mesh_path).is_file() else mesh_sha256(mesh.vertices, mesh.faces)
        w = create_dataset(self.out, grid=cfg.grid, range_bins=RangeBins(), created_by="holodata raytrace-gt",
                           provenance={"mesh": str(mesh_path), "mesh_sha256": mhash, "poses": str(poses_path),
                                       "poses_sha256": file_sha256(poses_path)},
                           shard_frames=cfg.shard_frames or 32)
        # marked unfinished in the put that makes (or reopens) the scene; finished after the last gt shard
        sc = w.scene(self.scene_id, n_frames=len(inputs.traj),
                     attrs={"frame_sensor": "radar", "source": "raytrace-gt standalone"}, stage="raytrace-gt",
                     rerun="rerun the same holodata raytrace-gt --mesh ... --poses ... --out command to finish it")
        _write_frame_meta(sc, inputs.traj, inputs.cycles)
        sc.write_array(MESH_VERTICES, mesh.vertices)
        sc.write_array(MESH_FACES, mesh.faces)
        if mesh.face_class is not None:
            sc.write_array(MESH_FACE_CLASS, mesh.face_class)
        attrs = gt_attrs(scene, cfg, mhash, inputs.human, column_times=columns)
        summary = write_scene_gt(sc, inputs, attrs, quiet=self.quiet, processes=self.processes, client=self.client,
                                 helper=helper)
        sc.finish("raytrace-gt")
        return summary


def _write_frame_meta(sc, traj: Trajectory, cycles: np.ndarray | None = None) -> None:
    """time/timestamp_ns and pose/T_world_radar of the standalone output, and ``cycles`` as
    radar/cycle_ns (the rotations the column times were taken from), so that ``evaluate`` and a
    later ``raytrace-gt DATASET`` place every column at the time this trace did."""
    ta = sc.frame_array(TIME_TIMESTAMP_NS, per_frame_shape=())
    pa = sc.frame_array(POSE_T_WORLD_RADAR, per_frame_shape=(4, 4))
    ca = None if cycles is None else sc.frame_array(RADAR_CYCLE_NS, per_frame_shape=(2,))
    for k in range(ta.n_shards):
        sl = ta.frames(k)
        if not ta.is_done(k):
            ta.write_shard(k, np.asarray(traj.timestamp_ns[sl], dtype=np.int64))
        if not pa.is_done(k):
            pa.write_shard(k, np.asarray(traj.poses[sl], dtype=np.float64))
        if ca is not None and not ca.is_done(k):
            ca.write_shard(k, np.asarray(cycles[sl], dtype=np.int64))


def _missing_hint(missing: list[str]) -> str:
    """What to do about the arrays raytrace-gt needs but a scene lacks."""
    if any(m.startswith("mesh/") for m in missing):
        return "run holodata slam first"
    if POSE_T_WORLD_RADAR in missing:
        return ("no radar poses: slam derives them from the LiDAR poses only when the recording's static TF "
                "gives the radar extrinsic; otherwise use the standalone form --mesh/--poses")
    return "ingest the recording again"


def raytrace_dataset(url: str, scene_ids: list[str] | None = None, cfg: GTConfig | None = None,
                     quiet: bool = True, processes: int = 0, client=None, unfinished_ok: bool = False,
                     force: bool = False) -> dict:
    """``holodata raytrace-gt DATASET [--scene ID]``: for each scene with mesh/* and pose/T_world_radar,
    trace with the dataset's grid and write gt/* (resumable). GT traced from other inputs than the
    scene holds now (scene attrs ``gt.inputs``: a person registered since, a new mesh or poses, other
    settings) is traced again, as is every scene's with ``force``. ``unfinished_ok``: the caller is the
    writer that marked the scenes unfinished and traces their GT as its last step (``synth --corners``),
    so its own mark does not stop it."""
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
        if not unfinished_ok:
            s.require_complete("raytrace-gt")
        names = set(s.arrays())
        missing = [n for n in (MESH_VERTICES, MESH_FACES, POSE_T_WORLD_RADAR, TIME_TIMESTAMP_NS) if n not in names]
        if missing:
            if scene_ids:
                raise InputError(f"{url}: scene {sid!r} lacks {', '.join(missing)} ({_missing_hint(missing)})")
            continue
        v = np.asarray(s[MESH_VERTICES][...], dtype=np.float64)
        f = np.asarray(s[MESH_FACES][...], dtype=np.int64)
        if len(f) == 0 or len(v) == 0:
            raise InputError(f"{url}: scene {sid!r} mesh is empty")
        if f.min() < 0 or f.max() >= len(v):
            raise InputError(f"{url}: scene {sid!r} mesh/faces index out of range")
        fc = np.asarray(s[MESH_FACE_CLASS][...], dtype=np.uint8) if MESH_FACE_CLASS in names else None
        poses = np.asarray(s[POSE_T_WORLD_RADAR][...], dtype=np.float64)
        ts = np.asarray(s[TIME_TIMESTAMP_NS][...], dtype=np.int64)
        if not np.all(np.isfinite(poses)):
            raise InputError(f"{url}: scene {sid!r} pose/T_world_radar has non-finite poses")
        cycles = np.asarray(s[RADAR_CYCLE_NS][...], dtype=np.int64) if RADAR_CYCLE_NS in names else None
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
        sc = w.scene(sid, n_frames=len(traj), stage="raytrace-gt",
                     rerun=f"rerun holodata raytrace-gt DATASET --scene {sid} to finish it")
        hsrc = HumanDataset(url, sid, s)
        attrs = gt_attrs(scene, scfg, mesh_sha256(v, f), hsrc, origin_source, cycles is not None)
        attrs["inputs"] = gt_inputs(s.nodes(), attrs)
        old = [n for n in s.arrays() if n.startswith("gt/")]
        changed = stale_inputs((s.attrs.get("gt") or {}).get("inputs"), attrs["inputs"]) if old else []
        if old and (force or changed):   # traced from other inputs (or asked to): trace again, whole
            for n in old:
                sc.remove(n)
        summary = write_scene_gt(sc, TraceInputs(mesh_args, scfg, traj, hsrc, cycles), attrs, quiet=quiet,
                                 label=f"raytrace-gt {sid}", processes=processes, client=client)
        sc.finish("raytrace-gt")
        out.append({"scene": sid, "origin_model": origin.describe(), "origin_source": origin_source,
                    "column_times": attrs["column_times_from"], "retraced": (["--force"] if force and old else changed),
                    **summary})
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
        extra = {"storage": FrameStorage(codec=cfg.codec)} if cfg.codec else {}
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


def trace_scene_dask(client, sc, inputs: TraceInputs, plan: list, quiet: bool = True,
                     label: str = "raytrace-gt") -> dict:
    """Run a raytrace-gt ``plan`` [(shard, names, frames)] of dataset scene ``sc`` (a SceneWriter),
    traced from ``inputs``, as one Dask task per shard. Returns {workers, ray_threads, tasks: [...]}."""
    from dataclasses import replace

    from .distributed import for_workers, n_workers, run_tasks, worker_path

    cfg = inputs.cfg
    local = getattr(client, "holodata_local_workers", 0)
    threads = cfg.nthreads or (max(1, cpus() // local) if local else 0)
    wcfg = replace(cfg, nthreads=threads)
    payload = {"mesh": inputs.mesh, "cfg": wcfg, "traj": inputs.traj, "human": for_workers(inputs.human),
               "url": worker_path(sc.ds.url), "grid": sc.ds.grid, "range_bins": sc.ds.range_bins, "scene_id": sc.id,
               "cycles": inputs.cycles}
    token = uuid.uuid4().hex
    [fut] = client.scatter([payload], broadcast=True, hash=False)
    calls = [(token, fut, k, list(names), frames.start, frames.stop) for k, names, frames in plan]
    keys = [f"raytrace-gt-{sc.id}-shard{k}-{token[:8]}" for k, _, _ in plan]
    try:
        tasks = run_tasks(client, _gt_shard_task, calls, keys, description=label, quiet=quiet)
    finally:
        client.cancel([fut])
    return {"workers": n_workers(client), "ray_threads": threads, "tasks": tasks}


__all__ = ["OriginModel", "GTConfig", "beam_rays", "column_times", "column_rays_soa", "points_to_mesh", "trace_frame",
           "write_scene_gt", "TraceInputs", "trace_shard", "FrameTracer", "gt_array_specs", "gt_attrs",
           "RaytraceStandalone", "raytrace_dataset", "standalone_cycles",
           "HumanSource", "HumanDir", "HumanFile", "HumanDataset", "GT_ARRAYS", "TracingError",
           "MESH_EXTS", "HUMAN_SPLAT_RADIUS_M", "file_sha256", "mesh_sha256", "auto_processes", "POOL_MIN_FRAMES",
           "auto_helper", "HELPER_MIN_FRAMES", "HELPER_SPAWN_MIN_FRAMES"]
