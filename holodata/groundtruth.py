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
from pathlib import Path

import numpy as np

from .beams import OriginModel, beam_rays, column_times, scene_origin_model
from .conventions import RangeBins
from .dataset.inputs import gt_inputs, stale_inputs
from .dataset.layout import (GT_ARRAYS, GT_RANGE, MESH_FACES, MESH_FACE_CLASS, MESH_VERTICES, POSE_T_WORLD_RADAR,
                             RADAR_CYCLE_NS, TIME_TIMESTAMP_NS)
from .errors import HolodataError, InputError
from .meshio import read_mesh
from .parallel import cpus
from .progress import track
from .safe_io import check_name
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


def write_scene_gt(sc, mesh: tuple, cfg: GTConfig, traj: Trajectory, human: HumanSource, attrs: dict,
                   quiet: bool = True, label: str = "raytrace-gt", processes: int = 1, client=None,
                   cycles=None, helper: Helper | None = None) -> dict:
    """Trace every frame of ``traj`` and write gt/* shard by shard into dataset scene ``sc``
    (skipping shards already written; a shard's arrays are written only once all its frames are
    traced). ``processes`` > 1 traces in that many spawned processes (the static scene is built once
    per worker); writing stays in this process, with a bounded number of frames in flight, so
    memory does not grow with the frame count. In-process runs trace in two threads and, when
    :func:`auto_helper` says so, with a helper process beside them (``helper``: one the caller
    started early for this scene, else one is started here). ``client`` (a ``distributed.Client``):
    one Dask task per shard instead, each worker writing its shards (:mod:`holodata.distributed`).
    ``cycles`` (T,2) int64: each frame's rotation start/end for per-column times. Returns a summary dict."""
    specs = gt_array_specs(cfg.grid, cfg.max_bounces)
    extra = {"codec": cfg.codec} if cfg.codec else {}
    arrays = {name: sc.frame_array(name, **spec, **extra) for name, spec in specs.items()}
    sc.set_attrs({"gt": attrs})
    first = arrays[GT_RANGE]
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
    helper_info = None
    if client is not None:
        if n_traced:
            dask_info = trace_scene_dask(client, sc, mesh, cfg, traj, human, plan, quiet=quiet, label=label,
                                         cycles=cycles)
        for a in arrays.values():  # fold the workers' manifest records into attrs (idempotent)
            a._consolidate()
    elif workers == 1 or n_traced == 0:
        own = Helper(mesh, cfg, traj, human, cycles) \
            if helper is None and n_traced and auto_helper(n_traced, processes, cfg.backend) else None
        helper = helper or own
        try:
            tracer = FrameTracer(mesh, cfg, traj, human, cycles) if n_traced else None
            todo = [f for _, _, frames in plan for f in frames]
            threads = min(2, cpus())
            results = (iter(()) if tracer is None else run_with_helper(tracer, todo, threads, helper) if helper
                       else tracer.run(todo, threads=threads))
            try:
                _write_plan(plan, results, arrays, specs, quiet, label, first.n_shards, clock, copy=False)
            finally:
                getattr(results, "close", lambda: None)()   # stop the tracing threads before the helper goes
        finally:
            if own is not None:
                own.close()
        if helper is not None and n_traced:
            workers, helper_info = 2, helper.method
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
            "frames_traced": n_traced, "processes": workers, "helper": helper_info, **extra_info, "seconds": round(dt, 3),
            "frames_per_s": round(n_traced / dt, 3) if n_traced and dt > 0 else None,
            "first_frame_s": round(clock["first"] - t0, 3) if "first" in clock else None}


def _write_plan(plan, results, arrays, specs, quiet, label, n_shards, clock: dict | None = None,
                copy: bool = True) -> None:
    """Write the shards of ``plan`` from per-frame ``results`` (dicts of gt arrays, in plan order).
    ``copy``: gather each shard into one array per name (results are views into reused
    shared-memory slots); else hand the writer the frames' own arrays, which it encodes frame by
    frame (in-process results are fresh per frame: no gathering copy), and the shard is written by a
    background thread while the next shard is traced (Blosc, sha256 and file writes release the GIL,
    so writing runs on the core the tracer's single-threaded parts leave idle)."""
    results = iter(results)
    writer = None if copy else ThreadPoolExecutor(1, thread_name_prefix="holodata-gt-writer")
    prev = None  # the shard being written in the background
    try:
        for k, todo, frames in track(plan, total=len(plan), description=label, quiet=quiet, unit="shards"):
            if copy:
                bufs = {name: np.empty((len(frames),) + tuple(specs[name]["per_frame_shape"]),
                                       dtype=specs[name]["dtype"]) for name in todo}
            else:
                bufs = {name: [None] * len(frames) for name in todo}
            for i in range(len(frames)):
                out = next(results)
                if clock is not None and "first" not in clock:
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


