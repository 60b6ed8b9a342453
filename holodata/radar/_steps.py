"""Steps shared by the far-field (:mod:`holodata.radar.beamform`) and the near-field
(:mod:`holodata.radar.beamform_near`) beamformers (and the torch one, :mod:`holodata.radar.beamform_torch`):
what every path derives first from the chirp and the parameters (:class:`Setup`), vertical
beamforming over the antenna column, the decimation fold of the chirp-axis IFFT, rows that share
coefficients, single-threaded BLAS while the caller threads itself. Arrays in, arrays out; a leaf
module (no import of either beamformer)."""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from .beam_geometry import BeamformParams, column_weights
from .chirp import ChirpConfig


@dataclass(frozen=True, eq=False)
class Setup:
    """What every beamformer path derives first for a rotation of ``N`` chirps: ``S`` samples per chirp,
    ``R`` range bins kept, ``elev`` (H,) rad the grid's elevation rows (row 0 the highest), ``beams``
    (nb,) the chirp positions formed and ``cw`` (W, nb) the matrix taking their magnitudes to the
    output columns (:func:`~.beam_geometry.column_weights`)."""

    N: int
    S: int
    R: int
    elev: np.ndarray
    beams: np.ndarray
    cw: np.ndarray

    @classmethod
    def of(cls, chirp: ChirpConfig, params: BeamformParams, N: int) -> Setup:
        S = chirp.n_samples
        beams, cw = column_weights(N, params)
        return cls(N, S, params.n_range or S, params.grid.elevations(), beams, cw)

    @property
    def H(self) -> int:
        return self.elev.size

    def fft_plan(self, L: int, off: int, circular: bool) -> tuple[int, int]:
        """(Lf, q) of the at-rest paths for ``L`` padded chirps whose chirp 0 is at ``off``: the length of
        the FFT over the chirp axis (N for a circularly padded rotation: the correlation is circular;
        else the next fast length, no wrap-around) and the decimation fold (:func:`_fold`)."""
        import scipy.fft as sfft

        Lf = self.N if circular else sfft.next_fast_len(L)
        return Lf, _fold(self.beams, off, Lf)


def _fold(beams: np.ndarray, off: int, Lf: int) -> int:
    """Decimation factor q when the beams are exactly every q-th output of the chirp-axis IFFT
    (then the spectrum is folded q times and a length-Lf/q IFFT gives just those beams), else 1."""
    nb = beams.size
    if nb < 2 or off != 0:
        return 1
    q = int(beams[1] - beams[0])
    if q > 1 and Lf % q == 0 and nb == Lf // q and np.array_equal(beams, q * np.arange(nb)):
        return q
    return 1


def _blas_single():
    """BLAS limited to one thread while we thread over samples ourselves (OpenBLAS's own threads on
    the many small (Lf × V) @ (V × H) products cost more than they give)."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - threadpoolctl comes with scipy's usual installs
        import contextlib

        return contextlib.nullcontext()
    return threadpool_limits(1, user_api="blas")


def _vertical(xp: np.ndarray, vw: np.ndarray, threads: int) -> np.ndarray:
    """(H, L, S) complex64 vertical beamforming of chirps ``xp`` (L, V, S) with weights ``vw`` (S, V, H):
    one small matrix product per sample, spread over threads with single-threaded BLAS."""
    L, V, S = xp.shape
    H = vw.shape[2]
    xt = np.ascontiguousarray(xp.transpose(2, 0, 1))                                # (S, L, V)
    out = np.empty((H, L, S), np.complex64)
    parts = [p for p in np.array_split(np.arange(S), threads) if p.size]

    def part(ss):
        s0, s1 = int(ss[0]), int(ss[-1]) + 1
        out[:, :, s0:s1] = np.matmul(xt[s0:s1], vw[s0:s1]).transpose(2, 1, 0)

    with _blas_single(), ThreadPoolExecutor(max_workers=len(parts)) as pool:
        list(pool.map(part, parts))
    return out


def _elevation_groups(elev: np.ndarray) -> list[list[int]]:
    """Rows with the same cos θ (±θ of a symmetric grid) share every coefficient but the data."""
    groups: dict = {}
    for r, e in enumerate(elev):
        groups.setdefault(round(float(np.cos(e)), 12), []).append(r)
    return list(groups.values())


def _row_pairs(groups: list[list[int]]) -> np.ndarray:
    """(G, 2) int64 rows formed together by the moving-platform sums: the first two rows of each
    group of :func:`_elevation_groups` (-1 when a row is alone); a third or later row of a group is
    formed on its own, after all groups."""
    rows = [g[:2] + [-1] * (2 - len(g[:2])) for g in groups]
    rows += [[r, -1] for g in groups for r in g[2:]]
    return np.array(rows, np.int64)


def _to_rotation_start(y: np.ndarray, rows: np.ndarray, gam: np.ndarray, beams: np.ndarray) -> None:
    """In place: the beams ``y`` (H, nb, ...) of each row pair referred to the rotation's start
    instead of their own chirp (``motion_reference="rotation_start"``), with the motion phase rate
    ``gam`` (G, nb, ...) of the pair."""
    for g, (r0, r1) in enumerate(rows):
        post = np.exp(1j * gam[g] * beams[:, None]).astype(np.complex64)
        y[r0] *= post
        if r1 >= 0:
            y[r1] *= post
