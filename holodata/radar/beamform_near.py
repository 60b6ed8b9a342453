"""Near-field focusing for the rotating-array beamformer (``BeamformParams.focus == "near"``).

PanoRadar's azimuth compensation ``exp(j4π r cos(h) cos θ / λ_i)`` is the far-field one: it assumes
the path from chirp ``m``'s antenna to a point is ``R − r cos θ cos(mΔφ)``. The exact distance,
``d_m = sqrt(R² + r² − 2 R r cos θ cos(mΔφ))``, differs by about ``r² (1 − cos²θ cos²(mΔφ)) / 2R``,
which over a 90° aperture on the 10.5 cm circle leaves a quadratic phase of ``~9/R`` radians
(R in metres) across the arc: at 0.8 m the main lobe smears over several degrees and near walls
put sidelobes 30–60° off a beam (docs/design/radar.md). This path focuses on every range bin's
centre instead (back-projection), keeping the FFT structure:

1. static reflection removal and vertical beamforming per sample as in the far-field path;
2. per row ``θ`` the samples are multiplied by ``exp(j4π r cos θ / λ_i)`` (the far-field compensation
   of the beam's own chirp, ``m = 0``: it moves a point at range ``R`` from the centre to bin ``R``,
   a shift of ``r cos θ`` that is up to 2.8 bins and must be applied before the range FFT), the
   sample window and ``exp(−jπ i / S)``; then the range FFT of every chirp;
3. per range bin ``k`` (centre ``R_k = (k + 0.5) Δr``), beam ``b`` sums the ``n_syn`` chirps around it:
   ``y[b, k] = Σ_m Z_θ[b+m, k] · w_c[m] · exp(−j4π (d_m(R_k) + r cos θ − R_k) f̄ / c) · M``,
   ``f̄`` the mean sample frequency (after a range FFT with a symmetric window the phase of a return
   at path ``2d`` is ``4π d f̄ / c`` plus a term of ``k`` alone, :func:`~.beam_geometry.centre_frequency`)
   and, moving, ``M = exp(j m · 4π δs f̄ / c)`` (the far-field path's motion term at ``f̄``);
4. the magnitude.

Step 3 is a correlation along the chirp axis per range bin with a kernel that depends on ``k``
but not on ``b``: at rest it runs as FFTs over chirps (the range FFT commutes with the chirp FFT,
so the chirp FFT is taken once per antenna, before the vertical beamforming); moving, the direct
sum of :mod:`._motion_kernel` runs over range bins instead of samples. What is approximated: the
residual range migration across the aperture (the far-field path removes it per sample): a point's
return in chirp ``m`` sits ``r cos θ (1 − cos(mΔφ))`` further than in chirp 0, 0.21 bins where the
Hann window is one half and 0.8 bins at the aperture's ends (weight ~0), so the range response
widens slightly; and the elevation is steered in the far field (a point at elevation θ seen from an
antenna on the circle at near range sits at ``R sin θ / d_0``, as in the far-field path).
Arrays in, arrays out.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ._steps import Setup, _blas_single, _elevation_groups, _row_pairs, _to_rotation_start, _vertical
from .beam_geometry import _to_columns, near_kernel, near_motion_phase_rate, near_sample_weights, vertical_weights

_NKCACHE: dict = {}


def _cache(key, make):
    if key not in _NKCACHE:
        if len(_NKCACHE) >= 2:
            _NKCACHE.pop(next(iter(_NKCACHE)))
        _NKCACHE[key] = make()
    return _NKCACHE[key]


def _row_weights(chirp, params, elev) -> np.ndarray:
    """(S, V, H) complex64: vertical weights × the per-row sample factors of step 2."""
    w = vertical_weights(chirp, elev) * near_sample_weights(chirp, params, elev)[:, None, :]
    return np.ascontiguousarray(w.transpose(2, 1, 0).astype(np.complex64))


def _kernel_spectrum(chirp, params, st: Setup, Lf, q, blk, threads):
    """Per block of ``blk`` rows, (R, Lf, rows) complex64: the FFT over the chirp axis of the circularly
    placed kernel g[k, (−m) mod Lf] = K[m, k], divided by the fold factor ``q`` (see :func:`static_near`)."""
    N, R = st.N, st.R

    def make():
        import scipy.fft as sfft

        K = near_kernel(chirp, params, np.cos(st.elev), N, R).astype(np.complex64)      # (H, n_syn, R)
        H, n_syn, _ = K.shape
        h = (n_syn - 1) // 2
        out = []
        for a in range(0, H, blk):
            g = np.zeros((R, Lf, min(a + blk, H) - a), np.complex64)
            g[:, (-np.arange(-h, h + 1)) % Lf, :] = K[a:a + blk].transpose(2, 1, 0)
            g = sfft.fft(g, axis=1, workers=threads, overwrite_x=True)
            g *= np.float32(1.0 / q)
            out.append(g)
        return out

    return _cache(("spectrum", chirp, params, N, Lf, R, q, blk), make)


def static_near(xp, off, circular, N, chirp, params, threads) -> np.ndarray:
    """(R, H, W) float32 for a platform at rest; arguments as :func:`holodata.radar.beamform._static_numpy`.

    Per block of rows: vertical beamforming of the chirp spectra (one small matrix product per
    sample), the range FFT, the product with the kernel spectrum of each range bin, and the inverse
    FFT over the chirp axis; when the beams are every q-th chirp position the spectrum is folded q
    times first (a length Lf/q inverse FFT gives just those beams)."""
    import scipy.fft as sfft

    st = Setup.of(chirp, params, N)
    S, R, elev, H, beams, cw = st.S, st.R, st.elev, st.H, st.beams, st.cw
    Lf, q = st.fft_plan(xp.shape[0], off, circular)
    Lq = Lf // q
    blk = 16
    Kf = _kernel_spectrum(chirp, params, st, Lf, q, blk, threads)                   # per block (R, Lf, rows)
    vw = _row_weights(chirp, params, elev)                                            # (S, V, H)
    xf = sfft.fft(xp, n=Lf, axis=0, workers=threads)                                  # (Lf, V, S)
    xf = np.ascontiguousarray(xf.transpose(2, 0, 1))                                   # (S, Lf, V)
    mag = np.empty((R, H, beams.size), np.float32)
    sparts = [p for p in np.array_split(np.arange(S), threads) if p.size]
    rparts = [p for p in np.array_split(np.arange(R), threads) if p.size]
    with _blas_single(), ThreadPoolExecutor(max_workers=max(len(sparts), len(rparts))) as pool:
        for n, a in enumerate(range(0, H, blk)):
            sl = slice(a, min(a + blk, H))
            hb = sl.stop - sl.start
            Y = np.empty((S, Lf, hb), np.complex64)

            def vert(ss, sl=sl, Y=Y):
                s0, s1 = int(ss[0]), int(ss[-1]) + 1
                np.matmul(xf[s0:s1], vw[s0:s1, :, sl], out=Y[s0:s1])                   # vertical beamforming

            list(pool.map(vert, sparts))
            Z = sfft.fft(Y, axis=0, workers=threads, overwrite_x=True)                 # range FFT
            del Y
            y = np.empty((R, beams.size, hb), np.complex64)

            def azim(ks, Kb=Kf[n], Z=Z, y=y):
                k0, k1 = int(ks[0]), int(ks[-1]) + 1
                T = Z[k0:k1]
                np.multiply(T, Kb[k0:k1], out=T)                                       # correlation over chirps
                for t in range(1, q):
                    T[:, :Lq] += T[:, t * Lq:(t + 1) * Lq]
                if q > 1:
                    y[k0:k1] = sfft.ifft(T[:, :Lq], axis=1, overwrite_x=True)
                else:
                    y[k0:k1] = sfft.ifft(T, axis=1, overwrite_x=True)[:, off + beams, :]

            list(pool.map(azim, rparts))
            mag[:, sl, :] = np.abs(y).transpose(0, 2, 1)
    return _to_columns(mag, cw)


def motion_near(xp, off, N, chirp, params, motion, threads) -> np.ndarray:
    """(R, H, W) float32 for a moving platform: ``xp`` (L, V, S) padded chirps, ``off`` the index of
    the rotation's chirp 0 (as :func:`holodata.radar.beamform._motion_numpy`)."""
    import scipy.fft as sfft

    from ._motion_kernel import motion_sums

    st = Setup.of(chirp, params, N)
    R, elev, H, beams, cw = st.R, st.elev, st.H, st.beams, st.cw
    X = _vertical(xp, _row_weights(chirp, params, elev), threads)                    # (H, L, S)
    X = np.ascontiguousarray(sfft.fft(X, axis=2, workers=threads, overwrite_x=True)[:, :, :R])   # (H, L, R)
    K = _cache(("kernel", chirp, params, N, R),
               lambda: near_kernel(chirp, params, np.cos(elev), N, R).astype(np.complex64))   # (H, n_syn, R)
    rows = _row_pairs(_elevation_groups(elev))
    gam = np.stack([near_motion_phase_rate(chirp, params, motion, float(np.cos(elev[r0])), beams, N, R)
                    for r0 in rows[:, 0]])                                             # (G, nb, R)
    y = np.empty((H, beams.size, R), np.complex64)
    motion_sums(X, rows, off, beams, K, gam, y, threads)
    if params.motion_reference == "rotation_start":
        _to_rotation_start(y, rows, gam, beams)
    return _to_columns(np.abs(y).transpose(2, 0, 1), cw)
