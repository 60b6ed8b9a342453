"""Angular point-spread function of the rotating-array beamformer (:mod:`holodata.radar.beamform`) at
the band's centre wavelength λ — what synth's direct heatmap path (:mod:`holodata.synth.radar`)
convolves its paths with, so that its heatmaps have the main lobes and sidelobes of heatmaps
beamformed from raw samples (``tests/synth/test_radar.py`` compares both).

Azimuth (one elevation row θ, a point at range R from the rotation centre and azimuth offset δ
from the beam): the beam sums the ``n_syn`` chirps ``m = −h..h`` around it with the chirp window
``w_m`` and the far-field compensation ``exp(j4π r cos(mΔφ) cos θ / λ)`` (``Δφ = 2π/N``); the point
is ``d_m = sqrt(R² + r² − 2Rr cos θ cos(mΔφ + δ))`` from chirp ``m``'s antenna, so

    A(δ; θ, R) = Σ_m w_m exp(j 4π [d_m − R + r cos θ cos(mΔφ)] / λ) / Σ_m w_m

(``R = ∞``: the far field, ``d_m − R → −r cos θ cos(mΔφ + δ)``). With near-field focusing
(``focus="near"``, :mod:`holodata.radar.beamform_near`) the compensation is the exact distance to
the focal point, ``R − r cos θ cos(mΔφ)`` above becomes ``sqrt(R² + r² − 2Rr cos θ cos(mΔφ))``. At a few metres the far-field
compensation leaves a quadratic phase over the 90° arc (``r² sin²/2R``, several radians at 3 m):
the main lobe widens and the near sidelobes rise, as in real heatmaps.

Elevation (a point at θ_p seen in row θ_r, at the azimuth peak): the vertical mean over the ``V``
virtual antennas (``d_v = s (V−1−v)``) gives the Dirichlet kernel
``D = sin(Vψ/2) / (V sin(ψ/2))``, ``ψ = 2π s (sin θ_p − sin θ_r) / λ`` (its linear phase dropped,
its sign kept), and the azimuth compensation made for ``cos θ_r`` loses coherence on a point at
``cos θ_p``: ``C = |A(0; θ_p → θ_r, R)| / |A(0; θ_p, R)|`` (the sum above with ``cos θ_p`` in ``d_m`` and
``cos θ_r`` in the compensation, relative to the point's own row). The elevation kernel is ``D · C``,
real, 1 at ``θ_p = θ_r``.
Arrays in, arrays out.
"""
from __future__ import annotations

import numpy as np

from .beam_geometry import window
from .chirp import SPEED_OF_LIGHT, ChirpConfig


def centre_wavelength(chirp: ChirpConfig) -> float:
    """Wavelength (m) at the mean sample frequency."""
    return float(SPEED_OF_LIGHT / chirp.frequencies().mean())


def _dirichlet(psi: np.ndarray, V: int) -> np.ndarray:
    """sin(Vψ/2) / (V sin(ψ/2)) (1 at ψ = 0): the mean of exp(jψ(V−1−v)) over v, its linear phase
    exp(jψ(V−1)/2) taken out."""
    half = np.sin(psi / 2)
    small = np.abs(half) < 1e-9
    return np.where(small, 1.0, np.sin(V * psi / 2) / (V * np.where(small, 1.0, half)))


def _aperture(n_syn: int, chirp_window: str, n_chirps: int):
    """(chirp angle offsets mΔφ (rad), normalised window) of one beam's synthetic aperture."""
    h = (n_syn - 1) // 2
    w = window(chirp_window, n_syn)
    return 2 * np.pi * np.arange(-h, h + 1) / n_chirps, w / w.sum()


def _compensated(r, R, cos_r, a, focus):
    """The path the beamformer's azimuth compensation assumes from chirp offset angle ``a`` (up to a
    constant): far field ``R − r cos θ_r cos a``; near (``focus="near"``) the exact distance to the
    focal point at ``R`` on the beam."""
    if focus == "near":
        return np.sqrt(R * R + r * r - 2 * R * r * cos_r * np.cos(a))
    return R - r * cos_r * np.cos(a)


