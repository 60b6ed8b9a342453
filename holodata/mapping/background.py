"""Voxel background model of the static scene (Ouster OS0 instance-segmentation method).

The world is cut into cubic voxels of edge ``voxel`` (default 15 cm). A voxel is *background*
(static structure) when LiDAR returns fall into it in at least ``min_fraction`` of the scans
that observed it; moving things (people) occupy any one voxel only in a few scans and stay out.
A point is background when any voxel of its 3×3×3 neighbourhood is (1-voxel tolerance), which
absorbs range noise and small pose errors at voxel borders.

"Observed" is approximated by the scans whose returns come within ``observe_radius`` (m) of the
voxel — cheap and adequate for corners where every scan sees most of the scene; with
``min_fraction=0`` every voxel with at least ``min_hits`` returns counts.

Used by :mod:`holodata.mapping.mesh` (remove dynamic points before meshing) and by the human
segmentation (foreground = returns outside the background).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError

_OFFS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)], np.int64)
_BIAS = 1 << 20        # voxel indices shifted to be non-negative (|index| < 2^20 voxels ≈ 157 km at 15 cm)
_BITS = 21


def _keys(ijk: np.ndarray) -> np.ndarray:
    """Pack (N,3) int voxel indices into (N,) int64 keys (21 bits per axis)."""
    u = (np.asarray(ijk, np.int64) + _BIAS)
    return (u[:, 0] << (2 * _BITS)) | (u[:, 1] << _BITS) | u[:, 2]


def _unkeys(keys: np.ndarray) -> np.ndarray:
    m = (1 << _BITS) - 1
    k = np.asarray(keys, np.int64)
    return np.stack([(k >> (2 * _BITS)) & m, (k >> _BITS) & m, k & m], 1) - _BIAS


def voxel_index(points: np.ndarray, voxel: float) -> np.ndarray:
    """(N,3) float points (m) → (N,3) int64 voxel indices ``floor(p / voxel)``."""
    return np.floor(np.asarray(points, np.float64) / voxel).astype(np.int64)


@dataclass
class VoxelBackground:
    """Set of static voxels. ``voxel`` edge (m); ``keys`` sorted unique int64 keys of background
    voxels; ``dilated`` sorted keys of background voxels grown by one voxel (the tolerance used by
    :meth:`contains`); ``hits`` (len(keys),) scans in which each background voxel was occupied;
    ``n_scans`` scans used to build."""

    voxel: float
    keys: np.ndarray
    dilated: np.ndarray
    hits: np.ndarray
    n_scans: int

    @classmethod
    def build(cls, points_world: list[np.ndarray], voxel: float = 0.15, min_fraction: float = 0.25,
              min_hits: int = 2, observe_radius: float | None = None) -> "VoxelBackground":
        """Background from world-frame scans ``points_world`` (list of (Ni,3), m).

        A voxel is static when it is occupied in ``>= min_hits`` scans and in ``>= min_fraction`` of
        the scans that observed its neighbourhood (a scan with a return within ``observe_radius``,
        default 3 voxels). Scans with fewer than 2 scans in total: every occupied voxel is static.
        """
        if voxel <= 0 or not np.isfinite(voxel):
            raise InputError(f"background voxel must be > 0 m, got {voxel}")
        if not 0.0 <= min_fraction <= 1.0:
            raise InputError(f"background min_fraction must be in [0, 1], got {min_fraction}")
        per_scan = []
        for i, p in enumerate(points_world):
            p = np.asarray(p, np.float64).reshape(-1, 3)
            p = p[np.isfinite(p).all(1)]
            per_scan.append(np.unique(_keys(voxel_index(p, voxel))))
        n = len(per_scan)
        if n == 0 or sum(len(k) for k in per_scan) == 0:
            empty = np.zeros(0, np.int64)
            return cls(float(voxel), empty, empty, empty, n)
        allk = np.concatenate(per_scan)
        keys, occ = np.unique(allk, return_counts=True)
        need_hits = min(int(min_hits), n)
        if n >= 2 and min_fraction > 0:
            r = max(1, int(np.ceil((observe_radius if observe_radius is not None else 3 * voxel) / voxel)))
            # coarse "observed" grid: a scan observes every coarse cell it has a return in (plus neighbours)
            coarse_obs = np.zeros(len(keys), np.int64)
            cidx = _unkeys(keys) // (r + 1)
            ckeys = _keys(cidx)
            for k in per_scan:
                c = np.unique(_keys(_unkeys(k) // (r + 1)))
                grown = np.unique((_keys(_unkeys(c)[:, None, :].repeat(27, 1).reshape(-1, 3)
                                         + np.tile(_OFFS, (len(c), 1)))))
                coarse_obs += np.isin(ckeys, grown)
            frac = occ / np.maximum(coarse_obs, 1)
            static = (occ >= need_hits) & (frac >= min_fraction)
        else:
            static = occ >= need_hits
        keys, hits = keys[static], occ[static]
        return cls(float(voxel), keys, _dilate(keys), hits.astype(np.int64), n)

    def contains(self, points_world: np.ndarray) -> np.ndarray:
        """(N,3) world points → (N,) bool, True = static background (within one voxel of a
        background voxel). Non-finite points are False."""
        p = np.asarray(points_world, np.float64).reshape(-1, 3)
        out = np.zeros(len(p), bool)
        if len(self.dilated) == 0 or len(p) == 0:
            return out
        ok = np.isfinite(p).all(1)
        k = _keys(voxel_index(p[ok], self.voxel))
        pos = np.searchsorted(self.dilated, k)
        pos = np.minimum(pos, len(self.dilated) - 1)
        out[ok] = self.dilated[pos] == k
        return out

    def centers(self) -> np.ndarray:
        """(V,3) float64 centres (m) of the background voxels."""
        return (_unkeys(self.keys) + 0.5) * self.voxel

    def __len__(self) -> int:
        return len(self.keys)


def _dilate(keys: np.ndarray) -> np.ndarray:
    if len(keys) == 0:
        return keys
    ijk = _unkeys(keys)
    out = [np.unique(_keys(ijk + o)) for o in _OFFS]
    return np.unique(np.concatenate(out))


__all__ = ["VoxelBackground", "voxel_index"]