def raytrace_standalone(mesh_path: str | Path, poses_path: str | Path, out: str, *,
                        human: str | Path | HumanSource | None = None, human_dir: str | Path | None = None,
                        scene_id: str = "scene", cfg: GTConfig | None = None, quiet: bool = True, processes: int = 0,
                        client=None, rotation_hz: float | None = None) -> dict:
    """``holodata raytrace-gt --mesh --poses --out``: validate all inputs, then write a docs/format.md §3 dataset
    (time/timestamp_ns, pose/T_world_radar, mesh/*, gt/*). Resumable: rerunning skips done shards.
    ``human``: one mesh file for every frame, or (Python API) any :class:`HumanSource`, e.g. a
    dataset scene's per-frame surfaces (:class:`HumanDataset`) indexed by the TUM rows.
    ``rotation_hz``: the radar's rotation rate for per-column times (None: each frame's columns span
    the time to the next frame; :func:`standalone_cycles`)."""
    cfg = cfg or GTConfig()
    from .raytrace import available_backends

    if cfg.backend not in available_backends():
        raise InputError(f"ray-tracing backend {cfg.backend!r} is not available (have: {', '.join(available_backends())})")
    if human is not None and human_dir is not None:
        raise InputError("give either --human or --human-dir, not both")
    check_name(scene_id, "--scene-id")   # names folders/keys under the output: never outside it
    mesh = read_mesh(mesh_path)
    traj = read_tum(poses_path)
    origin = cfg.origin or OriginModel()
    cycles, columns = None, None
    if origin.column_time:
        cycles, columns = standalone_cycles(traj, rotation_hz, str(poses_path))
    hsrc: HumanSource = HumanSource()
    if isinstance(human, HumanSource):
        hsrc = human
    elif human is not None:
        hsrc = HumanFile(human)
    elif human_dir is not None:
        hsrc = HumanDir(human_dir, len(traj))
    mesh_args = (mesh.vertices, mesh.faces, mesh.face_class, mesh.class_names)
    scene = _make_scene(*mesh_args, cfg)
    # inputs are valid: the helper process starts now (forked before this process casts, with the
    # compiled kernels the scene loaded), so that its start-up overlaps the output's creation
    helper = Helper(mesh_args, cfg, traj, hsrc, cycles) \
        if client is None and auto_helper(len(traj), processes, cfg.backend) else None
    try:
        return _standalone(mesh_path, poses_path, out, mesh, mesh_args, scene, traj, hsrc, cycles, columns, origin,
                           scene_id, cfg, quiet, processes, client, helper)
    finally:
        if helper is not None:
            helper.close()


def _standalone(mesh_path, poses_path, out, mesh, mesh_args, scene, traj, hsrc, cycles, columns, origin, scene_id, cfg,
                quiet, processes, client, helper) -> dict:
    # only now create (or reopen) the output
    from .dataset import create_dataset

    mhash = file_sha256(mesh_path) if Path(mesh_path).is_file() else mesh_sha256(mesh.vertices, mesh.faces)
    w = create_dataset(out, grid=cfg.grid, range_bins=RangeBins(), created_by="holodata raytrace-gt",
                       provenance={"mesh": str(mesh_path), "mesh_sha256": mhash, "poses": str(poses_path),
                                   "poses_sha256": file_sha256(poses_path)},
                       shard_frames=cfg.shard_frames or 32)
    T = len(traj)
    # marked unfinished in the put that makes (or reopens) the scene; finished after the last gt shard
    sc = w.scene(scene_id, n_frames=T, attrs={"frame_sensor": "radar", "source": "raytrace-gt standalone"},
                 stage="raytrace-gt", rerun="rerun the same holodata raytrace-gt --mesh ... --poses ... --out command "
                                            "to finish it")
    _write_frame_meta(sc, traj, cycles)
    sc.write_array(MESH_VERTICES, mesh.vertices)
    sc.write_array(MESH_FACES, mesh.faces)
    if mesh.face_class is not None:
        sc.write_array(MESH_FACE_CLASS, mesh.face_class)
    attrs = gt_attrs(scene, cfg, mhash, hsrc, column_times=columns)
    summary = write_scene_gt(sc, mesh_args, cfg, traj, hsrc, attrs, quiet=quiet, processes=processes, client=client,
                             cycles=cycles, helper=helper)
    sc.finish("raytrace-gt")
    return {"out": str(out), "scenes": [{"scene": scene_id, "origin_model": origin.describe(),
                                         "column_times": columns, **summary}]}


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
        summary = write_scene_gt(sc, mesh_args, scfg, traj, hsrc, attrs, quiet=quiet, label=f"raytrace-gt {sid}",
                                 processes=processes, client=client, cycles=cycles)
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


__all__ = ["OriginModel", "GTConfig", "beam_rays", "column_times", "column_rays_soa", "points_to_mesh", "trace_frame",
           "write_scene_gt", "trace_shard", "FrameTracer", "gt_array_specs", "gt_attrs", "raytrace_standalone",
           "raytrace_dataset", "standalone_cycles",
           "HumanSource", "HumanDir", "HumanFile", "HumanDataset", "GT_ARRAYS", "TracingError",
           "MESH_EXTS", "HUMAN_SPLAT_RADIUS_M", "file_sha256", "mesh_sha256", "auto_processes", "POOL_MIN_FRAMES",
           "auto_helper", "HELPER_MIN_FRAMES", "HELPER_SPAWN_MIN_FRAMES"]
