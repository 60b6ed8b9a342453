"""The rotating-array imaging algorithm written out as plain direct sums (no FFT over chirps, no
shared coefficients, no recurrences), straight from FIELD-NOTES §"Raw radar" / PanoRadar's
``radar_imaging_3d.py``: the reference the fast beamformer (:mod:`holodata.radar.beamform`) is
checked against in ``tests/radar/test_beamform.py`` and timed against in ``benchmarks/beamform.py``.
complex128 throughout. Only the windows come from holodata (numpy's own functions).
"""
from __future__ import annotations

import math

import numpy as np

from holodata.radar.beam_geometry import window


def _inputs(rotation, chirp, params, neighbours, velocity, chirp_period_s, static_refl):
    """What both references start from: the rotation's shape (N, V, S); ``chirp_at(n)``, chirp
    position n (neighbouring rotations' chirps, or circular without them) minus the static
    reflection; and the platform's motion (moving, travel per chirp ds0 in m, heading theta_v)."""
    x = np.asarray(rotation, np.complex128)
    before, after = neighbours if neighbours is not None else (None, None)
    N, V, S = x.shape
    if params.static_removal == "none":
        refl = np.zeros((V, S))
    elif params.static_removal == "trajectory" and static_refl is not None:
        refl = np.asarray(static_refl, np.complex128)
    else:
        refl = x.mean(axis=0)

    def chirp_at(n):
        if before is None or after is None:
            c = x[n % N]
        elif n < 0:
            c = np.asarray(before, np.complex128)[len(before) + n]
        elif n >= N:
            c = np.asarray(after, np.complex128)[n - N]
        else:
            c = x[n]
        return c - refl

    moving = velocity is not None and math.hypot(*velocity[:2]) > 0
    ds0 = theta_v = 0.0
    if moving:
        T = chirp.chirp_period_s if chirp_period_s is None else chirp_period_s
        ds0 = math.hypot(*velocity[:2]) * T
        theta_v = math.atan2(velocity[1], velocity[0])
    return (N, V, S), chirp_at, moving, ds0, theta_v


def beamform_direct(rotation, chirp, params, *, neighbours=None, velocity=None, chirp_period_s=None,
                    static_refl=None, beams=None, elevation_rows=None) -> np.ndarray:
    """(n_range, len(rows), len(beams)) float64 magnitudes for beams ``beams`` (default: every chirp
    position) and elevation rows ``elevation_rows`` (default all); columns are not decimated here
    (see :func:`columns_direct`)."""
    (N, V, S), chirp_at, moving, ds0, theta_v = _inputs(rotation, chirp, params, neighbours, velocity,
                                                        chirp_period_s, static_refl)
    R = params.n_range or S
    n_syn = params.syn_count(N)
    h = (n_syn - 1) // 2
    lam = chirp.wavelengths()
    elev = params.grid.elevations()
    rows = range(elev.size) if elevation_rows is None else elevation_rows
    beams = range(N) if beams is None else beams
    wc = window(params.chirp_window, n_syn)
    ws = window(params.sample_window, S)
    half_bin = np.exp(-1j * np.pi * np.arange(S) / S)
    r = chirp.rotation_radius_m
    out = np.zeros((R, len(rows), len(beams)))
    for io, ih in enumerate(rows):
        el = elev[ih]
        d_v = chirp.antenna_spacing_m * np.sin(el) * (V - 1 - np.arange(V))
        vbf = np.exp(-2j * np.pi * d_v[:, None] / lam[None, :])                 # (V, S)
        for jo, b in enumerate(beams):
            phi_b = -2 * np.pi * b / N
            acc = np.zeros(S, np.complex128)
            for k in range(n_syn):
                m = k - h
                X = np.mean(chirp_at(b + m) * vbf, axis=0)                        # vertical beamforming
                hh = 2 * np.pi * m / N                                             # angle offset from beam b
                term = X * wc[k] * ws * np.exp(4j * np.pi * r * np.cos(hh) * np.cos(el) / lam)
                if moving:
                    ds = ds0 * np.cos(phi_b - theta_v) * np.cos(el)
                    steps = (b + m) if params.motion_reference == "rotation_start" else m
                    term = term * np.exp(2j * np.pi * 2 * steps * ds / lam)
                acc += term
            out[:, io, jo] = np.abs(np.fft.fft(acc * half_bin))[:R]
    return out


