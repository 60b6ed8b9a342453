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
chirp's facing direction (seen from the rotation centre), and only those within ``cos_cut`` of it
are summed (a scatterer behind the board is not seen). Compiled with numba (parallel over chirps); arrays in, arrays out.
The grid keeps a chirp's antennas side by side per cell (C, cells, V): the antennas of one chirp are
millimetres apart, so a scatterer's taps mostly start at the same cell for all of them and its
spread is one pass over adjacent memory (the sums, in the same order, are those of one row per
antenna to the bit; the time it saves: docs/design/performance.md, the quick demo).
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


@numba.njit(parallel=True, fastmath=True, cache=True)
def _spread(ant, cen, facing, pts, amp, cos_cut, power, k0, u_per_m, shift_per_m, M, taps, tau, out):  # pragma: no cover
    C, V = ant.shape[0], ant.shape[1]
    K = pts.shape[0]
    e3 = np.empty(taps)
    half = taps // 2
    for j in range(taps):
        e3[j] = math.exp(-(j * j) / (4 * tau))
    for c in numba.prange(C):
        fx, fy = facing[c, 0], facing[c, 1]
        zv = np.empty(V, np.complex128)                  # per antenna: phasor, φ(x0), its tap step, first cell
        gv = np.empty(V)
        sv = np.empty(V)
        bv = np.empty(V, np.int64)
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
            if power > 0:                                # the antennas' azimuth pattern cos^q
                gain = max(cos_off, 0.0) ** power
            kap = k0 + shift_per_m                       # carrier phase + the half-record shift, per metre
            a_k = amp[k] * gain
            z = complex(0.0, 0.0)
            w = complex(1.0, 0.0)
            r_prev = 0.0
            d1 = 0.0
            same = True
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
                elif v == 1:
                    d1 = R - r_prev
                    w = complex(math.cos(kap * d1), math.sin(kap * d1))
                    z = z * w
                else:
                    e = kap * (R - r_prev - d1)
                    z = z * (w * complex(1.0 - 0.5 * e * e, e))
                r_prev = R
                m0 = int(math.floor(u)) - half + 1       # cells m0 .. m0 + taps − 1 around u
                x0 = m0 - u
                # φ(x0 + j) = φ(x0) · exp(−2 x0 / 4τ)^j · exp(−j² / 4τ)
                zv[v] = z
                gv[v] = math.exp(-x0 * x0 / (4 * tau))
                sv[v] = math.exp(-2 * x0 / (4 * tau))
                bv[v] = m0 + taps                        # the grid is padded by ``taps`` cells each side
                if bv[v] != bv[0]:
                    same = False
            if same:                                     # (mostly: the antennas are mm apart)
                base = bv[0]
                for j in range(taps):
                    row = oc[base + j]
                    ej = e3[j]
                    for v in range(V):
                        row[v] += zv[v] * (gv[v] * ej)
                        gv[v] *= sv[v]
            else:
                for v in range(V):
                    g = gv[v]
                    for j in range(taps):
                        oc[bv[v] + j, v] += zv[v] * (g * e3[j])
                        g *= sv[v]


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
    if len(points):
        _spread(np.ascontiguousarray(sites.antennas, np.float64), np.ascontiguousarray(sites.centres, np.float64),
                np.ascontiguousarray(sites.facing, np.float64), np.ascontiguousarray(points, np.float64),
                np.ascontiguousarray(amplitudes, np.complex128), float(cos_cut),
                q, k0, nu_per_m * M,
                2 * np.pi * nu_per_m * (S // 2), M, TAPS, TAU, grid)
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
