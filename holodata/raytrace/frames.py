"""raytrace-gt's per-frame ground truth: the configuration, each frame's beams, the trace of one
frame into the gt/* layout (docs/format.md §2-§4) and the scene attrs saying how it was traced.

:class:`FrameTracer` (a static :class:`~holodata.raytrace.RayScene` built once, the human of each
frame) is what every executor runs: in-process, in the local process pool
(:mod:`holodata.raytrace.pool`) and in Dask tasks (:mod:`holodata.groundtruth`).
"""
from __future__ import annotations

import threading
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from itertools import islice

import numpy as np

from ..beams import OriginModel, beam_rays, column_poses, local_origins
from ..conventions import DEFAULT_MAX_BOUNCES, DEFAULT_MAX_RANGE_M, LOS_TOLERANCE_M, Grid
from ..dataset.layout import GT_ARRAYS, GT_HUMAN_CENTER, GT_LABEL, GT_NORMAL, GT_POINT, GT_RANGE, GT_SEMANTIC, RADAR_CYCLE_NS
from ..errors import InputError
from ..trajectory import Trajectory
from . import _kernels
from .humans import HumanSource
from .trace import RayScene


@dataclass
class GTConfig:
    grid: Grid = field(default_factory=Grid)
    max_bounces: int = DEFAULT_MAX_BOUNCES
    max_range: float = DEFAULT_MAX_RANGE_M
    backend: str = "open3d"
    origin: OriginModel | None = None  # None: the scene's recorded model (ingest), else the default
    shard_frames: int | None = None  # frames per shard of new arrays (None: the dataset's, 32 when new)
    nthreads: int = 0
    codec: str | None = "lz4"  # Blosc codec of the gt arrays: lz4 encodes faster than zstd, larger output
                               # (raytrace-gt is CPU-bound, docs/design/performance.md;
                               # None = the dataset's default, zstd)


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
        _GRID_DIRS[grid] = np.ascontiguousarray(grid.directions(), dtype=np.float64)
    return _GRID_DIRS[grid]


