"""Rotating mmWave radar forward model: one (n_range, H, W) linear-amplitude heatmap per rotation.

Physics per beam (grid direction d_1 from the rotation centre at that column's time) and per
bounce b = 1..B of its specular path (holodata.raytrace, the return retraces the path):

    a_b = g_el(θ) · sqrt(ρ_b · lobe(α_b)) · Π_{k<b} 10^(-L_k/10) · (1 m / R_b) · exp(-j 4π R_b / λ)

``ρ_b`` backscatter reflectivity of the b-th surface, ``lobe(α) = (1-κ) exp(-α²/2σ²) + κ cos α``
(specular lobe of width σ plus a diffuse share κ, α the incidence angle), ``L_k`` the specular
reflection loss (dB) of each earlier surface, paid on the way out and back (hence /10, not /20),
``R_b`` the accumulated (one-way) path length. Spreading: two-way spherical spreading (power
∝ R⁻⁴) times the beam footprint area (∝ R²) gives amplitude ∝ 1/R for every beam-filling patch.
``g_el`` is the board's element pattern (cos θ).

Range response: a Hann-windowed 4 GHz chirp FFT (bins of c/2B = 3.75 cm), whose response to a
target at R is ``h(x) = sinc(x) + (sinc(x-1) + sinc(x+1))/2`` at bin offset x (main lobe ±2 bins,
-31 dB sidelobes), evaluated exactly per path on ±``range_taps`` bins. Angular response: the point-
spread function of the rotating-array beamformer that makes real heatmaps from raw samples
(:mod:`holodata.radar.psf`: a Hann-windowed 90° synthetic aperture on the rotation circle with
PanoRadar's far-field compensation — near-field defocus included, so it depends on the range bin —
or, with ``beamform_focus="near"``, that of the near-field-focused beamformer; and the 8-antenna
vertical column), separable, applied to the complex cube (azimuth by circular
FFT convolution per range bin and row, elevation by one banded matrix per range bin), so sidelobes
and neighbouring paths interfere coherently (speckle that changes with mm-scale motion:
λ ≈ 3.9 mm). The kernels are normalised to 1 at their peak (the amplitude model above stays the
calibration; the beamformer's defocus loss of the peak is not applied). Thermal noise is circular
complex Gaussian added before the magnitude.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
import scipy.fft as sfft

from ..conventions import RADAR_ROTATION_HZ, RADAR_ROTATION_RADIUS_M, Grid, RangeBins

C_LIGHT = 299_792_458.0


@dataclass(frozen=True)
class RadarConfig:
    """Radar model parameters (all recorded in the truth scene description)."""

    grid: Grid = field(default_factory=Grid)
    range_bins: RangeBins = field(default_factory=RangeBins)
    rotation_hz: float = RADAR_ROTATION_HZ
    rotation_radius_m: float = RADAR_ROTATION_RADIUS_M
    start_frequency_hz: float = 77e9
    bandwidth_hz: float = 4e9
    max_bounces: int = 3
    n_virtual: int = 8                 # virtual antennas in the vertical column (2 TX x 4 RX)
    antenna_spacing_m: float = 1.9e-3  # their spacing (two-way path per element per sin θ)
    chirps_per_rotation: int = 1024    # chirp positions on the rotation circle
    azimuth_fov_deg: float = 90.0      # synthetic aperture of one beam (Hann-windowed)
    azimuth_support_deg: float = 30.0  # half-width of the azimuth kernel applied
    element_beamwidth_deg: float | None = 100.0  # antennas' azimuth pattern (amplitude half at ±50°); None: isotropic
    specular_lobe_deg: float = 10.0
    range_taps: int = 3            # half-width (bins) of the exact range response per path
    elevation_taps: int = 12       # half-width (rows) of the elevation kernel
    noise_amplitude: float = 2e-3  # std of the complex thermal noise per cell (|a| = 1: ρ=1 at 1 m)
    leakage_amplitude: float = 0.05  # TX→RX coupling at the first range bins
    psf: bool = True
    beamform_focus: str = "far"    # the beamformer whose PSF the direct heatmaps carry: "far" (PanoRadar) or "near"
    encoding: str = "float16"

    @property
    def wavelength_m(self) -> float:
        return C_LIGHT / self.start_frequency_hz

    def imaging(self):
        """(ChirpConfig, n_syn): the raw-radar rig whose beamformer's point-spread function the
        heatmaps carry (:mod:`holodata.radar.psf`) and whose samples ``radar_output="iq"`` writes.
        Its sweep is the one whose range bins are ``range_bins.dr`` (c / 2B, B = slope·S/fs; 3.997 GHz
        for 3.75 cm, as PanoRadar's 3.9975 GHz), so a beamformed rotation lands on the same bins."""
        from ..radar.beam_geometry import BeamformParams
        from ..radar.chirp import ChirpConfig

        n, S, fs = self.n_virtual, max(256, self.range_bins.n), 5.12e6
        chirp = ChirpConfig(start_frequency_hz=self.start_frequency_hz,
                            slope_hz_per_s=C_LIGHT / (2 * self.range_bins.dr) * fs / S, n_samples=S, sample_rate_hz=fs,
                            n_tx=2 if n % 2 == 0 else 1, n_rx=n // 2 if n % 2 == 0 else n,
                            antenna_spacing_m=self.antenna_spacing_m, rotation_radius_m=self.rotation_radius_m,
                            chirps_per_rotation=self.chirps_per_rotation, rotation_hz=self.rotation_hz)
        return chirp, BeamformParams(azimuth_fov_deg=self.azimuth_fov_deg).syn_count(self.chirps_per_rotation)

    def describe(self) -> dict:
        d = asdict(self)
        d["grid"] = self.grid.to_attrs()
        d["range_bins"] = self.range_bins.to_attrs()
        d["wavelength_m"] = self.wavelength_m
        d["range_resolution_from_bandwidth_m"] = C_LIGHT / (2 * self.bandwidth_hz)
        return d


_PSF_CACHE: dict = {}


def beamformer_psf(cfg: RadarConfig, n_ranges: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """The beamformer's angular PSF on ``cfg``'s grid: ``(az_spectrum, el_matrix)``.

    ``az_spectrum`` (n_range, H, W) complex64: FFT along the columns of the circular azimuth kernel
    of each range bin and row (``A(δ; θ, R) / A(0; θ, R)`` at column offsets δ within
    ``azimuth_support_deg``); ``el_matrix`` (n_range, H, H) float32: ``K[k, i, i']`` the response of row
    ``i`` to a path in row ``i'`` at range bin ``k`` (within ``elevation_taps`` rows). Both are
    computed exactly at ``n_ranges`` ranges evenly spaced in 1/R (the near-field terms go as 1/R)
    and interpolated linearly in 1/R to the bin centres (error < 0.01 of the peak at 32 ranges)."""
    from ..radar.psf import azimuth_response, elevation_response

    key = (cfg.grid, cfg.range_bins, cfg.n_virtual, cfg.antenna_spacing_m, cfg.chirps_per_rotation,
           cfg.azimuth_fov_deg, cfg.azimuth_support_deg, cfg.elevation_taps, cfg.rotation_radius_m,
           cfg.start_frequency_hz, cfg.bandwidth_hz, n_ranges, cfg.beamform_focus)
    if key in _PSF_CACHE:
        return _PSF_CACHE[key]
    chirp, n_syn = cfg.imaging()
    g, rb = cfg.grid, cfg.range_bins
    H, W, R = g.H, g.W, rb.n
    elev = g.elevations()
    r_min = 2 * cfg.rotation_radius_m
    centres = np.maximum((np.arange(R) + 0.5) * rb.dr, r_min)
    u = np.linspace(1 / centres.max(), 1 / r_min, n_ranges) if centres.max() > r_min else np.array([1 / r_min] * 2)
    wgt = np.clip(np.interp(1 / centres, u, np.arange(u.size)), 0, u.size - 1)   # fractional sample index
    lo = np.minimum(np.floor(wgt).astype(int), u.size - 2)
    t = (wgt - lo)[:, None]

    def at_bins(samples):    # (n_ranges, ...) -> (R, ...), linear in 1/R
        s = samples.reshape(samples.shape[0], -1)
        return ((1 - t) * s[lo] + t * s[lo + 1]).reshape((R,) + samples.shape[1:])

    K = int(min(W // 2, np.ceil(cfg.azimuth_support_deg / (360.0 / W))))
    offs = np.arange(-K, K + 1)
    kern = np.zeros((R, H, W), np.complex128)
    cos_rows = np.round(np.cos(elev), 12)
    for c in np.unique(cos_rows):
        A = azimuth_response(chirp, n_syn, 2 * np.pi * offs / W, [c], 1 / u,
                             focus=cfg.beamform_focus)[0]                                   # (n_ranges, 2K+1)
        A = at_bins(A / A[:, K:K + 1])
        kern[:, cos_rows == c, :] = 0
        for j, o in enumerate(offs):
            kern[:, cos_rows == c, o % W] += A[:, None, j]
    spectrum = sfft.fft(kern, axis=2).astype(np.complex64)
    el = np.zeros((R, H, H), np.float32)
    for i in range(H):
        band = np.arange(max(0, i - cfg.elevation_taps), min(H, i + cfg.elevation_taps + 1))
        E = elevation_response(chirp, n_syn, elev[i:i + 1], elev[band], 1 / u,
                               focus=cfg.beamform_focus)[:, 0, :]                           # (n_ranges, len(band))
        el[:, i, band] = at_bins(E)
    _PSF_CACHE.clear()
    _PSF_CACHE[key] = (spectrum, el)
    return spectrum, el


def range_response(x: np.ndarray) -> np.ndarray:
    """Hann-windowed FFT response at bin offset ``x`` (bins), normalised to 1 at x = 0."""
    return np.sinc(x) + 0.5 * (np.sinc(x - 1.0) + np.sinc(x + 1.0))


class RadarModel:
    """Precomputed kernels + per-frame synthesis. ``materials``: sequence of worlds.Material;
    ``face_material`` (F,) uint8 of the static scene; ``human_material`` index for the dynamic mesh."""

    def __init__(self, config: RadarConfig, materials, face_material: np.ndarray, human_material: int,
                 noise_seed: int = 0):
        self.cfg = cfg = config
        self.noise_seed = noise_seed
        self._buf = self._buf2 = self._bank = None
        g, rb = cfg.grid, cfg.range_bins
        self.H, self.W, self.R = g.H, g.W, rb.n
        self.dirs = g.directions().reshape(-1, 3)                 # (H*W,3) sensor frame
        elev = g.elevations()
        self.gain = np.repeat(np.cos(elev), g.W)                   # (H*W,)
        self.rho = np.array([m.rf_reflectivity for m in materials], np.float64)
        self.loss = np.array([10 ** (-m.rf_loss_db / 10.0) for m in materials], np.float64)
        self.kappa = np.array([m.rf_diffuse for m in materials], np.float64)
        self.face_material = np.asarray(face_material, np.int64)
        self.human_material = int(human_material)
        self._psf: tuple | None = None   # beamformer_psf(cfg), made when a heatmap first needs it (raw samples never do)
        taps = np.arange(cfg.range_taps + 1) / 1.0
        lk = np.zeros(self.R)
        if cfg.leakage_amplitude > 0:
            lk[: len(taps)] = cfg.leakage_amplitude * np.exp(-taps)
        self.leakage = lk.astype(np.float32)

    # ------------------------------------------------------------------ paths
    def paths(self, tr, origins: np.ndarray, directions: np.ndarray) -> dict:
        """Per-path complex amplitudes from a TraceResult: dict of flat arrays ``pix`` (beam index),
        ``bounce`` (1..B), ``range`` m, ``amp`` complex128 (before angular/range responses),
        ``human`` bool."""
        N, B = tr.range.shape
        d = directions.astype(np.float64)
        cum = np.ones(N)
        out = {"pix": [], "bounce": [], "range": [], "amp": [], "human": []}
        lam = self.cfg.wavelength_m
        sig = np.deg2rad(self.cfg.specular_lobe_deg)
        for b in range(B):
            f = tr.face[:, b]
            ok = f >= 0
            if not ok.any():
                break
            n = tr.normal[:, b].astype(np.float64)
            cosi = np.abs(np.einsum("ij,ij->i", np.nan_to_num(n), d))
            mat = np.where(tr.hit_dynamic[:, b], self.human_material,
                           self.face_material[np.where(ok & ~tr.hit_dynamic[:, b], f, 0)])
            alpha = np.arccos(np.clip(cosi, 0.0, 1.0))
            kap = self.kappa[mat]
            lobe = (1 - kap) * np.exp(-alpha ** 2 / (2 * sig ** 2)) + kap * cosi
            R = tr.range[:, b].astype(np.float64)
            amp = self.gain * np.sqrt(self.rho[mat] * lobe) * cum / np.maximum(R, 0.05)
            idx = np.nonzero(ok)[0]
            out["pix"].append(idx)
            out["bounce"].append(np.full(len(idx), b + 1))
            out["range"].append(R[idx])
            out["amp"].append(amp[idx] * np.exp(-1j * 4 * np.pi * R[idx] / lam))
            out["human"].append(tr.hit_dynamic[idx, b])
            cum = cum * np.where(ok, self.loss[mat], 0.0)
            d = d + 2.0 * cosi[:, None] * np.nan_to_num(n)
            d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        empty = {"pix": np.int64, "bounce": np.int64, "range": np.float64, "amp": np.complex128, "human": bool}
        return {k: (np.concatenate(v) if v else np.zeros(0, empty[k])) for k, v in out.items()}

    # ------------------------------------------------------------------ cube
    def cube(self, paths: dict, rng: np.random.Generator | None) -> np.ndarray:
        """(n_range, H, W) float32 linear amplitude from per-path amplitudes (+ noise if ``rng``).

        Work buffers are kept between calls (no page faults per frame); the result is a new array.
        """
        H, W, R = self.H, self.W, self.R
        dr = self.cfg.range_bins.dr
        if self._buf is None:
            self._buf = np.zeros(R * H * W, np.complex64)
            self._buf2 = np.zeros((R, H, 2 * W), np.float32)
        cube = self._buf
        cube.fill(0)
        u = paths["range"] / dr - 0.5
        k0 = np.rint(u).astype(np.int64)
        amp = paths["amp"].astype(np.complex64)
        pix = paths["pix"]
        for bnc in np.unique(paths["bounce"]):  # one path per beam per bounce: unique indices per call
            sel = paths["bounce"] == bnc
            kb, ub, ab, pb = k0[sel], u[sel], amp[sel], pix[sel]
            for m in range(-self.cfg.range_taps, self.cfg.range_taps + 1):
                k = kb + m
                ok = (k >= 0) & (k < R)
                w = range_response(k[ok] - ub[ok]).astype(np.float32)
                cube[k[ok] * (H * W) + pb[ok]] += ab[ok] * w
        cube = cube.reshape(R, H, W)
        if self.cfg.leakage_amplitude > 0:
            cube += self.leakage[:, None, None]
        if self.cfg.psf:
            if self._psf is None:
                self._psf = beamformer_psf(self.cfg)
            az_spectrum, el_matrix = self._psf
            X = sfft.fft(cube, axis=2, workers=2, overwrite_x=True)
            X *= az_spectrum
            X = sfft.ifft(X, axis=2, workers=2, overwrite_x=True)
            fl = X.view(np.float32).reshape(R, H, 2 * W)
            np.matmul(el_matrix, fl, out=self._buf2)
            cube = self._buf2.view(np.complex64).reshape(R, H, W)
        if rng is not None and self.cfg.noise_amplitude > 0:
            bank = self._noise_bank(cube.size)
            o = int(rng.integers(cube.size))
            flat = cube.reshape(-1)
            flat[: cube.size - o] += bank[o:]
            flat[cube.size - o:] += bank[:o]
        return np.abs(cube)

    # ------------------------------------------------------------------ raw samples
    def raw_scale(self) -> tuple[float, float]:
        """(amplitude scale, noise std per sample) of raw samples: a path of amplitude ``a`` (the
        model above) is sent as ``a · scale`` so that the beamformer (Hann windows over the n_syn
        chirps of a beam and the samples, mean over antennas, unnormalised sums) images it at ``a``
        again; the complex noise per sample gives ``noise_amplitude`` per heatmap cell after the
        same sums (σ · sqrt(Σw_c² Σw_s² / V))."""
        from ..radar.beam_geometry import window

        chirp, n_syn = self.cfg.imaging()
        wc, ws = window("hann", n_syn), window("hann", chirp.n_samples)
        gain = float(wc.sum() * ws.sum())
        noise = self.cfg.noise_amplitude * np.sqrt(chirp.n_virtual / float((wc ** 2).sum() * (ws ** 2).sum()))
        return 1.0 / gain, float(noise)

    def iq(self, paths: dict, origins: np.ndarray, directions: np.ndarray, chirp_poses: np.ndarray,
           chirp_index: np.ndarray, rng: np.random.Generator | None) -> np.ndarray:
        """(C, V, S) complex64 raw FMCW samples of the chirps ``chirp_index`` (C,) of one rotation
        (``0..N−1`` this rotation, negative / ``>= N`` its neighbours), sent from ``chirp_poses``
        (C, 4, 4) T_world_radar at each chirp's time (the rotation centre; chirp ``n`` faces
        ``−2πn/N`` in that frame, its antennas on the circle of ``rotation_radius_m``,
        :mod:`holodata.radar.simulate`'s geometry). Every path of :meth:`paths` is a point scatterer
        at its image source: ``origins[pix] + range · directions[pix]`` (world frame; the point a
        specular chain is seen at), amplitude ``|amp|`` (the propagation phase comes from the
        geometry) times the antennas' azimuth pattern (``element_beamwidth_deg``) at its angle off
        each chirp's facing, seen by the chirps that face its half-space. Plus thermal noise and the TX→RX leakage (a return at
        zero range, the
        same in every chirp: what static-reflection removal takes out)."""
        from ..radar._iq_kernel import ChirpSites, beat_samples

        cfg = self.cfg
        chirp, _ = cfg.imaging()
        N = cfg.chirps_per_rotation
        n = np.asarray(chirp_index, np.float64)
        phi = -2 * np.pi * n / N
        face = np.stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)], axis=1)           # (C,3) radar frame
        z = chirp.antenna_heights()
        local = cfg.rotation_radius_m * face[:, None, :] + np.stack([0 * z, 0 * z, z], axis=1)[None]   # (C,V,3)
        Rw, tw = chirp_poses[:, :3, :3], chirp_poses[:, :3, 3]
        ant = np.einsum("cij,cvj->cvi", Rw, local) + tw[:, None, :]
        fw = np.einsum("cij,cj->ci", Rw, face)[:, :2]
        fw /= np.maximum(np.linalg.norm(fw, axis=1, keepdims=True), 1e-12)
        pix = paths["pix"]
        X = np.asarray(origins, np.float64)[pix] + paths["range"][:, None] * np.asarray(directions, np.float64)[pix]
        scale, noise = self.raw_scale()
        out = beat_samples(ChirpSites(ant, tw, fw), X, np.abs(paths["amp"]) * scale, chirp, cos_cut=0.0,
                           beamwidth_deg=cfg.element_beamwidth_deg)
        if cfg.leakage_amplitude > 0:
            out += np.complex64(cfg.leakage_amplitude * scale)
        if rng is not None and noise > 0:
            out += self.raw_noise(rng, out.shape)
        return out

    def raw_noise(self, rng: np.random.Generator, shape: tuple) -> np.ndarray:
        """(C, V, S) complex64 thermal noise of raw samples drawn from ``rng`` (circular Gaussian, the
        per-sample std of :meth:`raw_scale`), as :meth:`iq` adds it."""
        _, noise = self.raw_scale()
        w = rng.standard_normal(2 * int(np.prod(shape)), dtype=np.float32) * np.float32(noise / np.sqrt(2))
        return w.view(np.complex64).reshape(shape)

    def _noise_bank(self, n: int) -> np.ndarray:
        """Thermal noise: a bank of n independent circular complex Gaussian samples (drawn once per
        model from ``noise_seed``), added from a random circular offset each frame. Per-frame
        statistics are exact; frames see the bank's values at different cells."""
        if self._bank is None or len(self._bank) != n:
            g = np.random.default_rng(self.noise_seed)
            std = np.float32(self.cfg.noise_amplitude / np.sqrt(2))
            self._bank = (g.standard_normal(2 * n, dtype=np.float32) * std).view(np.complex64)
        return self._bank


def encode_heatmap(hm: np.ndarray, encoding: str) -> bytes:
    """(n_range, H, W) float -> little-endian bytes in ``encoding`` ("float16" | "float32")."""
    dt = {"float16": "<f2", "float32": "<f4"}[encoding]
    return np.ascontiguousarray(hm, dtype=dt).tobytes()
