"""Plane fits: the total-least-squares plane of points (:func:`fit_plane`), a height field plane
``z = a·x + b·y + c`` (:func:`fit_height_plane`), the RANSAC plane with the most inliers
(:func:`ransac_plane`, Fischler & Bolles 1981, refitted to its inliers) and the per-neighbourhood PCA
planes that denoise a cloud (:func:`local_plane_projection`, its neighbourhood sums compiled with numba
in :mod:`._ball_kernel`). No I/O."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def fit_plane(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Total-least-squares plane of points (N,3), N >= 3: (unit normal (3,), offset) with
    ``normal · p + offset = 0``; the normal is the right singular vector of the centred points with the
    smallest singular value (the plane through the centroid that minimises the squared orthogonal
    distances; its sign is arbitrary)."""
    q = np.asarray(points, np.float64)
    c = q.mean(0)
    normal = np.linalg.svd(q - c, full_matrices=False)[2][-1]
    return normal, -float(normal @ c)


def fit_height_plane(points: np.ndarray) -> np.ndarray:
    """Least-squares height field plane ``z = a·x + b·y + c`` of points (N,3), N >= 3 (residuals
    measured along z, as for a floor with z up): (3,) [a, b, c]."""
    q = np.asarray(points, np.float64)
    A = np.c_[q[:, :2], np.ones(len(q))]
    return np.linalg.lstsq(A, q[:, 2], rcond=None)[0]


