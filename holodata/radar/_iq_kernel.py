"""Raw FMCW beat samples of many point scatterers, by Gaussian gridding (a type-2 non-uniform FFT).

The beat signal of chirp ``c`` at virtual antenna ``v`` is a sum of complex exponentials, one per
scatterer ``k`` at distance ``R = |p_k − a_{c,v}|`` from that antenna::

    s[c, v, i] = Σ_k amp_k · exp(j 4π f_0 R / c₀) · exp(j 2π ν_k i),   ν_k = 2 R · slope / (c₀ · fs)

(:mod:`holodata.radar.simulate`, sample ``i`` at ``f_0 + slope·i/fs``). Summed directly this costs
(scatterers × samples) per chirp and antenna. Instead each scatterer is spread with a Gaussian
``φ(x) = exp(−x²/4τ)`` onto ``M = 2·S`` frequency cells around ``u = ν·M`` (``w`` taps), the cells
are transformed with one length-``M`` FFT, and the result is divided by the Gaussian's transform
(Dutt & Rokhlin 1993; Greengard & Lee 2004, "Accelerating the nonuniform fast Fourier transform",
SIAM Rev. 46, §2). Samples are indexed from the middle (``i' = i − S/2``) so that the kept
frequencies |i'/M| ≤ 1/4 sit as far as possible from their aliases. ``τ = w / (4√2 π)`` balances
the kernel's truncation error against aliasing (``exp(−2π²τ)`` each: 1.5e-5 of the amplitude at
``w = 10``).

Each scatterer's amplitude is weighted by the antennas' azimuth pattern at its angle off the
chirp's facing direction (seen from the rotation centre; tabulated on the cosine, linear
interpolation within 1e-6 of the pattern's peak), and only those within ``cos_cut`` of it are summed
(a scatterer behind the board is not seen). Compiled with numba (parallel over chirps); arrays in,
arrays out. The grid keeps a chirp's antennas side by side per cell (C, cells, V), and a scatterer is
spread onto the same ``w + 2e`` cells for all of a chirp's antennas, ``e`` cells more on each side
than one antenna needs: the antennas are millimetres apart, so a scatterer's cell position ``u``
moves by less than ``e`` cells across them (``e`` is that bound, from the antennas' spread), and its
spread is one pass over adjacent memory. Along the antennas the carrier phase, the Gaussian at the
window's first cell and its step from cell to cell change by nearly the same factor from one antenna
to the next (the distances to a linear array): each is computed exactly for the first two antennas
and then updated by the change of that factor (≪ 1) to second or third order, so an antenna costs
no transcendental function (the sums agree with the exact per-antenna weights within 1e-5 of the
strongest sample: tests/synth/test_iq.py; the time it saves: docs/design/performance.md).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numba
import numpy as np
import scipy.fft as sfft

if TYPE_CHECKING:
    from .chirp import ChirpConfig

numba.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]

TAPS = 10                                   # Gaussian gridding width (cells)
TAU = TAPS / (4 * math.sqrt(2) * math.pi)   # its variance parameter (cells²)
PATTERN_CELLS = 4096                        # the antennas' azimuth pattern, tabulated on cos(off) in [0, 1]


@numba.njit(parallel=True, fastmath=True, cache=True)
def _spread(ant, cen, facing, pts, amp, cos_cut, pattern, k0, u_per_m, shift_per_m, M, taps, extra, tau, out):  # pragma: no cover
    C, V = ant.shape[0], ant.shape[1]
    K = pts.shape[0]
    W = taps + 2 * extra                                 # cells per scatterer, shared by a chirp's antennas
    e3 = np.empty(W)
    for j in range(W):
        e3[j] = math.exp(-(j * j) / (4 * tau))
    nt = pattern.shape[0] - 1
    c4 = 1.0 / (4 * tau)
    c2 = 1.0 / (2 * tau)
    for c in numba.prange(C):
        fx, fy = facing[c, 0], facing[c, 1]
        zv = np.empty(V, np.complex128)                  # per antenna: phasor, φ(x_v), its tap step
        gv = np.empty(V)
        sv = np.empty(V)
        oc = out[c]                                      # (cells, V): the antennas of a cell side by side
        for k in range(K):
            dx = pts[k, 0] - cen[c, 0]
            dy = pts[k, 1] - cen[c, 1]
            h = math.sqrt(dx * dx + dy * dy)
            if h < 1e-9:
                continue
            cos_off = (dx * fx + dy * fy) / h
            if cos_off <= cos_cut:
                continue
            gain = 1.0
            if nt > 0:                                   # the antennas' azimuth pattern, tabulated on cos(off) in [0, 1]
                if cos_off <= 0.0:
                    continue
                t = cos_off * nt
                i = min(int(t), nt - 1)
                gain = pattern[i] + (t - i) * (pattern[i + 1] - pattern[i])
            kap = k0 + shift_per_m                       # carrier phase + the half-record shift, per metre
            a_k = amp[k] * gain
            z = complex(0.0, 0.0)
            w = complex(1.0, 0.0)
            r_prev = 0.0
            d1 = 0.0
            m0 = 0
            x_prev = 0.0
            dx_prev = 0.0
            ratio = 1.0
            x_pp = 0.0
            step = 1.0
            for v in range(V):
                ex = pts[k, 0] - ant[c, v, 0]
                ey = pts[k, 1] - ant[c, v, 1]
                ez = pts[k, 2] - ant[c, v, 2]
                R = math.sqrt(ex * ex + ey * ey + ez * ez)
                u = R * u_per_m
                # the phase exp(j κ R_v) advances by nearly the same step from antenna to antenna:
                # exact for v = 0 and 1, then the step's change (≪ 1 rad) to second order
                if v == 0:
                    z = a_k * complex(math.cos(kap * R), math.sin(kap * R))
                    m0 = int(math.floor(u)) - taps // 2 + 1 - extra   # cells m0 .. m0 + W − 1, for every antenna
                    x = m0 - u
                    gv[0] = math.exp(-x * x * c4)        # φ(x + j) = φ(x) · exp(−2x / 4τ)^j · exp(−j² / 4τ)
                    sv[0] = math.exp(-x * c2)
                elif v == 1:
                    d1 = R - r_prev
                    w = complex(math.cos(kap * d1), math.sin(kap * d1))
                    z = z * w
                    x = m0 - u
                    dx_ = x - x_prev
                    ratio = math.exp(-(x * x - x_prev * x_prev) * c4)
                    step = math.exp(-dx_ * c2)
                    gv[1] = gv[0] * ratio
                    sv[1] = sv[0] * step
                    dx_prev = dx_
                else:
                    e = kap * (R - r_prev - d1)
                    z = z * (w * complex(1.0 - 0.5 * e * e, e))
                    # likewise φ(x_v) and its step: their ratios to antenna v − 1's change by ≪ 1
                    x = m0 - u
                    dx_ = x - x_prev
                    da = (x * x - x_prev * x_prev - (x_prev * x_prev - x_pp * x_pp)) * c4
                    ratio *= 1.0 - da * (1.0 - da * (0.5 - da / 6.0))
                    ds = (dx_ - dx_prev) * c2
                    step *= 1.0 - ds * (1.0 - 0.5 * ds)
                    gv[v] = gv[v - 1] * ratio
                    sv[v] = sv[v - 1] * step
                    dx_prev = dx_
                x_pp = x_prev
                x_prev = x
                r_prev = R
                zv[v] = z
            base = m0 + taps                             # the grid is padded by ``taps`` cells each side
            for j in range(W):
                row = oc[base + j]
                ej = e3[j]
                for v in range(V):
                    row[v] += zv[v] * (gv[v] * ej)
                    gv[v] *= sv[v]


@dataclass(frozen=True, eq=False)
class ChirpSites:
    """Where each of C chirps is sent from (the same frame, world or radar, as the scatterers):
    ``antennas`` (C, V, 3) m every virtual antenna of every chirp, ``centres`` (C, 3) m the rotation
    centre at each chirp, ``facing`` (C, 2) the unit horizontal direction each chirp faces."""

    antennas: np.ndarray
    centres: np.ndarray
    facing: np.ndarray


def beat_samples(sites: ChirpSites, points: np.ndarray, amplitudes: np.ndarray, chirp: ChirpConfig, *,
                 cos_cut: float = -1.0, beamwidth_deg: float | None = None, workers: int | None = None) -> np.ndarray:
    """(C, V, S) complex64 beat samples (see the module docstring) of the chirps sent from ``sites``
    (:class:`ChirpSites`) with the ramp and sampling of ``chirp`` (start frequency, slope, sample rate,
    ``S`` = its samples per chirp).

    ``points`` (K, 3) m and ``amplitudes`` (K,) complex: the scatterers; ``cos_cut``: scatterers seen
    from the centre at more than arccos(cos_cut) from the facing direction are left out (−1: none);
    ``beamwidth_deg``: the antennas' azimuth pattern on the (two-way) amplitude, ``cos(off)^q`` with
    ``q`` such that it is half at ±beamwidth/2 — a patch antenna's smooth roll-off to nothing at 90°
    (None: isotropic); ``workers``: threads of the final FFT (default 2)."""
    from .chirp import SPEED_OF_LIGHT

    S = int(chirp.n_samples)
    M = 2 * S
    C, V = sites.antennas.shape[:2]
    grid = np.zeros((C, M + 4 * TAPS, V), np.complex128)   # padded: no modulo in the inner loop
    k0 = 4 * np.pi * chirp.start_frequency_hz / SPEED_OF_LIGHT
    nu_per_m = 2 * chirp.slope_hz_per_s / (SPEED_OF_LIGHT * chirp.sample_rate_hz)      # cycles per sample per metre
    q = 0.0 if beamwidth_deg is None else float(np.log(0.5) / np.log(np.cos(np.deg2rad(beamwidth_deg) / 2)))
    pattern = np.zeros(1) if beamwidth_deg is None else np.linspace(0.0, 1.0, PATTERN_CELLS + 1) ** q
    if len(points):
        ant = np.ascontiguousarray(sites.antennas, np.float64)
        extra = int(np.ceil(np.linalg.norm(ant - ant[:, :1], axis=2).max() * nu_per_m * M))
        if extra > TAPS // 2:   # the grid's padding holds the window of an array up to TAPS/2 cells across
            raise ValueError(f"a chirp's antennas span {extra} frequency cells (at most {TAPS // 2} supported)")
        _spread(ant, np.ascontiguousarray(sites.centres, np.float64),
                np.ascontiguousarray(sites.facing, np.float64), np.ascontiguousarray(points, np.float64),
                np.ascontiguousarray(amplitudes, np.complex128), float(cos_cut),
                pattern, k0, nu_per_m * M,
                2 * np.pi * nu_per_m * (S // 2), M, TAPS, extra, TAU, grid)
    grid = grid.transpose(0, 2, 1)              # (C, V, cells)
    p = TAPS
    folded = grid[..., p:p + M]                 # cell m sits at m + TAPS; fold the padding back (mod M)
    folded[..., :grid.shape[-1] - p - M] += grid[..., p + M:]
    folded[..., M - p:] += grid[..., :p]
    G = sfft.ifft(folded, axis=-1, workers=workers or 2) * M
    ip = np.arange(S) - S // 2                                             # i' = i − S/2
    phi_hat = np.sqrt(4 * np.pi * TAU) * np.exp(-4 * np.pi ** 2 * TAU * (ip / M) ** 2)
    return (G[..., ip % M] / phi_hat).astype(np.complex64)


__all__ = ["ChirpSites", "beat_samples", "TAPS", "TAU"]