def _sum(chirp, ang, w, R, cos_p, cos_r, delta, focus="far"):
    """Σ_m w_m exp(j4π[d_m − (compensated path)]/λ), broadcast over R, cos_p, cos_r, delta."""
    r = chirp.rotation_radius_m
    k = 4 * np.pi / centre_wavelength(chirp)
    a = ang.reshape((1,) * np.ndim(np.broadcast(R, cos_p, cos_r, delta)) + (-1,))
    R, cos_p, cos_r, delta = (np.asarray(v, float)[..., None] for v in (R, cos_p, cos_r, delta))
    if np.all(np.isinf(R)):
        res = r * (cos_r * np.cos(a) - cos_p * np.cos(a + delta))
    else:
        d = np.sqrt(R * R + r * r - 2 * R * r * cos_p * np.cos(a + delta))
        res = d - _compensated(r, R, cos_r, a, focus)
    return np.exp(1j * k * res) @ w


def azimuth_response(chirp: ChirpConfig, n_syn: int, offsets_rad, cos_el, ranges_m=np.inf, *,
                     chirp_window: str = "hann", n_chirps: int | None = None, focus: str = "far") -> np.ndarray:
    """(len(cos_el), len(ranges), len(offsets)) complex128: A(δ; θ, R) above (``ranges_m`` = inf:
    far field); ``focus`` as :class:`~holodata.radar.beam_geometry.BeamformParams` (``"near"``: the
    compensation is the exact distance, so the response is the far-field-like main lobe at every R)."""
    ang, w = _aperture(n_syn, chirp_window, int(n_chirps or chirp.chirps_per_rotation))
    ce = np.asarray(cos_el, float).reshape(-1, 1, 1)
    R = np.maximum(np.asarray(ranges_m, float).reshape(1, -1, 1), 2 * chirp.rotation_radius_m)
    d = np.asarray(offsets_rad, float).reshape(1, 1, -1)
    return _sum(chirp, ang, w, R, ce, ce, d, focus)


def elevation_response(chirp: ChirpConfig, n_syn: int, elev_rows, elev_points, ranges_m=np.inf, *,
                       chirp_window: str = "hann", n_chirps: int | None = None, focus: str = "far") -> np.ndarray:
    """(len(ranges), len(rows), len(points)) float64: the elevation kernel above, 1 at θ_p = θ_r."""
    ang, w = _aperture(n_syn, chirp_window, int(n_chirps or chirp.chirps_per_rotation))
    R = np.maximum(np.asarray(ranges_m, float).reshape(-1, 1, 1, 1), 2 * chirp.rotation_radius_m)
    er = np.asarray(elev_rows, float).reshape(1, -1, 1, 1)
    ep = np.asarray(elev_points, float).reshape(1, 1, -1, 1)
    a = ang.reshape(1, 1, 1, -1)
    r, lam, V = chirp.rotation_radius_m, centre_wavelength(chirp), chirp.n_virtual
    k = 4 * np.pi / lam

    def response(cos_p, sin_p, cos_r, sin_r):
        if np.all(np.isinf(R)):
            res, sin_seen = r * (cos_r - cos_p) * np.cos(a), sin_p
        else:
            d = np.sqrt(R * R + r * r - 2 * R * r * cos_p * np.cos(a))
            res, sin_seen = d - _compensated(r, R, cos_r, a, focus), R * sin_p / d   # elevation seen from the antenna
        psi = 2 * np.pi * chirp.antenna_spacing_m * (sin_seen - sin_r) / lam
        return np.abs((np.exp(1j * (k * res + psi * (V - 1) / 2)) * _dirichlet(psi, V)) @ w)

    out = response(np.cos(ep), np.sin(ep), np.cos(er), np.sin(er))
    own = response(np.cos(ep), np.sin(ep), np.cos(ep), np.sin(ep))
    return out / own
