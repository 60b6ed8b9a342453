"""Imaging parameters and beam geometry of the rotating-array beamformer (:mod:`holodata.radar.beamform`):
:class:`BeamformParams` and :class:`Motion` (the platform's travel during a rotation), windows, the
vertical and azimuth compensations, range weights, which formed beam each output column takes,
and the motion phase per chirp. Shared by the numpy, near-field and torch paths
(:mod:`holodata.radar.beamform_near`, :mod:`holodata.radar.beamform_torch`) so all form the same
beams; imports nothing of the beamformers (they import it). Arrays in, arrays out."""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

from ..conventions import Grid
from .chirp import SPEED_OF_LIGHT, ChirpConfig

WINDOWS = ("hann", "hamming", "blackman", "rect")
STATIC_REMOVAL = ("trajectory", "rotation", "none")
DECIMATION = ("pick", "triangle")
MOTION_REFERENCES = ("beam", "rotation_start")
FOCUS = ("far", "near")


@dataclass(frozen=True)
class BeamformParams:
    """Imaging parameters. Angles in degrees here (they are attributes and flags); radians inside.

    ``grid``: the beams formed (:class:`~holodata.conventions.Grid`: H elevation rows, W azimuth
    columns; default 64×512, ±45°). In attributes it is written as PanoRadar's ``n_elevation``,
    ``n_azimuth``, ``elevation_max_deg``, ``elevation_min_deg`` (:meth:`to_attrs`).
    ``n_syn``: chirps per beam (odd); ``None`` → PanoRadar's ``int(fov/360 · N)`` made odd, from
    ``azimuth_fov_deg`` and the rotation's chirp count ``N`` (257 for 1024 chirps and 90°).
    ``n_range``: range bins kept (the first ``n_range`` of the ``n_samples``-point FFT; ``None`` → all).
    ``focus``: ``"far"`` — PanoRadar's far-field azimuth compensation (the default; what real
    PanoRadar heatmaps are); ``"near"`` — back-projection with the exact distance from every chirp's
    antenna to each range bin's centre (:mod:`holodata.radar.beamform_near`; docs/design/radar.md).
    """

    grid: Grid = field(default_factory=Grid)
    azimuth_fov_deg: float = 90.0
    n_syn: int | None = None
    chirp_window: str = "hann"
    sample_window: str = "hann"
    n_range: int | None = None
    static_removal: str = "trajectory"
    azimuth_decimation: str = "pick"
    motion_reference: str = "beam"
    focus: str = "far"

    def __post_init__(self) -> None:
        if not isinstance(self.grid, Grid):
            raise TypeError(f"grid must be a holodata.conventions.Grid, got {type(self.grid).__name__}")
        if not 0 < self.azimuth_fov_deg <= 360:
            raise ValueError(f"azimuth_fov_deg must be in (0, 360], got {self.azimuth_fov_deg}")
        if self.n_syn is not None and (self.n_syn < 1 or self.n_syn % 2 == 0):
            raise ValueError(f"n_syn must be a positive odd number, got {self.n_syn}")
        for name, ok in (("chirp_window", WINDOWS), ("sample_window", WINDOWS), ("static_removal", STATIC_REMOVAL),
                         ("azimuth_decimation", DECIMATION), ("motion_reference", MOTION_REFERENCES),
                         ("focus", FOCUS)):
            if getattr(self, name) not in ok:
                raise ValueError(f"{name} must be one of {', '.join(ok)}, got {getattr(self, name)!r}")
        if self.n_range is not None and self.n_range < 1:
            raise ValueError(f"n_range must be >= 1, got {self.n_range}")

    def syn_count(self, n_chirps: int) -> int:
        """Chirps per beam for a rotation of ``n_chirps`` (odd, at most ``n_chirps``)."""
        if self.n_syn is not None:
            n = self.n_syn
        else:
            n = int(np.deg2rad(self.azimuth_fov_deg) / (2 * np.pi) * n_chirps)
            n = n if n % 2 == 1 else n + 1
        if n > n_chirps:
            raise ValueError(f"n_syn {n} exceeds the rotation's {n_chirps} chirps")
        return n

    def to_attrs(self) -> dict:
        """Flat attributes: the grid as ``n_elevation``, ``n_azimuth``, ``elevation_max_deg``,
        ``elevation_min_deg`` (in that order, first), then the other fields in declaration order."""
        g = self.grid
        return {"n_elevation": g.H, "n_azimuth": g.W, "elevation_max_deg": g.elev_max_deg,
                "elevation_min_deg": g.elev_min_deg,
                **{f.name: getattr(self, f.name) for f in fields(self) if f.name != "grid"}}

    @classmethod
    def from_attrs(cls, attrs: dict) -> BeamformParams:
        """The inverse of :meth:`to_attrs`; keys it does not know are ignored, missing ones take the defaults."""
        d = Grid()
        grid = Grid(attrs.get("n_elevation", d.H), attrs.get("n_azimuth", d.W),
                    attrs.get("elevation_max_deg", d.elev_max_deg), attrs.get("elevation_min_deg", d.elev_min_deg))
        names = {f.name for f in fields(cls)} - {"grid"}
        return cls(grid=grid, **{k: v for k, v in attrs.items() if k in names})


