"""Raw FMCW beat samples of point scatterers seen by the rotating radar — the input the beamformer
(:mod:`holodata.radar.beamform`) expects, for tests, PanoRadar-layout test trajectories and synth.

Geometry (:class:`~holodata.radar.chirp.ChirpConfig`): chirp ``n`` (any integer; ``0..N−1`` is the
rotation, negative / ``>= N`` the neighbouring ones) faces azimuth ``φ_n = −2πn/N`` and is sent from
the rotation circle, ``c_n + r (cos φ_n, sin φ_n, 0) + (0, 0, z_v)``, with ``c_n = n · T_chirp · v`` the
rotation centre of a platform moving at constant velocity ``v`` (radar frame at chirp 0; no yaw) and
``z_v`` the monostatic-equivalent height of virtual antenna ``v``
(:meth:`~holodata.radar.chirp.ChirpConfig.antenna_heights`). A scatterer at distance ``R`` from that
antenna gives the de-chirped beat sample ``a · exp(j2π f_i · 2R/c)``, ``f_i`` the instantaneous
frequency of sample ``i`` — the sign convention PanoRadar's compensation terms and range FFT assume
(beat frequency ``2R·slope/c`` at a positive FFT bin). Motion within one chirp (56 µs) is neglected.
Optional: a Gaussian azimuth antenna pattern around the facing direction, thermal noise, and a
constant TX→RX leakage term (what static-reflection removal takes out).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .chirp import SPEED_OF_LIGHT, ChirpConfig


def antenna_positions(chirp: ChirpConfig, chirp_index: np.ndarray, n_chirps: int, velocity=(0.0, 0.0),
                      chirp_period_s: float | None = None) -> np.ndarray:
    """(C, V, 3) float64 metres: the virtual antennas of chirps ``chirp_index`` in the radar frame at chirp 0."""
    n = np.asarray(chirp_index, np.float64)
    T = chirp.chirp_period_s if chirp_period_s is None else float(chirp_period_s)
    v = np.zeros(3)
    v[:2] = np.asarray(velocity, float).reshape(-1)[:2]
    phi = -2 * np.pi * n / n_chirps
    base = n[:, None] * T * v[None, :]
    base[:, 0] += chirp.rotation_radius_m * np.cos(phi)
    base[:, 1] += chirp.rotation_radius_m * np.sin(phi)
    z = chirp.antenna_heights()
    out = np.repeat(base[:, None, :], z.size, axis=1)
    out[:, :, 2] += z[None, :]
    return out


@dataclass(frozen=True)
class RigEffects:
    """What a simulated rig adds to ideal isotropic point returns (:func:`simulate_chirps`):
    ``beamwidth_deg`` the −3 dB full width of a Gaussian azimuth antenna pattern around the facing
    direction (None: isotropic); ``leakage`` (V, S) complex added to every chirp (the TX→RX leakage
    static-reflection removal takes out); ``noise_std`` the per-component std of complex white noise,
    drawn from ``rng`` (a Generator or a seed; None: fresh entropy)."""

    beamwidth_deg: float | None = None
    noise_std: float = 0.0
    leakage: np.ndarray | None = None
    rng: np.random.Generator | int | None = None


def simulate_chirps(points, amplitudes=None, chirp: ChirpConfig | None = None, *, chirp_index=None,
                    n_chirps: int | None = None, velocity=(0.0, 0.0), chirp_period_s: float | None = None,
                    effects: RigEffects | None = None) -> np.ndarray:
    """(C, V, S) complex64 beat samples of point scatterers.

    ``points``: (K, 3) metres in the radar frame at chirp 0 (rotation centre at the origin, z = the
    height of the vertical phase reference); ``amplitudes``: (K,) complex (default 1);
    ``chirp_index``: (C,) chirp numbers (default ``0..n_chirps−1``, one rotation); ``n_chirps``: chirps
    per rotation (default ``chirp.chirps_per_rotation``); ``velocity``: (vx, vy) m/s, chirps
    ``chirp_period_s`` apart (default ``chirp.chirp_period_s``); ``effects``: the antenna pattern,
    leakage and noise (:class:`RigEffects`; default none of them).
    """
    chirp = chirp or ChirpConfig()
    fx = effects or RigEffects()
    N = int(n_chirps or chirp.chirps_per_rotation)
    idx = np.arange(N) if chirp_index is None else np.asarray(chirp_index, np.int64)
    P = np.asarray(points, np.float64).reshape(-1, 3)
    a = np.ones(len(P), np.complex128) if amplitudes is None else np.asarray(amplitudes, np.complex128).reshape(-1)
    if a.size != len(P):
        raise ValueError(f"{len(P)} points but {a.size} amplitudes")
    f = chirp.frequencies()
    k = 4j * np.pi * f / SPEED_OF_LIGHT                              # phase per metre of one-way distance
    out = np.zeros((idx.size, chirp.n_virtual, chirp.n_samples), np.complex64)
    step = max(1, 2048 // max(len(P), 1))              # (chirps, V, K, S) complex128 blocks of ~64 MB
    for s in range(0, idx.size, step):
        ant = antenna_positions(chirp, idx[s:s + step], N, velocity, chirp_period_s)   # (c, V, 3)
        d = P[None, None, :, :] - ant[:, :, None, :]                                    # (c, V, K, 3)
        R = np.linalg.norm(d, axis=-1)
        g = a[None, None, :]
        if fx.beamwidth_deg is not None:
            phi = -2 * np.pi * idx[s:s + step] / N
            off = np.angle(np.exp(1j * (np.arctan2(d[..., 1], d[..., 0]) - phi[:, None, None])))
            sig = np.deg2rad(fx.beamwidth_deg) / (2 * np.sqrt(2 * np.log(2)))
            g = g * np.exp(-0.5 * (off / sig) ** 2)
        out[s:s + step] = np.einsum("cvk,cvks->cvs", g * np.ones_like(R), np.exp(k[None, None, None, :] * R[..., None]))
    if fx.leakage is not None:
        out += np.asarray(fx.leakage, np.complex64).reshape(1, chirp.n_virtual, chirp.n_samples)
    if fx.noise_std > 0:
        rng = np.random.default_rng(fx.rng)
        out += (fx.noise_std * (rng.standard_normal(out.shape) + 1j * rng.standard_normal(out.shape))).astype(np.complex64)
    return out


def simulate_rotation(points, amplitudes=None, chirp: ChirpConfig | None = None, *, n_chirps: int | None = None,
                      velocity=(0.0, 0.0), pad: int = 0, **kw) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """One rotation (N, V, S) and, with ``pad > 0``, the last ``pad`` chirps of the rotation before
    and the first ``pad`` of the one after (the platform keeps moving through them): ``(rotation,
    before, after)`` — what :func:`~holodata.radar.beamform.beamform` takes (``neighbours`` = (before,
    after)). ``kw``: more of :func:`simulate_chirps`' arguments (``chirp_period_s``, ``effects``)."""
    chirp = chirp or ChirpConfig()
    N = int(n_chirps or chirp.chirps_per_rotation)
    rot = simulate_chirps(points, amplitudes, chirp, n_chirps=N, velocity=velocity, **kw)
    if pad <= 0:
        return rot, None, None
    before = simulate_chirps(points, amplitudes, chirp, chirp_index=np.arange(-pad, 0), n_chirps=N,
                             velocity=velocity, **kw)
    after = simulate_chirps(points, amplitudes, chirp, chirp_index=np.arange(N, N + pad), n_chirps=N,
                            velocity=velocity, **kw)
    return rot, before, after


def point_at(range_m: float, azimuth_rad: float, elevation_rad: float) -> np.ndarray:
    """(3,) position at ``range_m`` from the origin along (azimuth, elevation) (docs/format.md §2 directions)."""
    ce = np.cos(elevation_rad)
    return range_m * np.array([ce * np.cos(azimuth_rad), ce * np.sin(azimuth_rad), np.sin(elevation_rad)])