def columns_direct(mag_all_beams: np.ndarray, params) -> np.ndarray:
    """(R, H, N) magnitudes of every beam → (R, H, W) columns: beam round(j·N/W) (pick) or the
    triangle-weighted mean of beams within N/W of column j's position j·N/W (triangle)."""
    R, H, N = mag_all_beams.shape
    W = params.grid.W
    out = np.zeros((R, H, W))
    for j in range(W):
        c = j * N / W
        if params.azimuth_decimation == "pick":
            out[:, :, j] = mag_all_beams[:, :, int(math.floor(c + 0.5)) % N]
            continue
        s = max(N / W, 1.0)
        tot = 0.0
        for b in range(int(math.floor(c - s)), int(math.ceil(c + s)) + 1):
            w = 1.0 - abs(b - c) / s
            if w > 0:
                out[:, :, j] += w * mag_all_beams[:, :, b % N]
                tot += w
        out[:, :, j] /= tot
    return out


def beamform_direct_near(rotation, chirp, params, *, neighbours=None, velocity=None, chirp_period_s=None,
                         static_refl=None, beams=None, elevation_rows=None) -> np.ndarray:
    """The near-field variant (``focus="near"``, :mod:`holodata.radar.beamform_near`) as direct sums:
    per beam, row and chirp of its window, vertical beamforming, the shift ``exp(j4π r cos θ/λ_i)``, the
    sample window and the half-bin factor, the range FFT, then per range bin the sum
    over chirps with ``exp(−j4π (d_m(R_k) + r cos θ − R_k) f̄/c)`` (exact distance ``d_m`` from chirp m's
    antenna to the bin centre ``R_k`` on the beam). Same shapes as :func:`beamform_direct`."""
    (N, V, S), chirp_at, moving, ds0, theta_v = _inputs(rotation, chirp, params, neighbours, velocity,
                                                        chirp_period_s, static_refl)
    R = params.n_range or S
    n_syn = params.syn_count(N)
    h = (n_syn - 1) // 2
    f = chirp.start_frequency_hz + chirp.slope_hz_per_s * np.arange(S) / chirp.sample_rate_hz
    c = 299_792_458.0
    lam = c / f
    fbar = f.mean()
    elev = params.grid.elevations()
    rows = range(elev.size) if elevation_rows is None else elevation_rows
    beams = range(N) if beams is None else beams
    wc = window(params.chirp_window, n_syn)
    ws = window(params.sample_window, S)
    r = chirp.rotation_radius_m
    Rk = (np.arange(R) + 0.5) * chirp.range_resolution_m
    out = np.zeros((R, len(rows), len(beams)))
    for io, ih in enumerate(rows):
        el = elev[ih]
        d_v = chirp.antenna_spacing_m * np.sin(el) * (V - 1 - np.arange(V))
        vbf = np.exp(-2j * np.pi * d_v[:, None] / lam[None, :])                 # (V, S)
        shift = np.exp(4j * np.pi * r * np.cos(el) / lam) * ws * np.exp(-1j * np.pi * np.arange(S) / S)
        for jo, b in enumerate(beams):
            phi_b = -2 * np.pi * b / N
            acc = np.zeros(R, np.complex128)
            for k in range(n_syn):
                m = k - h
                X = np.mean(chirp_at(b + m) * vbf, axis=0)                        # vertical beamforming
                Z = np.fft.fft(X * shift)[:R]                                      # range profile (R,)
                hh = 2 * np.pi * m / N
                d = np.sqrt(Rk ** 2 + r * r - 2 * Rk * r * np.cos(el) * np.cos(hh))
                term = Z * wc[k] * np.exp(-4j * np.pi * (d + r * np.cos(el) - Rk) * fbar / c)
                if moving:
                    ds = ds0 * np.cos(phi_b - theta_v) * np.cos(el)
                    steps = (b + m) if params.motion_reference == "rotation_start" else m
                    term = term * np.exp(4j * np.pi * steps * ds * fbar / c)
                acc += term
            out[:, io, jo] = np.abs(acc)
    return out
