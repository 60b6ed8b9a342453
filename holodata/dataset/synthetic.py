"""A small, rule-abiding dataset filled with random values (tests, benchmarks, README smoke run).

Not physics: ranges are random but ordered (R1 < R2 < R3, NaN after the first missing bounce),
labels 1 (bounce 1) / 2 (later) where a range exists, normals random unit vectors, poses rigid.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..conventions import DEFAULT_MAX_RANGE_M, Grid, RangeBins
from .layout import (
    GT_LABEL,
    GT_NORMAL,
    GT_POINT,
    GT_RANGE,
    LIDAR_POINTS,
    MESH_FACES,
    MESH_VERTICES,
    POSE_T_WORLD_RADAR,
    RADAR_HEATMAP,
    TIME_TIMESTAMP_NS,
)
from .writer import create_dataset


def toy_frames(rng: np.random.Generator, frames: range, grid: Grid, n_bounces: int = 3, n_range: int = 16,
               heatmap_dtype="float16") -> dict:
    """gt/*, radar/heatmap, time and pose arrays for ``frames`` (frame axis first)."""
    n, H, W, B = len(frames), grid.H, grid.W, n_bounces
    steps = rng.uniform(0.3, 2.0, size=(n, B, H, W)).astype(np.float32)
    rng_ = np.cumsum(steps, axis=1)
    n_ret = rng.integers(0, B + 1, size=(n, 1, H, W))
    rng_[np.arange(B)[None, :, None, None] >= n_ret] = np.nan
    fin = np.isfinite(rng_)
    label = np.where(fin, np.where(np.arange(B)[None, :, None, None] == 0, 1, 2), 0).astype(np.uint8)
    nrm = rng.normal(size=(n, B, H, W, 3)).astype(np.float32)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    nrm[~fin] = np.nan
    pts = np.where(fin[..., None], rng.uniform(-5, 5, size=(n, B, H, W, 3)), np.nan).astype(np.float32)
    f = np.asarray(frames)
    th = 0.05 * f
    poses = np.zeros((n, 4, 4))
    poses[:, 0, 0] = poses[:, 1, 1] = np.cos(th)
    poses[:, 0, 1], poses[:, 1, 0] = -np.sin(th), np.sin(th)
    poses[:, 2, 2] = poses[:, 3, 3] = 1.0
    poses[:, 0, 3] = 0.1 * f
    heat = np.abs(rng.normal(size=(n, n_range, H, W))).astype(heatmap_dtype)
    return {GT_RANGE: rng_, GT_LABEL: label, GT_NORMAL: nrm.astype(np.float16), GT_POINT: pts,
            RADAR_HEATMAP: heat, TIME_TIMESTAMP_NS: (10**9 + f * 500_000_000).astype(np.int64),
            POSE_T_WORLD_RADAR: poses}


def array_specs(grid: Grid, n_range: int, n_bounces: int = 3, heatmap_dtype="float16") -> dict:
    H, W, B = grid.H, grid.W, n_bounces
    return {   # dtypes, dims and units: the layout's (the heatmap's dtype is one of the two it allows)
        TIME_TIMESTAMP_NS: dict(per_frame_shape=()),
        POSE_T_WORLD_RADAR: dict(per_frame_shape=(4, 4)),
        RADAR_HEATMAP: dict(per_frame_shape=(n_range, H, W), dtype=heatmap_dtype),
        GT_RANGE: dict(per_frame_shape=(B, H, W)),
        GT_LABEL: dict(per_frame_shape=(B, H, W)),
        GT_NORMAL: dict(per_frame_shape=(B, H, W, 3)),
        GT_POINT: dict(per_frame_shape=(B, H, W, 3)),
    }


@dataclass
class ToyContents:
    """What a toy dataset holds beyond its scenes and frames: the beam ``grid`` (None: 8x32),
    ``n_range`` range bins over the radar's range, the frame ``arrays`` written (None: all of
    :func:`array_specs`), LiDAR points or not (``lidar``), and the ``codec`` of its shards."""

    grid: Grid | None = None
    n_range: int = 16
    arrays: list[str] | None = None
    lidar: bool = True
    codec: str = "zstd"


def write_toy_dataset(url, n_frames: int = 10, shard_frames: int = 4, scenes=("c1",), seed: int = 0,
                      contents: ToyContents | None = None) -> str:
    """Write a valid dataset with ``scenes`` of ``n_frames`` frames each (``shard_frames`` per shard;
    random values drawn from ``seed``), holding ``contents`` (default :class:`ToyContents`); returns ``url``."""
    c = contents or ToyContents()
    grid, n_range = c.grid or Grid(8, 32), c.n_range
    rb = RangeBins(n=n_range, dr=DEFAULT_MAX_RANGE_M / n_range)   # the radar's range, in n_range bins
    w = create_dataset(url, grid=grid, range_bins=rb, created_by="holodata toy dataset",
                       provenance={"generator": "holodata.dataset.synthetic", "seed": seed},
                       shard_frames=shard_frames, codec=c.codec)
    rng = np.random.default_rng(seed)
    specs = array_specs(grid, n_range)
    names = c.arrays or list(specs)
    w.begin("toy dataset", rerun="write the toy dataset again")   # the root: until its splits
    for i, sid in enumerate(scenes):
        sc = w.scene(sid, n_frames=n_frames, attrs={"corner_type": ["L", "T", "cross", "oblique"][i % 4],
                                                    "width_m": 1.0 + i, "frame_sensor": "radar",
                                                    "source": {"recording": f"{sid}.mcap", "sha256": "0" * 64}},
                     stage="toy dataset", rerun="write the toy dataset again")
        arrs = {n: sc.frame_array(n, **specs[n]) for n in names}
        first = arrs[names[0]]
        for k in range(first.n_shards):
            fr = first.frames(k)
            data = toy_frames(rng, range(fr.start, fr.stop), grid, n_range=n_range)
            for n, a in arrs.items():
                a.write_shard(k, data[n])
        sc.write_array(MESH_VERTICES, rng.uniform(-5, 5, (12, 3)))
        sc.write_array(MESH_FACES, rng.integers(0, 12, (20, 3)))
        if c.lidar:
            rag = sc.ragged_array(LIDAR_POINTS)
            for k in range(rag.n_shards):
                fr = rag.frames(k)
                rag.write_shard(k, [rng.normal(size=(int(rng.integers(0, 50)), 3)).astype(np.float32)
                                    for _ in range(fr.start, fr.stop)])
        sc.finish("toy dataset")
    w.set_splits(train=list(scenes[:-1]) or list(scenes), test=list(scenes[-1:]))
    w.finish("toy dataset")
    return str(url)
