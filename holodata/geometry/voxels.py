"""Voxel grids of point clouds: integer voxel indices, packed int64 keys, dense-box cell indices, one
point per voxel and voxel means.

A voxel of edge ``voxel`` (m) holds the points with ``floor(p / voxel) == (i, j, k)`` (computed in
float64, :func:`voxel_index`). Sets of voxels are kept as sorted unique int64 keys (:func:`voxel_keys`:
21 bits per axis, indices biased to be non-negative), which sort like C-order flat indices of any box
that holds them (:func:`flat_index`); a box of at most :data:`DENSE_MAX_CELLS` cells (:func:`dense_box`)
is counted with ``bincount`` instead of sorting keys. No I/O, numpy only.
"""
from __future__ import annotations

import numpy as np

BIAS = 1 << 20         # voxel indices shifted to be non-negative (|index| < 2^20 voxels ≈ 157 km at 15 cm)
BITS = 21              # bits per axis of a packed key
DENSE_MAX_CELLS = 1 << 24   # dense voxel grids (occupancy counts, lookups) up to this many cells (16.8 M)


def voxel_keys(ijk: np.ndarray) -> np.ndarray:
    """Pack (N,3) int voxel indices into (N,) int64 keys (21 bits per axis)."""
    u = (np.asarray(ijk, np.int64) + BIAS)
    return (u[:, 0] << (2 * BITS)) | (u[:, 1] << BITS) | u[:, 2]


def unpack_keys(keys: np.ndarray) -> np.ndarray:
    """(N,) int64 keys of :func:`voxel_keys` → (N,3) int64 voxel indices."""
    m = (1 << BITS) - 1
    k = np.asarray(keys, np.int64)
    return np.stack([(k >> (2 * BITS)) & m, (k >> BITS) & m, k & m], 1) - BIAS


def voxel_index(points: np.ndarray, voxel: float) -> np.ndarray:
    """(N,3) float points (m) → (N,3) int64 voxel indices ``floor(p / voxel)`` (computed in float64)."""
    q = np.divide(points, voxel, dtype=np.float64)
    return np.floor(q, out=q).astype(np.int64)


def dense_box(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(lo, dims) of the box of voxel indices ``lo`` .. ``hi`` (3,) int64 when a dense grid of it has at
    most :data:`DENSE_MAX_CELLS` cells; None when it is larger (then sorted keys are used)."""
    dims = hi - lo + 1
    return (lo, dims) if float(np.prod(dims.astype(np.float64))) <= DENSE_MAX_CELLS else None


def flat_index(ijk: np.ndarray, lo: np.ndarray, dims: np.ndarray) -> np.ndarray:
    """(N,) C-order flat cell index of voxel indices ``ijk`` (N,3) inside the box ``lo``, ``dims``; it
    sorts like :func:`voxel_keys`."""
    rel = ijk - lo
    return (rel[:, 0] * dims[1] + rel[:, 1]) * dims[2] + rel[:, 2]


def cell_keys(cells: np.ndarray, lo: np.ndarray, dims: np.ndarray) -> np.ndarray:
    """:func:`voxel_keys` of flat C-order cell indices ``cells`` of the box ``lo``, ``dims`` (sorted cells
    give sorted keys)."""
    return voxel_keys(np.stack(np.unravel_index(cells, tuple(dims)), 1) + lo)


def unique_voxels(ijk: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(voxel_keys(ijk), return_inverse=True)`` of (N,3) int voxel indices: sorted unique keys
    (V,) int64 and each row's position (N,) in them. On a dense grid of the indices' bounding box
    when it has at most :data:`DENSE_MAX_CELLS` cells (a C-order flat cell index sorts like the key;
    ``bincount`` instead of sorting the N keys), else by sorting."""
    if len(ijk) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    box = dense_box(ijk.min(0), ijk.max(0))
    if box is None:
        return np.unique(voxel_keys(ijk), return_inverse=True)
    lo, dims = box
    flat = flat_index(ijk, lo, dims)
    occ = np.bincount(flat, minlength=int(np.prod(dims)))
    cells = np.flatnonzero(occ)
    rank = np.zeros(len(occ), np.int32)
    rank[cells] = np.arange(len(cells))
    return cell_keys(cells, lo, dims), rank[flat]


def first_per_voxel(points: np.ndarray, voxel: float) -> np.ndarray:
    """Sorted indices (K,) int64 of one point per occupied ``voxel`` (m) of ``points`` (N,3): the first
    in input order (voxel-grid downsampling that keeps measured points, not means)."""
    if len(points) == 0:
        return np.zeros(0, np.int64)
    _, idx = np.unique(voxel_keys(voxel_index(points, voxel)), return_index=True)
    return np.sort(idx)


def voxel_average(points: np.ndarray, voxel: float) -> np.ndarray:
    """(V,3) float64 mean of the points (N,3) in each occupied voxel of edge ``voxel`` (m): open3d's
    ``voxel_down_sample`` (same grid, anchored half a voxel below the points' minimum; same means up to
    rounding) in voxel-key order instead of hash order."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    if len(p) == 0:
        return p.copy()
    lo = p.min(0) - voxel * 0.5
    ijk = np.floor((p - lo) / voxel).astype(np.int64)
    dims = ijk.max(0) + 1
    key = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    order = np.argsort(key, kind="stable")
    ks = key[order]
    start = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
    count = np.diff(np.r_[start, len(ks)])
    return np.add.reduceat(p[order], start, axis=0) / count[:, None]
