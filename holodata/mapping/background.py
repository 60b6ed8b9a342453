"""Voxel background model of the static scene (Ouster OS0 instance-segmentation method).

The world is cut into cubic voxels of edge ``voxel`` (default 15 cm). A voxel is *background*
(static structure) when LiDAR returns fall into it in at least ``min_fraction`` of the scans
that observed it; moving things (people) occupy any one voxel only in a few scans and stay out.
A point is background when any voxel of its 3×3×3 neighbourhood is (1-voxel tolerance), which
absorbs range noise and small pose errors at voxel borders.

With the sensor origins of the scans, "observed" is decided by free-space reasoning (a scan that
sees *through* a voxel observed it empty); without them, by the scans whose returns come within
``observe_radius`` (m) of the voxel. With ``min_fraction=0`` every voxel with at least
``min_hits`` returns counts.

Used by :mod:`holodata.mapping.mesh` (remove dynamic points before meshing) and by the human
segmentation (foreground = returns outside the background).

Indoor scenes fit a dense grid of voxels (at most ``DENSE_MAX_CELLS`` of :mod:`holodata.geometry.voxels`,
16.8 M: a 60×60×7 m box at 15 cm): the occupancy count is one ``count[cells] += 1`` per scan (a cell counts once per scan) and
lookups index a boolean grid, instead of sorting keys per scan and binary searches (the same model, faster:
docs/design/performance.md); larger boxes use the sorted keys.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..geometry.voxels import cell_keys, dense_box, flat_index, unpack_keys, voxel_index, voxel_keys

# a return within max(voxel, this × range) of a voxel's centre along its ray occupies it; beyond, it
# sees through it: the LiDAR's range error and the ray's footprint grow with range
FREE_SPACE_RANGE_SHARE = 0.02
_OFFS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)], np.int64)


def _finite_rows(p: np.ndarray) -> np.ndarray:
    """(N,) bool: rows of (N,3) ``p`` with three finite coordinates (``isfinite(p).all(1)``, faster)."""
    f = np.isfinite(p)
    return f[:, 0] & f[:, 1] & f[:, 2]


def _occupancy(pts: list, voxel: float, need_inverse: bool = False, need_per_scan: bool = False):
    """Voxels occupied by finite point sets ``pts`` (list of (Ni,3) float, m): (sorted unique keys (V,)
    int64, occ (V,) int64 = in how many sets each voxel has points, per-point position in ``keys`` per
    set (list of (Ni,) int arrays, or None), sorted unique keys per set (list, or None)). The same as
    ``np.unique`` over the sets' unique keys, computed on a dense grid of the points' bounding box
    (``occ[cells] += 1`` counts a cell once per set, no sort) when it has at most
    ``DENSE_MAX_CELLS`` (:mod:`holodata.geometry.voxels`) cells, else with sorted keys."""
    nz = [p for p in pts if len(p)]
    # per column: (N,3).min(0) is slower (docs/design/performance.md)
    lo = np.floor(np.divide([min(p[:, j].min() for p in nz) for j in range(3)], voxel, dtype=np.float64)).astype(np.int64)
    hi = np.floor(np.divide([max(p[:, j].max() for p in nz) for j in range(3)], voxel, dtype=np.float64)).astype(np.int64)
    box = dense_box(lo, hi)
    if box is not None:
        dims = box[1]
        cnt = np.zeros(int(np.prod(dims)), np.int32)
        flats = []
        step = np.array([dims[1] * dims[2], dims[2], 1], np.float64)
        for p in pts:
            q = np.divide(p, voxel, dtype=np.float64)
            np.floor(q, out=q)                       # voxel_index, kept in float64: integers, exact below 2^53
            q -= lo                                  # floor is monotonic: every point is inside the box
            f = (q @ step).astype(np.int32)          # flat C-order cell index
            cnt[f] += 1                                          # buffered: +1 per cell and set
            flats.append(f if (need_inverse or need_per_scan) else None)
        cells = np.flatnonzero(cnt)
        occ = cnt[cells].astype(np.int64)
        keys = cell_keys(cells, lo, dims)
        per_scan = [keys[np.searchsorted(cells, np.unique(f))] for f in flats] if need_per_scan else None
        inv = None
        if need_inverse:
            cnt[cells] = np.arange(len(cells), dtype=np.int32)
            inv = [cnt[f] for f in flats]
        return keys, occ, inv, per_scan
    pk = [voxel_keys(voxel_index(p, voxel)) for p in pts]
    per_scan = [np.unique(k) for k in pk]
    keys, occ = np.unique(np.concatenate(per_scan), return_counts=True)
    inv = [np.searchsorted(keys, k) for k in pk] if need_inverse else None
    return keys, occ, inv, per_scan if need_per_scan else None


@dataclass
class VoxelBackground:
    """Set of static voxels. ``voxel`` edge (m); ``keys`` sorted unique int64 keys of background
    voxels; ``dilated`` sorted keys of background voxels grown by one voxel (the tolerance used by
    :meth:`contains`); ``hits`` (len(keys),) scans in which each background voxel was occupied;
    ``n_scans`` scans used to build; ``floor`` optional floor plane [a, b, c] (``z = a·x + b·y + c``,
    world frame) set by the human segmentation (:func:`holodata.mapping.segment.floor_plane`), None
    otherwise — :meth:`contains` does not use it."""

    voxel: float
    keys: np.ndarray
    dilated: np.ndarray
    hits: np.ndarray
    n_scans: int
    floor: np.ndarray | None = None
    # dense lookup grids of keys / dilated (built at the first lookup, so keys are not to be edited after
    # it; False: too large, sorted keys instead)
    _grids: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @classmethod
    def build(cls, points_world: list[np.ndarray], voxel: float = 0.15, min_fraction: float = 0.25,
              min_hits: int = 2, origins: list | np.ndarray | None = None, observe_radius: float | None = None,
              angle_res_deg: float = 0.5, max_scans: int = 80) -> VoxelBackground:
        """Background from world-frame scans ``points_world`` (list of (Ni,3), m).

        With ``origins`` (the sensor position (3,) of each scan, world frame) — free-space test: each
        voxel (at the centroid of its returns) is looked up in a spherical min-range image (``angle_res_deg``
        bins) of up to ``max_scans`` scans; a scan *sees it occupied* when its range there is within a
        margin of the voxel's distance (1 voxel, or 2 % of the range) and *sees through it* (free)
        when the range is longer. Static = occupied in ``>= min_hits`` scans and
        occupied/(occupied + free) ``>= min_fraction`` (voxels never seen through are static).
        People who walk through a voxel are seen through it in the other scans and drop out
        (limit: a trail that stays hidden behind the walker — someone walking straight at the sensor
        for the whole recording — is never seen through and stays).

        Without ``origins`` — occupancy count: static = occupied in ``>= min_hits`` scans and in
        ``>= min_fraction`` of the scans with returns within ``observe_radius`` (default 3 voxels).
        """
        if voxel <= 0 or not np.isfinite(voxel):
            raise InputError(f"background voxel must be > 0 m, got {voxel}")
        if not 0.0 <= min_fraction <= 1.0:
            raise InputError(f"background min_fraction must be in [0, 1], got {min_fraction}")
        if origins is not None and len(origins) != len(points_world):
            raise InputError(f"background: {len(origins)} origins for {len(points_world)} scans")
        pts = []
        for p in points_world:
            p = np.asarray(p).reshape(-1, 3)
            if p.dtype not in (np.float32, np.float64):
                p = p.astype(np.float64)
            ok = _finite_rows(p)
            pts.append(p if ok.all() else p[ok])       # no copy of the (usual) all-finite scan
        n = len(pts)
        if n == 0 or sum(len(p) for p in pts) == 0:
            empty = np.zeros(0, np.int64)
            return cls(float(voxel), empty, empty, empty, n)
        free_space = origins is not None and n >= 2 and min_fraction > 0
        keys, occ, inv, per_scan = _occupancy(pts, voxel, need_inverse=free_space,
                                              need_per_scan=not free_space and n >= 2 and min_fraction > 0)
        need_hits = min(int(min_hits), n)
        if free_space:
            # the voxels' centroids, summed scan by scan: concatenating every scan's points and voxel
            # positions first costs far more in fresh memory (docs/design/performance.md)
            V = len(keys)
            sums, cnt = np.zeros((V, 3)), np.zeros(V)
            for p, i in zip(pts, inv):
                cnt += np.bincount(i, minlength=V)
                for j in range(3):
                    sums[:, j] += np.bincount(i, p[:, j], V)
            cen = sums / np.maximum(cnt, 1)[:, None]
            del inv, sums
            seen_occ, seen_free = _free_space(pts, np.asarray(origins, np.float64).reshape(-1, 3), cen, voxel,
                                              angle_res_deg, max_scans)
            tot = seen_occ + seen_free
            frac = np.where(tot > 0, seen_occ / np.maximum(tot, 1), 1.0)
            static = (occ >= need_hits) & (frac >= min_fraction)
        elif n >= 2 and min_fraction > 0:
            r = max(1, int(np.ceil((observe_radius if observe_radius is not None else 3 * voxel) / voxel)))
            coarse_obs = np.zeros(len(keys), np.int64)
            ckeys = voxel_keys(unpack_keys(keys) // (r + 1))
            for k in per_scan:
                c = unpack_keys(np.unique(voxel_keys(unpack_keys(k) // (r + 1))))
                grown = np.unique(voxel_keys((c[:, None, :] + _OFFS[None, :, :]).reshape(-1, 3)))
                coarse_obs += np.isin(ckeys, grown)
            frac = occ / np.maximum(coarse_obs, 1)
            static = (occ >= need_hits) & (frac >= min_fraction)
        else:
            static = occ >= need_hits
        keys, hits = keys[static], occ[static]
        return cls(float(voxel), keys, _dilate(keys), hits.astype(np.int64), n)

    def contains(self, points_world: np.ndarray, tolerance: int = 1) -> np.ndarray:
        """(N,3) world points → (N,) bool, True = static background: within one voxel of a
        background voxel (``tolerance=1``, default) or inside one (``tolerance=0``, stricter: what
        the mesh uses, so a walker's body next to a wall or the floor is not kept through the
        neighbourhood). Non-finite points are False."""
        p = np.asarray(points_world).reshape(-1, 3)
        out = np.zeros(len(p), bool)
        if len(p) == 0:
            return out
        ok = _finite_rows(p)
        q = np.divide(p if ok.all() else p[ok], self.voxel, dtype=np.float64)
        np.floor(q, out=q)                    # voxel_index in float64 (integer values, exact)
        if ok.all():
            return self._lookup(q, bool(tolerance))
        out[ok] = self._lookup(q, bool(tolerance))
        return out

    def _lookup(self, q: np.ndarray, dilated: bool) -> np.ndarray:
        """(N,) bool: voxel indices given as float64 integer values ``q`` (N,3) that are background
        voxels (``dilated``: within one voxel of one). A dense boolean grid of the model's bounding box
        (built at the first call, at most ``DENSE_MAX_CELLS`` cells) answers without hashing or
        sorting; larger models use the sorted keys."""
        table = self.dilated if dilated else self.keys
        out = np.zeros(len(q), bool)
        if len(table) == 0 or len(q) == 0:
            return out
        grid = self._grids.get(dilated)
        if grid is None:
            cells = unpack_keys(table)
            box = dense_box(cells.min(0), cells.max(0))
            grid = False
            if box is not None:
                lo, dims = box
                occ = np.zeros(int(np.prod(dims)), bool)
                occ[flat_index(cells, lo, dims)] = True
                grid = (lo.astype(np.float64), dims.astype(np.float64), occ,
                        np.array([dims[1] * dims[2], dims[2], 1], np.float64))
            self._grids[dilated] = grid
        if grid is not False:
            lo, dims, occ, step = grid
            r = q - lo
            ok = (r >= 0) & (r < dims)
            inside = ok[:, 0] & ok[:, 1] & ok[:, 2]
            if inside.all():                  # the common case: no gathered copy of the indices
                return occ[(r @ step).astype(np.int64)]
            out[inside] = occ[(r[inside] @ step).astype(np.int64)]
            return out
        k = voxel_keys(q.astype(np.int64))
        pos = np.minimum(np.searchsorted(table, k), len(table) - 1)
        return table[pos] == k

    def centers(self) -> np.ndarray:
        """(V,3) float64 centres (m) of the background voxels."""
        return (unpack_keys(self.keys) + 0.5) * self.voxel

    def __len__(self) -> int:
        return len(self.keys)


def _free_space(pts: list, origins: np.ndarray, centers: np.ndarray, voxel: float, res_deg: float,
                max_scans: int) -> tuple[np.ndarray, np.ndarray]:
    """Per voxel centre: in how many of (up to ``max_scans``) scans it was seen occupied / seen through."""
    from scipy.ndimage import minimum_filter

    res = np.deg2rad(res_deg)
    nel, naz = int(np.ceil(np.pi / res)) + 1, int(np.ceil(2 * np.pi / res)) + 1
    occ = np.zeros(len(centers))
    free = np.zeros(len(centers))
    idx = np.unique(np.linspace(0, len(pts) - 1, min(len(pts), max_scans)).round().astype(int))

    def bins(d):
        r = np.linalg.norm(d, axis=1)
        el = np.arcsin(np.clip(d[:, 2] / np.maximum(r, 1e-9), -1, 1))
        az = np.arctan2(d[:, 1], d[:, 0])
        return r, ((el + np.pi / 2) / res).astype(np.int64), ((az + np.pi) / res).astype(np.int64)

    for s in idx:
        p, o = pts[s], origins[s]
        if not len(p):
            continue
        r, i, j = bins(p - o)
        img = np.full(nel * naz, np.inf)
        np.minimum.at(img, i * naz + j, r)
        img2 = img.reshape(nel, naz)
        hole = ~np.isfinite(img2)
        img2[hole] = minimum_filter(img2, size=3, mode="wrap")[hole]  # fill gaps between rings/columns
        rv, iv, jv = bins(centers - o)
        rr = img[iv * naz + jv]
        margin = np.maximum(voxel, FREE_SPACE_RANGE_SHARE * rv)
        occ += np.abs(rr - rv) <= margin
        free += np.isfinite(rr) & (rr > rv + margin)
    return occ, free


def _dilate(keys: np.ndarray) -> np.ndarray:
    if len(keys) == 0:
        return keys
    ijk = unpack_keys(keys)
    out = [np.unique(voxel_keys(ijk + o)) for o in _OFFS]
    return np.unique(np.concatenate(out))


__all__ = ["VoxelBackground", "voxel_index"]
