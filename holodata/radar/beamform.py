"""Rotating-array beamforming: one rotation of raw FMCW samples → a (n_range, H, W) linear-amplitude heatmap.

The algorithm is PanoRadar's (``panoradar_SP/radar_imaging_3d.py``, MIT licence; summarised in
``/work/shared/FIELD-NOTES.md`` §"Raw radar"), which HoloRadar (NeurIPS 2025, §3 and appendix A)
uses for its 64 × 512 × 256 heatmaps. For one rotation of ``N`` chirp frames ``x[n, v, i]``
(chirp ``n`` facing azimuth ``φ_n = −2πn/N``, virtual antenna ``v``, ADC sample ``i`` at wavelength
``λ_i``) and every elevation row ``θ`` of the grid:

1. **static reflection removal**: ``x ← x − s`` with ``s[v, i]`` the mean over all chirps of the
   trajectory (TX→RX leakage and the rig's own reflections; the caller passes it, see
   :func:`static_reflection`), or of this rotation only, or nothing (``BeamformParams.static_removal``);
2. **vertical beamforming**: ``X_θ[n, i] = mean_v x[n, v, i] · exp(−j2π d_v / λ_i)``,
   ``d_v = antenna_spacing · sin θ · (V − 1 − v)``;
3. **azimuth synthesis**: beam ``b`` (facing ``φ_b = −2πb/N``) sums the ``N_syn`` chirps centred on it
   (``N_syn`` odd, 90° of the rotation by default):
   ``y[b, i] = Σ_{m=−h..h} X_θ[b+m, i] · w_c[m] · w_s[i] · exp(j4π r cos(mΔφ) cos θ / λ_i) · M[b, m, i]``
   with ``Δφ = 2π/N``, Hann windows over chirps ``w_c`` and samples ``w_s``, and for a moving platform
   ``M = exp(j2π · 2(b+m)·δs / λ_i)``, ``δs = δs0 · cos(φ_b − θ_v) · cos θ`` (``δs0`` the travel per
   chirp, ``θ_v`` the heading counter-clockwise from beam 0); ``M = 1`` for a platform at rest.
   Chirps beyond the rotation come from the neighbouring rotations when given, else the rotation
   is padded circularly (PanoRadar's static case);
4. **range FFT** over the samples and the magnitude. Range bin ``k`` is evaluated at frequency
   ``k + 0.5`` (the samples are multiplied by ``exp(−jπ i / n_samples)`` first), so its centre is
   ``(k + 0.5) · Δr`` as docs/format.md §2 has it (PanoRadar's bins sit at ``k · Δr``).

**Where ranges are measured from.** The azimuth term replaces each antenna's path by the path from
the rotation axis (``r cos(h) cos θ`` is how much closer the antenna is to a far target in beam
``b``), the vertical term refers the column to antenna ``V − 1``, and the motion term removes the
platform's travel since chirp ``0`` (PanoRadar's ``b + m``: ``motion_reference="rotation_start"``,
ranges from where the rotation centre was when the rotation started) or since the beam's own chirp
(``motion_reference="beam"``, the default: only ``m`` in the motion term, ranges from where the
centre was when beam ``b`` was formed — the per-column-time centre model holodata's ground truth
traces with, :mod:`holodata.beams`). Either way the heatmap's ``range_origin`` is
``"rotation_centre"`` (:data:`holodata.messages.RANGE_ORIGINS`), recorded by :func:`beamform_attrs`.
The tests check it with point scatterers simulated at known ranges from the centre.

**Columns.** Output column ``j`` (azimuth ``−2πj/W``) is beam ``b_j = round(j·N/W)`` (``"pick"``,
the default: exact for ``N`` a multiple of ``W``, otherwise within half a chirp spacing), or a
triangle-weighted mean of the magnitudes of the beams within ``N/W`` of it (``"triangle"``; the
1024 → 512 resize of PanoRadar's ``process_raw_data.py`` is an antialiased resize of magnitudes).

**How it is computed.** At rest the azimuth sum is a correlation along the chirp axis with a kernel
that does not depend on ``b`` — circular for a padded-circular rotation — so it runs as FFTs over the
chirp axis (vertical beamforming is done after that FFT: 8 instead of 64 transforms per sample). A
moving platform makes the kernel depend on ``b`` through ``cos(φ_b − θ_v)``, so no convolution
structure is left; that path is the direct sum over the window, compiled with numba
(:mod:`holodata.radar._motion_kernel`: samples innermost, beams in parallel), with the motion phase
advanced by one complex multiplication per chirp (re-anchored exactly every 64 chirps) and
elevation rows with equal ``cos θ`` (``±θ`` of a symmetric grid) sharing the coefficients. ``device="cuda"`` (or any torch
device) runs the same
two formulations in torch. Arrays in, arrays out: no I/O here.
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ._steps import Setup, _blas_single, _elevation_groups, _row_pairs, _to_rotation_start, _vertical
from .beam_geometry import BeamformParams, Motion, _to_columns, azimuth_kernel, motion_phase_rate, range_weights, vertical_weights
from .chirp import ChirpConfig

RANGE_ORIGIN = "rotation_centre"


def beamform_attrs(chirp: ChirpConfig, params: BeamformParams, n_chirps: int | None = None, **extra) -> dict:
    """Everything a dataset must say about how its heatmaps were made (scene attrs)."""
    n = int(n_chirps or chirp.chirps_per_rotation)
    return {"method": "rotating-array beamforming (PanoRadar panoradar_SP/radar_imaging_3d.py; HoloRadar app. A)",
            "chirp": chirp.to_attrs(), "params": params.to_attrs(), "n_syn": params.syn_count(n),
            "range_origin": RANGE_ORIGIN,
            "range_resolution_m": chirp.range_resolution_m,
            "range_bin_centre": "(k+0.5)*range_resolution_m (samples x exp(-j*pi*i/n_samples) before the FFT)",
            "amplitude": "linear |sum|: mean over antennas, sums over chirps and samples with the windows, unnormalised",
            "columns": "column j = beam round(j*N/W) (pick) or triangle mean of beams within N/W (triangle)",
            "focus": FOCUS_DOC[params.focus],
            **extra}


FOCUS_DOC = {
    "far": "far-field azimuth compensation exp(j4pi r cos(h) cos(el)/lambda_i) per sample (PanoRadar)",
    "near": "near field: rows shifted by exp(j4pi r cos(el)/lambda_i), range FFT per chirp, then per range bin k the "
            "chirps summed with exp(-j4pi (d_m(R_k) + r cos(el) - R_k) f_mean/c), d_m the exact distance from chirp m's "
            "antenna to the bin centre R_k=(k+0.5)*range_resolution_m on the beam (holodata.radar.beamform_near)",
}


def static_reflection(chirps: np.ndarray) -> np.ndarray:
    """(V, S) complex64: mean over the chirp axis of ``chirps`` (C, V, S) — PanoRadar's
    ``static_refl``, taken over the whole trajectory. Accumulated in blocks (memory-mapped input)."""
    acc = np.zeros(chirps.shape[1:], np.complex128)
    step = 4096
    for a in range(0, chirps.shape[0], step):
        acc += np.asarray(chirps[a:a + step]).sum(axis=0, dtype=np.complex128)
    return (acc / max(chirps.shape[0], 1)).astype(np.complex64)


# -- entry point ---------------------------------------------------------------------------------------
def beamform(rotation: np.ndarray, chirp: ChirpConfig | None = None, params: BeamformParams | None = None, *,
             neighbours: tuple | None = None, velocity=None, chirp_period_s: float | None = None,
             static_refl: np.ndarray | None = None, device: str = "cpu") -> np.ndarray:
    """Beamform one rotation. Returns (n_range, H, W) float32 linear amplitude.

    ``rotation``: (N, V, S) complex, the N chirp frames of one rotation (chirp 0 faces +x);
    ``neighbours``: (before, after), chirps of the previous/next rotation (at least ``n_syn//2`` each;
    the last ones of ``before`` and the first of ``after`` are used), else (None, or either part None)
    circular padding; ``velocity``: (vx, vy) m/s of the platform in the radar frame at the rotation
    start (None/0 → at rest); ``chirp_period_s``: time between chirps (default ``chirp.chirp_period_s``);
    ``static_refl``: (V, S) to subtract (``params.static_removal == "trajectory"``; see
    :func:`static_reflection`); without it "trajectory" falls back to this rotation's mean.
    ``device``: ``"cpu"`` (numpy/scipy, on up to 8 threads) or a torch device (``"cuda"``, ``"cpu-torch"``
    = torch on CPU).
    """
    chirp = chirp or ChirpConfig()
    params = params or BeamformParams()
    x = np.asarray(rotation)
    V, S = chirp.n_virtual, chirp.n_samples
    if x.ndim != 3 or x.shape[1:] != (V, S):
        raise ValueError(f"rotation must be (chirps, {V}, {S}), got {x.shape}")
    N = x.shape[0]
    h = (params.syn_count(N) - 1) // 2
    if params.n_range is not None and params.n_range > S:
        raise ValueError(f"n_range {params.n_range} exceeds n_samples {S}")
    refl = _reflection(x, params, static_refl, (V, S))                  # 1. static reflection
    xp, off, circular = _padded(x, neighbours, h, (V, S))
    xp = xp.astype(np.complex64, copy=False)
    if refl is not None:
        xp = xp - refl[None]
    motion = Motion.from_velocity(velocity, chirp_period_s or chirp.chirp_period_s)
    if device != "cpu":
        if params.focus == "near":
            raise ValueError(f"focus 'near' runs on the numpy path only (device 'cpu'), got device {device!r}")
        from .beamform_torch import beamform_torch

        return beamform_torch(xp, off, circular, N, chirp, params, motion, device)
    if params.focus == "near":
        from .beamform_near import motion_near as moving
        from .beamform_near import static_near as static
    else:
        moving, static = _motion_numpy, _static_numpy
    threads = min(os.cpu_count() or 1, 8)
    if motion is None:
        return static(xp, off, circular, N, chirp, params, threads)
    if circular and h:
        xp = np.concatenate([xp[N - h:], xp, xp[:h]], axis=0)
        off = h
    return moving(xp, off, N, chirp, params, motion, threads)


def _reflection(x: np.ndarray, params: BeamformParams, static_refl, shape: tuple) -> np.ndarray | None:
    """The static reflection (V, S) to subtract from the rotation ``x``: none, the trajectory's
    (``static_refl`` as given), or the rotation's own mean (``params.static_removal``)."""
    if params.static_removal == "none":
        return None
    if params.static_removal == "trajectory" and static_refl is not None:
        return np.asarray(static_refl, np.complex64).reshape(shape)
    return static_reflection(x)