def column_rays_soa(grid: Grid, origin: OriginModel, col: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`holodata.beams.beam_rays` with ``column_poses`` = ``col`` (W,4,4), as (3, H*W) float32
    origins and directions, equal to the bit to ``beam_rays``'s float64 arrays cast to float32.

    beam_rays's ``einsum("wij,hwj->hwi")`` is slow per frame; the same float64 products summed
    in the same order, ``(R_i0 d_0 + R_i2 d_2) + R_i1 d_1`` (numpy's einsum order for this
    contraction; tests/test_groundtruth.py checks it), cost a fraction of it in numpy, less in a
    compiled loop (:func:`holodata.raytrace._kernels.column_dirs`; docs/design/raytrace.md, "Per-column
    beams", and docs/design/performance.md)."""
    H, W = grid.H, grid.W
    R, t = col[:, :3, :3], col[:, :3, 3]
    o = np.einsum("wij,wj->wi", R, local_origins(grid, origin)) + t  # (W,3), as beam_rays
    dirs = _grid_dirs(grid)
    d = np.empty((3, H, W), dtype=np.float32)
    _kernels.column_dirs(np.ascontiguousarray(R), dirs, d)  # the sum below in one compiled pass, to the bit
    # numpy: d[i] = (R[None, :, i, 0] * dirs[..., 0] + R[None, :, i, 2] * dirs[..., 2]) + R[None, :, i, 1] * dirs[..., 1]
    o32 = np.ascontiguousarray(np.broadcast_to(o.T.astype(np.float32)[:, None, :], (3, H, W)))
    return o32.reshape(3, H * W), d.reshape(3, H * W)


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
        GT_RANGE: res.range.T.reshape(B, H, W),
        GT_NORMAL: _half(res.normal.transpose(1, 0, 2)).reshape(B, H, W, 3),
        GT_POINT: res.point.transpose(1, 0, 2).reshape(B, H, W, 3),
        GT_LABEL: res.label.T.reshape(B, H, W),
        GT_SEMANTIC: res.semantic.T.reshape(B, H, W),
        GT_HUMAN_CENTER: center,
    }


def _half(a: np.ndarray) -> np.ndarray:
    """``a.astype(np.float16)``, to the bit; for a C-contiguous float32 array in one compiled pass
    (:func:`holodata.raytrace._kernels.to_half`)."""
    if a.dtype != np.float32 or not a.flags.c_contiguous:
        return a.astype(np.float16)
    out = np.empty(a.shape, np.float16)
    _kernels.to_half(a.reshape(-1), out.reshape(-1).view(np.uint16))
    return out


def gt_array_specs(grid: Grid, B: int) -> dict:
    """{name: frame_array arguments} of the gt arrays (:data:`holodata.dataset.layout.GT_ARRAYS`) for
    ``B`` bounces on ``grid``; one human centre per frame."""
    from ..dataset.layout import LAYOUT

    out = {}
    for name in GT_ARRAYS:
        s = LAYOUT[name]
        out[name] = dict(per_frame_shape=s.per_frame(B=B, H=grid.H, W=grid.W, K=1), dtype=s.dtype, dims=list(s.dims),
                         units=s.units, fill_value=s.fill)
    return out


def gt_attrs(scene, cfg: GTConfig, mesh_hash: str, human: HumanSource, origin_source: str | None = None,
             cycles: bool = False, column_times: str | None = None) -> dict:
    """Scene attrs ``gt``: how the ground truth was traced. ``origin_source``: where the beam-origin
    model came from ("flags", "recording" or "default"; :func:`holodata.beams.scene_origin_model`);
    ``cycles``: column times were taken from radar/cycle_ns; ``column_times``: else the model that
    gave them (the standalone form's, :func:`holodata.groundtruth.standalone_cycles`), default the
    frame stamp as the middle of a ``rotation_hz`` rotation."""
    origin = cfg.origin or OriginModel()
    if not origin.column_time:
        columns = None
    elif cycles:
        columns = RADAR_CYCLE_NS
    else:
        columns = column_times or f"frame stamps (the middle of a {origin.rotation_hz:g} Hz rotation)"
    return {
        "backend": cfg.backend, "max_bounces": int(cfg.max_bounces), "max_range_m": float(cfg.max_range),
        "origin_model": origin.to_attrs(),
        "origin_source": origin_source or ("flags" if cfg.origin is not None else "default"),
        "column_times_from": columns,
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
        vertices, faces, face_class, class_names = mesh
        self.scene = _make_scene(vertices, faces, face_class, class_names, cfg)
        self.cfg, self.traj, self.human, self.cycles = cfg, traj, human, cycles
        self._last = (None, None)
        self._lock = threading.Lock()

    def __call__(self, f: int) -> dict:
        return self._trace(f, *self._human(f))

    def run(self, frames, threads: int = 2) -> Iterator[dict]:
        """Each frame's gt dict (as ``self(f)``), in the order of ``frames``, traced by ``threads``
        threads, each frame in one of them. open3d's casts hold the GIL (and use every core); the
        compiled kernels and numpy's loops release it, so one frame's kernels run while another
        frame's rays are cast, and the core a single frame leaves idle between its casts is used.
        Each frame's trace is the one ``self(f)`` computes (nothing shared is written but the
        scene's per-thread ray buffer), so the results are the same to the bit."""
        if threads <= 1:
            yield from (self(f) for f in frames)
            return
        from collections import deque

        it = iter(frames)
        with ThreadPoolExecutor(threads, thread_name_prefix="holodata-gt-trace") as ex:
            pending: deque = deque(ex.submit(self, f) for f in islice(it, threads))
            while pending:
                out = pending.popleft().result()
                f = next(it, None)
                if f is not None:
                    pending.append(ex.submit(self, f))
                yield out

    def _human(self, f: int) -> tuple:
        """(human (vertices, faces), its prepared dynamic geometry) of frame ``f``, or (None, None).
        One thread at a time: a human source (a dataset reader, a user's class) need not be
        thread-safe, and reading it holds the GIL anyway."""
        with self._lock:
            h = self.human(f)
            if h is None:
                return None, None
            last = self._last
            if h is not last[0]:  # build the human BVH once per distinct mesh
                last = self._last = (h, self.scene.prepare_dynamic(*h))
        return h, last[1]

    def _trace(self, f: int, h, dyn) -> dict:
        if h is None:
            return trace_frame(self.scene, self.cfg, self.traj, f, None, cycles=self.cycles)
        return trace_frame(self.scene, self.cfg, self.traj, f, dyn, human_vertices=h[0], cycles=self.cycles)


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


def _make_scene(vertices, faces, face_class, class_names, cfg: GTConfig):
    try:
        return RayScene(vertices, faces, backend=cfg.backend, face_class=face_class, class_names=class_names,
                        nthreads=cfg.nthreads)
    except ValueError as err:
        raise InputError(f"scene mesh: {err}") from err


__all__ = ["GTConfig", "column_rays_soa", "trace_frame", "gt_array_specs", "gt_attrs", "FrameTracer", "trace_shard"]
