"""Plane fits: the total-least-squares plane of points (:func:`fit_plane`), a height field plane
``z = a·x + b·y + c`` (:func:`fit_height_plane`), the RANSAC plane with the most inliers
(:func:`ransac_plane`, Fischler & Bolles 1981, refitted to its inliers) and the per-neighbourhood PCA
planes that denoise a cloud (:func:`local_plane_projection`). No I/O, numpy/scipy only."""
from __future__ import annotations

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
                           only: np.ndarray | None = None, chunk: int = 4096) -> np.ndarray:
    """Denoised copy of a point cloud (N,3): each point moved along the normal of the plane fitted
    (PCA) to its neighbours within ``radius`` onto that plane, where the neighbourhood is planar (smallest
    covariance eigenvalue < ``ratio`` × the middle one) and holds >= ``min_nn`` points; other points
    (edges, corners, clutter) stay. ``only`` (N,) bool: project just those (their neighbourhoods still
    span every point). Vectorised: neighbour pairs (scipy ``sparse_distance_matrix``), first and second
    moments by a sparse product, batched 3×3 eigen-decompositions."""
    from scipy.sparse import csr_matrix
    from scipy.spatial import cKDTree

    X = np.asarray(points, np.float64).reshape(-1, 3)
    idx = np.arange(len(X)) if only is None else np.flatnonzero(only)
    if len(idx) == 0 or radius <= 0:
        return X.copy()
    # neighbours (itself included) of just the projected points, a chunk at a time: a 0.3 m ball on
    # a 4 cm map holds ~400 points (17 M pairs for 41 k points; 1.5 GB at once)
    tree = cKDTree(X)
    XX = (X[:, :, None] * X[:, None, :]).reshape(-1, 9)
    cnt, mu, C = np.empty(len(idx)), np.empty((len(idx), 3)), np.empty((len(idx), 9))
    for s in range(0, len(idx), chunk):
        q = idx[s:s + chunk]
        nb = cKDTree(X[q]).sparse_distance_matrix(tree, radius, output_type="ndarray")
        A = csr_matrix((np.ones(len(nb)), (nb["i"], nb["j"])), shape=(len(q), len(X)))
        cnt[s:s + len(q)] = np.asarray(A.sum(1)).ravel()
        mu[s:s + len(q)] = A @ X
        C[s:s + len(q)] = A @ XX
    mu /= cnt[:, None]
    C = (C / cnt[:, None]).reshape(-1, 3, 3) - mu[:, :, None] * mu[:, None, :]
    w, V = np.linalg.eigh(C)
    n = V[:, :, 0]
    ok = (cnt >= min_nn) & (w[:, 0] < ratio * w[:, 1])
    out = X.copy()
    d = np.einsum("ij,ij->i", X[idx] - mu, n)
    out[idx[ok]] -= d[ok, None] * n[ok]
    return out
