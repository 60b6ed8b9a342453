"""The one place for holodata's conventions (docs/format.md §2).

Units: metres, radians, int64 nanoseconds. Frames: REP-103 (x forward, y left, z up).
Poses are ``T_world_sensor`` 4x4 float64. Nothing here imports the rest of holodata.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from enum import IntEnum

import numpy as np

FORMAT_VERSION = "1.0"

DEFAULT_H = 64
DEFAULT_W = 512
DEFAULT_ELEV_DEG = (45.0, -45.0)  # (max, min): row 0 looks up
DEFAULT_RANGE_BINS = 256
DEFAULT_RANGE_RESOLUTION_M = 0.0375
DEFAULT_MAX_RANGE_M = 9.6
DEFAULT_MAX_BOUNCES = 3
LOS_TOLERANCE_M = 0.02

# Paper radar (HoloRadar appendix / PanoRadar): rotation radius and rate.
RADAR_ROTATION_RADIUS_M = 0.105
RADAR_ROTATION_HZ = 2.0


class Label(IntEnum):
    """Per-beam, per-bounce ground-truth label (uint8)."""

    NONE = 0
    LOS_STRUCTURE = 1
    NLOS_STRUCTURE = 2
    LOS_HUMAN = 3
    NLOS_HUMAN = 4


LABEL_NAMES = {int(v): v.name.lower() for v in Label}


def is_los(label):
    """Where a label array (numpy or torch) is line-of-sight: LOS structure or LOS human."""
    return (label == Label.LOS_STRUCTURE) | (label == Label.LOS_HUMAN)


def is_human(label):
    """Where a label array (numpy or torch) is a human surface, LOS or NLOS."""
    return (label == Label.LOS_HUMAN) | (label == Label.NLOS_HUMAN)


@dataclass(frozen=True)
class Grid:
    """Radar / GT beam grid: ``(H, W)``; row 0 at ``elev_max_deg``, last row at ``elev_min_deg``.

    Column ``j`` has azimuth ``-2*pi*j/W`` (column 0 looks along +x, clockwise from above).
    """

    H: int = DEFAULT_H
    W: int = DEFAULT_W
    elev_max_deg: float = DEFAULT_ELEV_DEG[0]
    elev_min_deg: float = DEFAULT_ELEV_DEG[1]

    def __post_init__(self) -> None:
        if self.H < 2 or self.W < 1:
            raise ValueError(f"grid must have H >= 2 and W >= 1, got {self.H}x{self.W}")
        if not self.elev_max_deg > self.elev_min_deg:
            raise ValueError(
                f"elevation max ({self.elev_max_deg}) must exceed min ({self.elev_min_deg})"
            )

    @property
    def shape(self) -> tuple[int, int]:
        return (self.H, self.W)

    def elevations(self) -> np.ndarray:
        """(H,) float64 radians, row 0 = max elevation, both ends included."""
        hi, lo = np.deg2rad(self.elev_max_deg), np.deg2rad(self.elev_min_deg)
        return hi - np.arange(self.H) * (hi - lo) / (self.H - 1)

    def azimuths(self) -> np.ndarray:
        """(W,) float64 radians, ``phi_j = -2*pi*j/W``."""
        return -2.0 * np.pi * np.arange(self.W) / self.W

    def directions(self) -> np.ndarray:
        """(H, W, 3) float64 unit beam directions in the sensor frame."""
        th = self.elevations()[:, None]
        ph = self.azimuths()[None, :]
        return np.stack(
            np.broadcast_arrays(np.cos(th) * np.cos(ph), np.cos(th) * np.sin(ph), np.sin(th)),
            axis=-1,
        )

    def to_attrs(self) -> dict:
        return {"H": self.H, "W": self.W, "elev_deg": [self.elev_max_deg, self.elev_min_deg]}

    def __str__(self) -> str:
        return f"{self.H}×{self.W} beams (elevation {self.elev_max_deg:+g}° to {self.elev_min_deg:+g}°)"

    @classmethod
    def from_attrs(cls, attrs: dict) -> Grid:
        return cls(int(attrs["H"]), int(attrs["W"]), float(attrs["elev_deg"][0]), float(attrs["elev_deg"][1]))

    @classmethod
    def parse(cls, grid: str = f"{DEFAULT_H}x{DEFAULT_W}", elevation_fov: str | None = None) -> Grid:
        """Parse CLI strings ``"64x512"`` and ``"-45,45"`` (degrees, min,max in any order)."""
        try:
            h, w = (int(v) for v in grid.lower().split("x"))
        except ValueError as err:
            raise ValueError(f"grid must look like 64x512, got {grid!r}") from err
        if elevation_fov is None:
            return cls(h, w)
        try:
            a, b = (float(v) for v in elevation_fov.split(","))
        except ValueError as err:
            raise ValueError(f"elevation FOV must look like -45,45, got {elevation_fov!r}") from err
        return cls(h, w, max(a, b), min(a, b))


def reduced_grid(grid: Grid, f: int) -> Grid:
    """The beam grid after striding rows and columns by ``f`` (rows 0, f, 2f, …): what the model and
    evaluation work at for a run trained with downsample ``f``."""
    if f <= 1:
        return grid
    H2 = (grid.H + f - 1) // f
    step = (grid.elev_max_deg - grid.elev_min_deg) / (grid.H - 1)
    W2 = (grid.W + f - 1) // f
    return Grid(H2, W2, grid.elev_max_deg, grid.elev_max_deg - (H2 - 1) * f * step)


@dataclass(frozen=True)
class RangeBins:
    """Radar range axis: bin ``k`` centre ``(k + 0.5) * dr`` metres."""

    n: int = DEFAULT_RANGE_BINS
    dr: float = DEFAULT_RANGE_RESOLUTION_M

    @property
    def max_range(self) -> float:
        return self.n * self.dr

    def centres(self) -> np.ndarray:
        """(n,) float64 metres."""
        return (np.arange(self.n) + 0.5) * self.dr

    def index(self, r: np.ndarray) -> np.ndarray:
        """Bin index of range ``r`` (metres); values outside [0, max_range) give -1."""
        k = np.floor(np.asarray(r) / self.dr).astype(np.int64)
        return np.where((k >= 0) & (k < self.n), k, -1)

    def to_attrs(self) -> dict:
        return asdict(self)

    def __str__(self) -> str:
        return f"{self.n} range bins of {self.dr * 100:g} cm"

    @classmethod
    def from_attrs(cls, attrs: dict) -> RangeBins:
        return cls(int(attrs["n"]), float(attrs["dr"]))



HEATMAP_LOG_U8 = "log10_u8"   # the ``encoding`` attribute's kind of a uint8 radar/heatmap


@dataclass(frozen=True)
class LogCode:
    """Log-amplitude storage of radar heatmaps in one byte per value (what a training corpus at the
    paper's 64×512 grid stores: half of float16's bytes and a third of its compressed size).

    PanoRadar stores ``log10(a + 1e-3) / 3`` as float32 (FIELD-NOTES, "Finding people behind
    corners"); this keeps the same log10 but quantises it linearly over [lo, hi] in 255 steps:
    ``q = round(255 · (log10(a + eps) − lo) / (hi − lo))`` clipped to 0..255, and back
    ``a = 10**(lo + q · (hi − lo) / 255) − eps``. With ``lo = log10(eps)`` code 0 is amplitude 0
    exactly; the defaults (5 decades to amplitude 100) step 0.0196 decades (0.39 dB, a relative
    amplitude error within ±2.3 %), amplitudes above ``10**hi − eps`` saturate at 255.
    Monotone: the maximum of codes is the code of the maximum, so range pooling works on codes.
    Recorded as the array's ``encoding`` attribute (:meth:`to_attrs`)."""

    eps: float = 1e-3
    lo: float = -3.0
    hi: float = 2.0

    LEVELS = 255

    def encode(self, a) -> np.ndarray:
        """Linear amplitude (any shape, ≥ 0) → uint8 codes, same shape."""
        x = np.log10(np.maximum(np.asarray(a, np.float32), 0) + np.float32(self.eps))
        x -= np.float32(self.lo)
        x *= np.float32(self.LEVELS / (self.hi - self.lo))
        return np.clip(np.rint(x), 0, self.LEVELS, out=x).astype(np.uint8)

    def table(self) -> np.ndarray:
        """(256,) float32 linear amplitude of each code (code 0 → 0)."""
        a = 10.0 ** (self.lo + np.arange(256) * ((self.hi - self.lo) / self.LEVELS)) - self.eps
        return np.maximum(a, 0).astype(np.float32)

    def decode(self, q) -> np.ndarray:
        """uint8 codes → float32 linear amplitude, same shape."""
        return self.table()[np.asarray(q, np.uint8)]

    def to_attrs(self) -> dict:
        return {"kind": HEATMAP_LOG_U8, "eps": self.eps, "lo": self.lo, "hi": self.hi}

    @classmethod
    def from_attrs(cls, attrs) -> LogCode:
        """Parse an ``encoding`` attribute; ValueError naming what is wrong."""
        if not isinstance(attrs, dict) or attrs.get("kind") != HEATMAP_LOG_U8:
            raise ValueError(f"encoding must be {{'kind': {HEATMAP_LOG_U8!r}, 'eps', 'lo', 'hi'}}, got {attrs!r}")
        try:
            c = cls(float(attrs["eps"]), float(attrs["lo"]), float(attrs["hi"]))
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(f"encoding {attrs!r}: {err}") from None
        if not (c.eps > 0 and np.isfinite([c.lo, c.hi]).all() and c.hi > c.lo):
            raise ValueError(f"encoding {attrs!r}: needs eps > 0 and finite lo < hi")
        return c

def seconds_to_ns(t) -> np.ndarray:
    """Seconds (float) to int64 nanoseconds, rounded to the nearest ns."""
    return np.round(np.asarray(t, dtype=np.float64) * 1e9).astype(np.int64)


def ns_to_seconds(t_ns) -> np.ndarray:
    return np.asarray(t_ns, dtype=np.int64) / 1e9


def is_rigid(T: np.ndarray, atol: float = 1e-6) -> np.ndarray:
    """For (..., 4, 4) transforms: True where the rotation is orthonormal (det +1) and the last
    row is (0, 0, 0, 1)."""
    T = np.asarray(T, dtype=np.float64)
    R = T[..., :3, :3]
    eye = np.eye(3)
    ortho = np.all(np.abs(R @ np.swapaxes(R, -1, -2) - eye) < atol, axis=(-1, -2))
    det = np.abs(np.linalg.det(R) - 1.0) < atol
    last = np.all(np.abs(T[..., 3, :] - np.array([0.0, 0.0, 0.0, 1.0])) < atol, axis=-1)
    return ortho & det & last & np.all(np.isfinite(T), axis=(-1, -2))


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points (..., 3) through the 4x4 transform ``T`` (or a stack (..., 4, 4) broadcast against the
    points' leading axes, e.g. (1,C,4,4) with (H,C,3): one pose per column): ``R @ p + t``, float64.
    Computed as three scaled-column sums, in blocks of rows, without BLAS: ``points @ R.T`` goes to
    OpenBLAS, whose threads contend on a busy machine and made it many times slower (timings in
    docs/design/performance.md). Same values up to rounding (~1e-16 m)."""
    T = np.asarray(T, np.float64)
    P = np.asarray(points)
    out = np.empty(np.broadcast_shapes(P.shape, T.shape[:-2] + (3,)), np.float64)
    if T.ndim == 2 and P.ndim == 2 and len(P) > _CHUNK:   # blocks that stay in cache (docs/design/performance.md)
        for a in range(0, len(P), _CHUNK):
            _transform_into(T, P[a:a + _CHUNK], out[a:a + _CHUNK])
        return out
    _transform_into(T, P, out)
    return out


_CHUNK = 32768


def _transform_into(T: np.ndarray, P: np.ndarray, out: np.ndarray) -> None:
    x, y, z = P[..., 0], P[..., 1], P[..., 2]
    for i in range(3):
        o = out[..., i]
        np.multiply(x, T[..., i, 0], out=o)
        o += y * T[..., i, 1]
        o += z * T[..., i, 2]
        o += T[..., i, 3]


def transform_directions(T: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Rotate (..., 3) direction vectors by the rotation part of a 4x4 transform (float64; as
    :func:`transform_points`, without BLAS)."""
    R = np.zeros((4, 4))
    R[:3, :3] = np.asarray(T, np.float64)[:3, :3]
    return transform_points(R, dirs)


def yaw_rad(R: np.ndarray) -> float:
    """Heading (rad) of the rotation in the top-left 3x3 of ``R`` (a rotation or a 4x4 transform)
    about the z axis: ``atan2(R[1,0], R[0,0])``, the angle of a turn about z, and the yaw of the ZYX
    (yaw-pitch-roll) angles of any rotation."""
    R = np.asarray(R)
    return float(np.arctan2(R[1, 0], R[0, 0]))


def rotation_angle_deg(R: np.ndarray) -> float:
    """Angle (degrees) of the rotation in the top-left 3x3 of ``R`` (a rotation or a 4x4 transform)."""
    c = (np.trace(np.asarray(R)[:3, :3]) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))