def _padded(x: np.ndarray, neighbours: tuple | None, h: int, shape: tuple) -> tuple[np.ndarray, int, bool]:
    """(chirps, index of the rotation's chirp 0 in them, circular): the rotation between the last ``h``
    chirps of the rotation before and the first ``h`` of the one after, or alone (circular padding)
    when ``neighbours`` (before, after) is None or lacks either."""
    before, after = neighbours if neighbours is not None else (None, None)
    if before is None or after is None:
        return x, 0, True
    V, S = shape
    before, after = np.asarray(before), np.asarray(after)
    for name, a in (("before", before), ("after", after)):
        if a.ndim != 3 or a.shape[1:] != (V, S) or a.shape[0] < h:
            raise ValueError(f"{name} must be (>= {h}, {V}, {S}) chirps, got {a.shape}")
    xp = np.concatenate([before[before.shape[0] - h:], x, after[:h]], axis=0) if h else x
    return xp, h, False


beamform_rotation = beamform


def beamform_recorded(chirps: np.ndarray, counts: tuple[int, int, int], motion: tuple[float, float], cycle_s: float,
                      chirp: ChirpConfig, params: BeamformParams) -> np.ndarray:
    """Beamform one rotation as a rig records it (a ``RadarRawRotation`` message's fields): ``chirps``
    (n_before + n_rotation + n_after, V, S) complex, the rotation's own chirps with the neighbouring
    rotations' last / first chirps around them, ``counts`` = (n_before, n_rotation, n_after) (0 before
    or after: circular padding on that side); ``motion`` = (travel_per_chirp m, heading rad
    counter-clockwise from beam 0), the odometry's motion over the rotation (:class:`Motion`);
    ``cycle_s`` the rotation's duration (chirp period = cycle_s / n_rotation; ≤ 0: the chirp
    configuration's, and no motion). Returns (n_range, H, W) float32, as :func:`beamform`. What
    ``holodata ingest`` does with each raw rotation and what a corpus of raw samples (``holodata synth
    --corners --radar-output iq``) stores, so both roads are one."""
    nb, nr, na = (int(c) for c in counts)
    before, rot, after = chirps[:nb], chirps[nb:nb + nr], chirps[nb + nr:nb + nr + na]
    period = cycle_s / nr
    vel = Motion(float(motion[0]), float(motion[1])).velocity(period)    # None at rest or without a period
    return beamform(rot, chirp, params, neighbours=(before if nb else None, after if na else None),
                    velocity=vel, chirp_period_s=period if period > 0 else None)


