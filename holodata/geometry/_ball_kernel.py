"""First and second moments of every query point's fixed-radius neighbourhood, compiled with numba.

For each query point ``q`` the neighbours are the points ``j`` with ``|X_j − X_q|² <= r²`` (itself
included), and the kernel returns their count, ``Σ X_j`` and ``Σ X_j X_jᵀ``: what
:func:`holodata.geometry.planes.local_plane_projection` fits its planes to.

How: the query points are sorted into a uniform grid of cells at least ``r`` wide (the cell key
``(x·n_y + y)·n_z + z``; a neighbour lies in one of the 27 cells around a point's, and the 3 cells
along z of each of the 9 (x, y) columns form one contiguous run of the sorted queries, found by
binary search). The kernel walks the points ``j`` in ascending order and adds each one to the sums
of every query within ``r`` of it, so each query's sums run over its neighbours in ascending index
order, and the squared distance is summed over x, y, z in that order as scipy's ``cKDTree`` does:
the sums equal those of a sparse neighbour matrix with sorted rows times the points (scipy's CSR
product, what this replaces) to the bit. Why: that road built and sorted every neighbour pair in
memory, tens of millions for a quick-demo scene's map (the times: docs/design/performance.md).
Arrays in, arrays out: no I/O. numba compiles it on first use and caches the machine code next to
this file.
"""
from __future__ import annotations

import numba
import numpy as np

# a grid axis has at most this many cells (a cell widens beyond the radius for huge extents), so the
# flat cell key of three axes stays within int64
MAX_CELLS_PER_AXIS = 2_000_000


@numba.njit(cache=True)
def _sums(X, cells, Xq, qkeys, n1, n2, r2, acc):  # pragma: no cover - compiled
    """acc (Q,10) += [1, x, y, z, xx, xy, xz, yy, yz, zz] of every point of X (N,3) (cells (N,3))
    within r2 (squared) of each query Xq (Q,3), the queries sorted by their cell keys qkeys (Q,)."""
    for j in range(X.shape[0]):
        cx, cy, cz = cells[j, 0], cells[j, 1], cells[j, 2]
        u, v, w = X[j, 0], X[j, 1], X[j, 2]
        uu, uv, uw, vv, vw, ww = u * u, u * v, u * w, v * v, v * w, w * w
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                base = ((cx + dx) * n1 + (cy + dy)) * n2 + cz
                a = np.searchsorted(qkeys, base - 1, side="left")
                b = np.searchsorted(qkeys, base + 1, side="right")
                for p in range(a, b):
                    ex = Xq[p, 0] - u
                    ey = Xq[p, 1] - v
                    ez = Xq[p, 2] - w
                    d = 0.0
                    d += ex * ex
                    d += ey * ey
                    d += ez * ez
                    if d <= r2:
                        acc[p, 0] += 1.0
                        acc[p, 1] += u
                        acc[p, 2] += v
                        acc[p, 3] += w
                        acc[p, 4] += uu
                        acc[p, 5] += uv
                        acc[p, 6] += uw
                        acc[p, 7] += vv
                        acc[p, 8] += vw
                        acc[p, 9] += ww


def ball_moments(points: np.ndarray, radius: float, idx: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Neighbourhood sums of the points ``idx`` (Q,) (default: all) of ``points`` (N,3) m, each
    over the points within ``radius`` m of it (itself included): (count (Q,) float64, Σ X_j (Q,3),
    Σ X_j X_jᵀ (Q,9), row-major 3×3). The order of the sums is the module docstring's."""
    X = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    idx = np.arange(len(X)) if idx is None else np.asarray(idx, np.int64).ravel()
    acc = np.zeros((len(idx), 10))
    if len(idx) and len(X):
        lo = X.min(0)
        h = max(float(radius), float((X.max(0) - lo).max()) / MAX_CELLS_PER_AXIS, 1e-300)
        # cells offset by one with a free cell on each side: the 27 cells around any point lie in the
        # grid, so the 9 runs a point searches never overlap
        cells = np.floor((X - lo) / h).astype(np.int64) + 1
        n = cells.max(0) + 2
        keys = (cells[:, 0] * n[1] + cells[:, 1]) * n[2] + cells[:, 2]
        qkeys = keys[idx]
        qorder = np.argsort(qkeys, kind="stable")
        _sums(X, cells, X[idx[qorder]], qkeys[qorder], int(n[1]), int(n[2]), float(radius) * float(radius), acc)
        acc[qorder] = acc.copy()
    s2 = acc[:, [4, 5, 6, 5, 7, 8, 6, 8, 9]]
    return acc[:, 0].copy(), np.ascontiguousarray(acc[:, 1:4]), s2


__all__ = ["ball_moments", "MAX_CELLS_PER_AXIS"]