@dataclass(frozen=True)
class Motion:
    """Platform motion during one rotation: travel per chirp ``ds0`` (m) and heading ``theta_v``
    (rad, counter-clockwise from beam 0 = the radar frame's +x at the rotation's start)."""

    ds0: float
    theta_v: float

    @classmethod
    def from_velocity(cls, velocity, chirp_period_s: float) -> Motion | None:
        """From (vx, vy) m/s in the radar frame at the rotation start; None for a platform at rest."""
        if velocity is None:
            return None
        vx, vy = (float(v) for v in np.asarray(velocity, float).reshape(-1)[:2])
        speed = math.hypot(vx, vy)
        if speed == 0.0:
            return None
        return cls(speed * float(chirp_period_s), math.atan2(vy, vx))

    def velocity(self, chirp_period_s: float) -> tuple[float, float] | None:
        """(vx, vy) m/s for chirps ``chirp_period_s`` apart (the inverse of :meth:`from_velocity`);
        None at rest (``ds0`` 0) or without a period — what :func:`beamform` takes."""
        if not self.ds0 > 0 or not chirp_period_s > 0:
            return None
        speed = self.ds0 / chirp_period_s
        return speed * math.cos(self.theta_v), speed * math.sin(self.theta_v)


_REANCHOR = 64


def window(name: str, n: int) -> np.ndarray:
    """(n,) float64 window: numpy's ``hanning`` (zero end points, as PanoRadar), ``hamming``,
    ``blackman`` or ``rect`` (ones)."""
    if name == "hann":
        return np.hanning(n)
    if name == "hamming":
        return np.hamming(n)
    if name == "blackman":
        return np.blackman(n)
    if name == "rect":
        return np.ones(n)
    raise ValueError(f"unknown window {name!r} (have {', '.join(WINDOWS)})")


def vertical_weights(chirp: ChirpConfig, elev: np.ndarray) -> np.ndarray:
    """(H, V, S) complex128: ``exp(−j2π d_v/λ_i) / V``, ``d_v = spacing · sin θ · (V−1−v)`` (step 2, the mean)."""
    V = chirp.n_virtual
    lam = chirp.wavelengths()
    d = chirp.antenna_spacing_m * np.sin(elev)[:, None, None] * (V - 1 - np.arange(V))[None, :, None]
    return np.exp(-2j * np.pi * d / lam[None, None, :]) / V


def azimuth_kernel(chirp: ChirpConfig, params: BeamformParams, cos_el: np.ndarray, n_chirps: int) -> np.ndarray:
    """(E, n_syn, S) complex128 for offsets ``m = −h..h``: ``w_c[m] · exp(j4π r cos(2πm/N) cos θ / λ_i)``
    (the sample window is applied with the range FFT)."""
    n_syn = params.syn_count(n_chirps)
    h = (n_syn - 1) // 2
    m = np.arange(-h, h + 1)
    ante = chirp.rotation_radius_m * np.cos(2 * np.pi * m / n_chirps)
    lam = chirp.wavelengths()
    ph = 4 * np.pi * np.asarray(cos_el, float)[:, None, None] * ante[None, :, None] / lam[None, None, :]
    return window(params.chirp_window, n_syn)[None, :, None] * np.exp(1j * ph)


def range_weights(chirp: ChirpConfig, params: BeamformParams) -> np.ndarray:
    """(S,) complex128: sample window × ``exp(−jπ i/S)`` (bin k evaluated at k + 0.5)."""
    S = chirp.n_samples
    return window(params.sample_window, S) * np.exp(-1j * np.pi * np.arange(S) / S)


def beam_indices(n_chirps: int, n_azimuth: int) -> np.ndarray:
    """(W,) int64: the beam (chirp position) nearest to each column's azimuth, ``round(j·N/W) mod N``."""
    return np.floor(np.arange(n_azimuth) * n_chirps / n_azimuth + 0.5).astype(np.int64) % n_chirps


def column_weights(n_chirps: int, params: BeamformParams) -> tuple[np.ndarray, np.ndarray]:
    """(beams, weights): the beams to form and a (W, len(beams)) float64 matrix that maps their
    magnitudes to the output columns (``pick``: one 1 per row)."""
    W = params.grid.W
    if params.azimuth_decimation == "pick":
        b = beam_indices(n_chirps, W)
        uniq, inv = np.unique(b, return_inverse=True)
        M = np.zeros((W, uniq.size))
        M[np.arange(W), inv] = 1.0
        return uniq, M
    s = max(n_chirps / W, 1.0)
    centre = np.arange(W) * n_chirps / W
    M = np.zeros((W, n_chirps))
    lo = np.floor(centre - s).astype(int) + 1
    for j in range(W):
        for b in range(lo[j], int(np.ceil(centre[j] + s))):
            wgt = 1.0 - abs(b - centre[j]) / s
            if wgt > 0:
                M[j, b % n_chirps] += wgt
    M /= M.sum(axis=1, keepdims=True)
    used = np.flatnonzero(M.any(axis=0))
    return used, M[:, used]