# -- static: FFT over the chirp axis -------------------------------------------------------------------
_KCACHE: dict = {}


def _kernel_spectrum(chirp, params, st: Setup, Lf, threads=1):
    """(S, Lf, H) complex64: FFT over the chirp axis of the circularly placed kernel g[(−m) mod Lf] = K[m]."""
    key = (chirp, params, st.N, Lf)
    if key not in _KCACHE:
        import scipy.fft as sfft

        K = azimuth_kernel(chirp, params, np.cos(st.elev), st.N).astype(np.complex64)   # (H, n_syn, S)
        H, n_syn, S = K.shape
        h = (n_syn - 1) // 2
        g = np.zeros((S, Lf, H), np.complex64)
        g[:, (-np.arange(-h, h + 1)) % Lf, :] = K.transpose(2, 1, 0)
        out = sfft.fft(g, axis=1, workers=threads, overwrite_x=True)
        if len(_KCACHE) >= 2:
            _KCACHE.pop(next(iter(_KCACHE)))
        _KCACHE[key] = out
    return _KCACHE[key]


def _static_numpy(xp, off, circular, N, chirp, params, threads):
    import scipy.fft as sfft

    st = Setup.of(chirp, params, N)
    S, R, elev, H, beams, cw = st.S, st.R, st.elev, st.H, st.beams, st.cw
    Lf, q = st.fft_plan(xp.shape[0], off, circular)
    Kf = _kernel_spectrum(chirp, params, st, Lf, threads)             # (S, Lf, H)
    # vertical weights with the range weights folded in (both are per-sample factors)
    vw = (vertical_weights(chirp, elev) * range_weights(chirp, params)[None, None, :]).transpose(2, 1, 0)
    vw = np.ascontiguousarray(vw.astype(np.complex64))                 # (S, V, H)
    xf = sfft.fft(xp, n=Lf, axis=0, workers=threads)                  # (Lf, V, S)
    xf = np.ascontiguousarray(xf.transpose(2, 0, 1))                   # (S, Lf, V)
    mag = np.empty((R, H, beams.size), np.float32)
    parts = [p for p in np.array_split(np.arange(S), threads) if p.size]
    blk = 16
    with _blas_single(), ThreadPoolExecutor(max_workers=len(parts)) as pool:
        for a in range(0, H, blk):
            sl = slice(a, min(a + blk, H))
            hb = sl.stop - sl.start
            y = np.empty((S, beams.size, hb), np.complex64)

            def part(ss, sl=sl, hb=hb, y=y):
                s0, s1 = int(ss[0]), int(ss[-1]) + 1
                Y = np.matmul(xf[s0:s1], vw[s0:s1, :, sl])             # vertical beamforming
                Y *= Kf[s0:s1, :, sl]                                  # × azimuth kernel: correlation over chirps
                if q > 1:                                              # only every q-th beam: fold the spectrum
                    Y = Y.reshape(s1 - s0, q, Lf // q, hb).sum(axis=1) * np.float32(1.0 / q)
                    y[s0:s1] = sfft.ifft(Y, axis=1, overwrite_x=True)
                else:
                    y[s0:s1] = sfft.ifft(Y, axis=1, overwrite_x=True)[:, off + beams, :]

            list(pool.map(part, parts))
            z = sfft.fft(y, axis=0, workers=threads, overwrite_x=True)[:R]  # (R, nb, hb) range FFT
            mag[:, sl, :] = np.abs(z).transpose(0, 2, 1)
    return _to_columns(mag, cw)


# -- moving platform: direct sum -----------------------------------------------------------------------


_AKCACHE: dict = {}


def _azimuth_kernel64(chirp, params, N):
    key = (chirp, params, N)
    if key not in _AKCACHE:
        if len(_AKCACHE) >= 2:
            _AKCACHE.pop(next(iter(_AKCACHE)))
        _AKCACHE[key] = azimuth_kernel(chirp, params, np.cos(params.grid.elevations()), N).astype(np.complex64)
    return _AKCACHE[key]


def _motion_numpy(xp, off, N, chirp, params, motion, threads):
    import scipy.fft as sfft

    st = Setup.of(chirp, params, N)
    S, R, elev, H, beams, cw = st.S, st.R, st.elev, st.H, st.beams, st.cw
    vw = vertical_weights(chirp, elev).transpose(2, 1, 0).astype(np.complex64)   # (S, V, H)
    rw = range_weights(chirp, params).astype(np.complex64)
    # vertical beamforming of every padded chirp: (H, L, S)
    X = _vertical(xp, vw, threads)
    K = _azimuth_kernel64(chirp, params, N)                                       # (H, n_syn, S)
    rows = _row_pairs(_elevation_groups(elev))
    gam = np.stack([motion_phase_rate(chirp, params, motion, float(np.cos(elev[r0])), beams, N)
                    for r0 in rows[:, 0]])                                        # (G, nb, S)
    y = np.empty((H, beams.size, S), np.complex64)
    from ._motion_kernel import motion_sums

    motion_sums(X, rows, off, beams, K, gam, y, threads)
    if params.motion_reference == "rotation_start":
        _to_rotation_start(y, rows, gam, beams)
    mag = np.abs(sfft.fft(y * rw, axis=2, workers=threads)[:, :, :R]).transpose(2, 0, 1)   # (R, H, nb)
    return _to_columns(mag, cw)
