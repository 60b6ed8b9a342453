"""The moving-platform azimuth sum of :mod:`holodata.radar.beamform`, compiled with numba.

For every elevation row pair (rows with equal cos θ share the coefficients), beam ``b`` and
sample ``i``::

    y[r, b, i] = Σ_{m=−h..h} X[r, off + b + m, i] · K[r, m, i] · exp(j m γ[b, i])

``X`` the vertically beamformed chirps (H, L, S), ``K`` the azimuth kernel with the chirp window
(:func:`~holodata.radar.beam_geometry.azimuth_kernel`), ``γ`` the motion phase per chirp of offset
(:func:`~holodata.radar.beam_geometry.motion_phase_rate`). The motion phase advances by one
complex multiplication per chirp and is recomputed exactly every 64 chirps (float32 drift stays
below 1e-5). The loops run over samples innermost (contiguous, vectorised) and over (row pair,
beam) in parallel. numba compiles it on first use and caches the machine code next to this file.
Arrays in, arrays out: no I/O.
"""
from __future__ import annotations

import numba
import numpy as np

from .beam_geometry import _REANCHOR as REANCHOR

# OpenMP first: thread-safe when several threads beamform at once (numba's workqueue layer is not),
# and no warning about an old TBB where one is installed
numba.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]


@numba.njit(parallel=True, fastmath=True, cache=True)
def _sums(X, rows, off, beams, K, gam, out):   # pragma: no cover - compiled
    G = rows.shape[0]
    nb = beams.size
    S = X.shape[2]
    h = (K.shape[1] - 1) // 2
    for t in numba.prange(G * nb):
        g = t // nb
        j = t % nb
        r0 = rows[g, 0]
        r1 = rows[g, 1]
        b = beams[j]
        a0 = np.zeros(S, np.complex64)
        a1 = np.zeros(S, np.complex64)
        E = np.empty(S, np.complex64)
        Q = np.empty(S, np.complex64)
        for i in range(S):
            Q[i] = np.complex64(complex(np.cos(gam[g, j, i]), np.sin(gam[g, j, i])))
        for m0 in range(-h, h + 1, REANCHOR):
            for i in range(S):
                ph = gam[g, j, i] * m0
                E[i] = np.complex64(complex(np.cos(ph), np.sin(ph)))
            for m in range(m0, min(m0 + REANCHOR, h + 1)):
                Km = K[r0, m + h]
                X0 = X[r0, off + b + m]
                if r1 >= 0:
                    X1 = X[r1, off + b + m]
                    for i in range(S):
                        T = E[i] * Km[i]
                        a0[i] += X0[i] * T
                        a1[i] += X1[i] * T
                        E[i] *= Q[i]
                else:
                    for i in range(S):
                        T = E[i] * Km[i]
                        a0[i] += X0[i] * T
                        E[i] *= Q[i]
        out[r0, j] = a0
        if r1 >= 0:
            out[r1, j] = a1


def motion_sums(X: np.ndarray, rows: np.ndarray, off: int, beams: np.ndarray, K: np.ndarray, gam: np.ndarray,
                out: np.ndarray, threads: int) -> np.ndarray:
    """Fill ``out`` (H, nb, S) complex64 with the sums above. ``X`` (H, L, S) complex64; ``rows``
    (G, 2) int64 row pairs (−1: none); ``off``: index in ``X`` of the rotation's chirp 0; ``beams``
    (nb,) int64; ``K`` (H, n_syn, S) complex64; ``gam`` (G, nb, S) float64 (one per row pair)."""
    from ..parallel import kernel_threads

    with kernel_threads(threads):
        _sums(np.ascontiguousarray(X, np.complex64), np.ascontiguousarray(rows, np.int64), int(off),
              np.ascontiguousarray(beams, np.int64), np.ascontiguousarray(K, np.complex64),
              np.ascontiguousarray(gam, np.float64), out)
    return out