def _to_columns(mag: np.ndarray, cw: np.ndarray) -> np.ndarray:
    """(R, H, nb) magnitudes of the formed beams → (R, H, W) float32 columns."""
    if cw.shape[0] == cw.shape[1] and np.array_equal(cw, np.eye(cw.shape[0])):
        return np.ascontiguousarray(mag, np.float32)
    if np.all((cw == 0) | (cw == 1)) and np.all(cw.sum(1) == 1):
        return np.ascontiguousarray(mag[:, :, cw.argmax(1)], np.float32)
    return np.ascontiguousarray(mag @ cw.T.astype(np.float32), np.float32)


def motion_phase_rate(chirp, params, motion: Motion, cos_el: float, beams: np.ndarray, N: int) -> np.ndarray:
    """(nb, S) float64: ``4π δs / λ_i`` per chirp of offset, ``δs = δs0 cos(φ_b − θ_v) cos θ``."""
    phi = -2 * np.pi * beams / N
    ds = motion.ds0 * np.cos(phi - motion.theta_v) * cos_el
    return 4 * np.pi * ds[:, None] / chirp.wavelengths()[None, :]


# -- near-field focusing (BeamformParams.focus == "near") -------------------------------------------------
def centre_frequency(chirp: ChirpConfig) -> float:
    """Hz: the mean sample frequency. After the range FFT (sample window symmetric, bin k evaluated at
    k + 0.5) a return from path length 2d has phase ``4π d f̄ / c`` plus a term of the bin alone, so
    range-domain compensations use this frequency (exactly, up to the window's range response)."""
    return float(chirp.frequencies().mean())


def range_centres(chirp: ChirpConfig, n_range: int) -> np.ndarray:
    """(n_range,) float64 metres: range-bin centres ``(k + 0.5) Δr`` from the rotation centre."""
    return (np.arange(n_range) + 0.5) * chirp.range_resolution_m


def near_sample_weights(chirp: ChirpConfig, params: BeamformParams, elev: np.ndarray) -> np.ndarray:
    """(H, S) complex128: per row, the sample-domain factors applied before the range FFT of the
    near-field path: the range weights (:func:`range_weights`) × ``exp(j4π r cos θ / λ_i)`` — the
    far-field compensation of the beam's own chirp (``m = 0``), which moves the return of a point at
    range ``R`` from the centre to bin ``R`` (its antenna is ``r cos θ`` closer) before any range-
    dependent term is applied."""
    lam = chirp.wavelengths()
    shift = np.exp(4j * np.pi * chirp.rotation_radius_m * np.cos(elev)[:, None] / lam[None, :])
    return shift * range_weights(chirp, params)[None, :]


def near_kernel(chirp: ChirpConfig, params: BeamformParams, cos_el: np.ndarray, n_chirps: int,
                n_range: int) -> np.ndarray:
    """(E, n_syn, n_range) complex128 for offsets ``m = −h..h`` and range bins ``k``:
    ``w_c[m] · exp(−j4π (d_m(R_k, θ) + r cos θ − R_k) f̄ / c)`` with the exact distance from chirp
    ``m``'s antenna to the focal point at the bin's centre ``R_k`` on the beam,
    ``d_m = sqrt(R_k² + r² − 2 R_k r cos θ cos(2πm/N))`` (back-projection; the far-field kernel
    :func:`azimuth_kernel` is its ``R → ∞`` limit up to a constant phase)."""
    n_syn = params.syn_count(n_chirps)
    h = (n_syn - 1) // 2
    ang = 2 * np.pi * np.arange(-h, h + 1) / n_chirps
    r = chirp.rotation_radius_m
    R = range_centres(chirp, n_range)[None, None, :]
    ce = np.asarray(cos_el, float)[:, None, None]
    d = np.sqrt(R * R + r * r - 2 * R * r * ce * np.cos(ang)[None, :, None])
    k = 4 * np.pi * centre_frequency(chirp) / SPEED_OF_LIGHT
    return window(params.chirp_window, n_syn)[None, :, None] * np.exp(-1j * k * (d + r * ce - R))


def near_motion_phase_rate(chirp, params, motion: Motion, cos_el: float, beams: np.ndarray, N: int,
                           n_range: int) -> np.ndarray:
    """(nb, n_range) float64: the motion phase per chirp of offset after the range FFT,
    ``4π δs f̄ / c`` (:func:`motion_phase_rate` at the centre frequency)."""
    phi = -2 * np.pi * beams / N
    ds = motion.ds0 * np.cos(phi - motion.theta_v) * cos_el
    g = 4 * np.pi * ds * centre_frequency(chirp) / SPEED_OF_LIGHT
    return np.repeat(g[:, None], n_range, axis=1)