def ransac_plane(points: np.ndarray, dist: float, iterations: int, rng) -> tuple[np.ndarray, float, int]:
    """Plane with the most points (N,3) within ``dist`` (m) among ``iterations`` planes through three
    random points (numpy ``rng``), refitted by least squares to its inliers: (unit normal (3,), offset,
    inlier count) with ``normal · p + offset = 0``. Deterministic for a given ``rng`` state (open3d's
    multithreaded ``segment_plane`` is not, even seeded: its result depended on thread timing)."""
    p = np.asarray(points, np.float64)
    i = rng.integers(0, len(p), (iterations, 3))
    n = np.cross(p[i[:, 1]] - p[i[:, 0]], p[i[:, 2]] - p[i[:, 0]])
    norm = np.linalg.norm(n, axis=1)
    ok = norm > 1e-12
    n, a = n[ok] / norm[ok, None], p[i[ok, 0]]
    d = -np.einsum("ij,ij->i", n, a)
    counts = np.zeros(len(n), np.int64)
    step = max(1, 4_000_000 // max(len(p), 1))          # (N, step) distances at a time
    for s in range(0, len(n), step):
        counts[s:s + step] = (np.abs(p @ n[s:s + step].T + d[s:s + step]) < dist).sum(0)
    if not len(counts):
        return np.array([0.0, 0.0, 1.0]), 0.0, 0
    b = int(np.argmax(counts))
    normal, offset = fit_plane(p[np.abs(p @ n[b] + d[b]) < dist])     # least-squares plane of the inliers
    return normal, offset, int((np.abs(p @ normal + offset) < dist).sum())


def local_plane_projection(points: np.ndarray, radius: float, ratio: float = 0.1, min_nn: int = 6,
                           only: np.ndarray | None = None) -> np.ndarray:
    """Denoised copy of a point cloud (N,3): each point moved along the normal of the plane fitted
    (PCA) to its neighbours within ``radius`` onto that plane, where the neighbourhood is planar (smallest
    covariance eigenvalue < ``ratio`` × the middle one) and holds >= ``min_nn`` points; other points
    (edges, corners, clutter) stay. ``only`` (N,) bool: project just those (their neighbourhoods still
    span every point). The neighbourhoods' first and second moments come from a compiled grid search
    (:func:`holodata.geometry._ball_kernel.ball_moments`: a 0.3 m ball of a 4 cm map holds hundreds
    of points, which a sparse neighbour matrix held and sorted pair by pair), then batched 3×3
    eigen-decompositions."""
    from ._ball_kernel import ball_moments

    X = np.asarray(points, np.float64).reshape(-1, 3)
    idx = np.arange(len(X)) if only is None else np.flatnonzero(only)
    if len(idx) == 0 or radius <= 0:
        return X.copy()
    cnt, mu, C = ball_moments(X, radius, idx)
    mu /= cnt[:, None]
    C = (C / cnt[:, None]).reshape(-1, 3, 3) - mu[:, :, None] * mu[:, None, :]
    w, V = np.linalg.eigh(C)
    n = V[:, :, 0]
    ok = (cnt >= min_nn) & (w[:, 0] < ratio * w[:, 1])
    out = X.copy()
    d = np.einsum("ij,ij->i", X[idx] - mu, n)
    out[idx[ok]] -= d[ok, None] * n[ok]
    return out


def _window(P: np.ndarray, rows: int, cols: int) -> list[np.ndarray]:
    """Neighbours of each pixel of a point image P (…,H,W,3) in a (2·rows+1)×(2·cols+1) window, one
    shifted copy (…,H,W,3) per offset: columns wrap around (a full rotation), rows beyond the image
    are NaN."""
    out = []
    for dy in range(-rows, rows + 1):
        q = np.full_like(P, np.nan)
        if dy >= 0:
            q[..., :P.shape[-3] - dy, :, :] = P[..., dy:, :, :]
        else:
            q[..., -dy:, :, :] = P[..., :dy, :, :]
        out.extend(np.roll(q, -dx, axis=-2) for dx in range(-cols, cols + 1))
    return out


def window_plane_normals(P: np.ndarray, n0: np.ndarray, rows: int = 1, cols: int = 4, sigma: float = 0.03,
                         iterations: int = 3) -> np.ndarray:
    """Unit normals (…,H,W,3) of a point image P (…,H,W,3) (a range image's points, NaN = none): per
    pixel the weighted total-least-squares plane (PCA) of its image window (:func:`_window`), iteratively
    reweighted by each neighbour's distance d (m) to the current plane, ``w = exp(−d²/2σ²)``, starting
    from the planes through the pixels with normals ``n0`` (…,H,W,3), e.g. eq. 4's finite differences.
    The weights keep the fit on the pixel's own surface across a depth edge (a neighbour on another
    surface is ≫ σ off the plane), the window averages the range noise that makes finite-difference
    normals of a predicted image degrees off. Signs follow ``n0``; NaN where ``n0`` is NaN; a pixel
    with under 4 neighbours of total weight keeps ``n0``. On a noise-free plane the result is exact.
    Moments are accumulated offset by offset, relative to the pixel's own point.
    Compiled with numba, pixel by pixel (:func:`holodata.geometry._planes_kernel.plane_normals`; the
    numpy version, :func:`_window_plane_normals_numpy`, is its reference)."""
    from ._planes_kernel import plane_normals

    P = np.asarray(P, np.float64)
    n = np.asarray(n0, np.float64)
    shape = np.broadcast_shapes(P.shape, n.shape)
    if len(shape) < 3 or shape[-1] != 3:
        raise ValueError(f"expected point and normal images (...,H,W,3), got {P.shape} and {n.shape}")
    H, W = shape[-3], shape[-2]
    Pf = np.ascontiguousarray(np.broadcast_to(P, shape)).reshape(-1, H, W, 3)
    nf = np.ascontiguousarray(np.broadcast_to(n, shape)).reshape(-1, H, W, 3)
    out = np.empty(Pf.shape)
    plane_normals(Pf, nf, int(rows), int(cols), float(sigma), int(iterations), out)
    return out.reshape(shape)


def _window_plane_normals_numpy(P: np.ndarray, n0: np.ndarray, rows: int = 1, cols: int = 4,
                                sigma: float = 0.03, iterations: int = 3) -> np.ndarray:
    """:func:`window_plane_normals` in numpy, offset by offset over whole images: the reference its
    compiled kernel is tested against."""
    P = np.asarray(P, np.float64)
    n = np.asarray(n0, np.float64)
    window = _window(P, rows, cols)
    rel = [np.nan_to_num(q - P) for q in window]                     # neighbours about the pixel
    fin = [np.isfinite(q).all(-1) & np.isfinite(P).all(-1) for q in window]
    c = np.zeros_like(P)                                              # plane point, about the pixel
    for _ in range(iterations):
        nz = np.nan_to_num(n)
        s0 = np.zeros(P.shape[:-1])
        s1 = np.zeros(P.shape)
        s2 = np.zeros(P.shape + (3,))
        for q, f in zip(rel, fin):
            d = np.einsum("...c,...c->...", q - c, nz)
            w = np.where(f, np.exp(-0.5 * (d / sigma) ** 2), 0.0)
            wq = w[..., None] * q
            s0 += w
            s1 += wq
            s2 += wq[..., :, None] * q[..., None, :]
        mu = s1 / np.maximum(s0, 1e-12)[..., None]
        C = s2 / np.maximum(s0, 1e-12)[..., None, None] - mu[..., :, None] * mu[..., None, :]
        m = np.linalg.eigh(C)[1][..., 0]
        ok = (s0 >= 4.0) & np.isfinite(n).all(-1)
        m = np.where((np.sum(m * nz, axis=-1) < 0)[..., None], -m, m)
        n = np.where(ok[..., None], m, n)
        c = np.where(ok[..., None], mu, 0.0)
    return n


@dataclass(frozen=True)
class PlaneRansac:
    """Settings of :func:`agreeing_planes`' sequential RANSAC: a point supports a plane within ``dist``
    m of it whose normal is within ``agree_deg`` of its own; ``iterations`` hypotheses per plane, each
    scored on up to ``sample`` of the free points; up to ``max_planes`` planes of at least
    ``min_inliers`` points."""

    dist: float = 0.04
    agree_deg: float = 20.0
    min_inliers: int = 24
    max_planes: int = 12
    iterations: int = 256
    sample: int = 1024


def agreeing_planes(points: np.ndarray, normals: np.ndarray, ransac: PlaneRansac = PlaneRansac(),
                    rng=None) -> np.ndarray:
    """Each point's normal replaced by that of the plane it belongs to: sequential RANSAC
    (Fischler & Bolles 1981) over points (N,3) with local normals (N,3), where a point supports a
    plane when it lies within ``ransac.dist`` m of it *and* its local normal is within
    ``ransac.agree_deg`` of the plane's (so a plane never takes the floor points it crosses, nor a box's
    side it cuts). Hypotheses through three points are scored on up to ``ransac.sample`` of the points
    still free, the best is refitted by least squares to its supporters (three times) and its
    supporters leave the pool; up to ``ransac.max_planes`` planes of ≥ ``ransac.min_inliers`` points
    (:class:`PlaneRansac`). A point supporting several planes takes the nearest. Returns (N,3) unit
    normals, signed like ``normals``; points on no plane keep theirs. Why: a wall's normal fitted to its
    hundreds of points is a small fraction of a degree off where a window of a noisy range image is
    degrees off, and un-mirroring turns a normal error δ into a lateral error of ~2δ per metre of the
    next segment. Deterministic for a given ``rng`` (default: seed 0)."""
    rng = np.random.default_rng(0) if rng is None else rng
    dist, min_inliers, sample = ransac.dist, ransac.min_inliers, ransac.sample
    X = np.asarray(points, np.float64)
    NL = np.asarray(normals, np.float64)
    cos_ag = np.cos(np.radians(ransac.agree_deg))
    best_n = np.full(X.shape, np.nan)
    best_d = np.full(len(X), np.inf)
    free = np.ones(len(X), bool)

    def support(n, p0):
        d = np.abs((X - p0) @ n)
        return (d < dist) & (np.abs(NL @ n) >= cos_ag), d

    for _ in range(ransac.max_planes):
        pool = np.flatnonzero(free)
        if len(pool) < min_inliers:
            break
        sub = pool if len(pool) <= sample else rng.choice(pool, sample, replace=False)
        tri = rng.choice(pool, (ransac.iterations, 3))
        n = np.cross(X[tri[:, 1]] - X[tri[:, 0]], X[tri[:, 2]] - X[tri[:, 0]])
        norm = np.linalg.norm(n, axis=1)
        good = norm > 1e-9
        if not good.any():
            break
        n, a = n[good] / norm[good, None], X[tri[good, 0]]
        d = np.abs(n @ X[sub].T - np.einsum("hc,hc->h", n, a)[:, None])
        score = ((d < dist) & (np.abs(n @ NL[sub].T) >= cos_ag)).sum(1)
        j = int(np.argmax(score))
        if score[j] * len(pool) / len(sub) < min_inliers:
            break
        nj, pj = n[j], a[j]
        for _ in range(3):
            inl, _d = support(nj, pj)
            if inl.sum() < 3:
                break
            nj, off = fit_plane(X[inl])
            pj = -off * nj
        inl, d_all = support(nj, pj)
        if inl.sum() < min_inliers:
            free[tri[j]] = False   # no plane here: do not draw these again
            continue
        take = inl & (d_all < best_d)
        best_n[take], best_d[take] = nj, d_all[take]
        free &= ~inl
    out = NL.copy()
    has = np.isfinite(best_n).all(1)
    sign = np.where(np.sum(best_n[has] * NL[has], axis=1) < 0, -1.0, 1.0)
    out[has] = best_n[has] * sign[:, None]
    return out
