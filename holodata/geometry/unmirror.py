"""Stage two without learning: multi-return range images → real 3-D points (paper §4.4).

Range image ``R_b`` (accumulated travel distance) along beam direction ``d_1`` gives the mirrored
point ``p'_b = R_b d_1``. Un-mirroring walks the bounce chain (paper eq. 2–3):
``d_b = d_{b−1} − 2(d_{b−1}·n_{b−1}) n_{b−1}``, ``p_b = p_{b−1} + (R_b − R_{b−1}) d_b``.
Unknown normals come from the range image itself (eq. 4: the closed-form normal of a spherical
range image) and are un-mirrored through the previous bounces' normals (eq. 5, applied for every
earlier mirror: ``n_b = L_{b−1}···L_1 n'_b`` with ``L_k = I − 2 n_k n_kᵀ``; the paper writes the
single-mirror case). Everything is in the radar frame of the frame's pose; each beam starts at its
own origin ``o`` (H,W,3) and looks along its own direction (the beam-origin model of
:mod:`holodata.beams`, :func:`holodata.scene_beams.frame_geometry`): ``p'_b = o + R_b d_1``.
Without origins every beam starts at 0 and looks along the grid's directions.
"""
from __future__ import annotations

import numpy as np

from holodata.conventions import Grid
from holodata.geometry.planes import agreeing_planes, window_plane_normals


def _reflect(v: np.ndarray, n: np.ndarray) -> np.ndarray:
    return v - 2.0 * np.sum(v * n, axis=-1, keepdims=True) * n


def _tangent(R: np.ndarray, P: np.ndarray, axis: int, periodic: bool) -> np.ndarray:
    """Tangent (…,H,W,3) of the point image P along grid ``axis`` (-2 rows, -1 columns): of the
    forward and backward neighbour differences, the one with the smaller range jump (so a depth
    edge does not bend the normals on either side of it)."""
    pax = axis - 1  # P has the trailing xyz axis
    if periodic:
        fwd_r, bwd_r = np.roll(R, -1, axis=axis) - R, R - np.roll(R, 1, axis=axis)
        fwd_p, bwd_p = np.roll(P, -1, axis=pax) - P, P - np.roll(P, 1, axis=pax)
    else:
        fwd_r, bwd_r = np.full_like(R, np.nan), np.full_like(R, np.nan)
        fwd_p, bwd_p = np.full_like(P, np.nan), np.full_like(P, np.nan)
        a, b = [slice(None)] * R.ndim, [slice(None)] * R.ndim
        a[axis], b[axis] = slice(0, -1), slice(1, None)
        dr, dp = np.diff(R, axis=axis), np.diff(P, axis=pax)
        fwd_r[tuple(a)], bwd_r[tuple(b)] = dr, dr
        fwd_p[tuple(a) + (slice(None),)], bwd_p[tuple(b) + (slice(None),)] = dp, dp
    pick_f = np.isfinite(fwd_r) & (~np.isfinite(bwd_r) | (np.abs(fwd_r) <= np.abs(bwd_r)))
    return np.where(pick_f[..., None], fwd_p, bwd_p)


# how normals_from_range estimates a normal: "planes" (the finite-difference normal refined by a
# robust window fit, then by the planes of the image, see normals_from_range) or "difference" (eq. 4's
# finite differences alone)
NORMAL_METHODS = ("planes", "difference")


@np.errstate(invalid="ignore", divide="ignore")
def normals_from_range(R, grid: Grid, origins=None, directions=None, method: str = "planes") -> np.ndarray:
    """Surface normals (…,H,W,3), radar frame, unit, facing the beam, of range image(s) R (…,H,W) m
    whose beams start at ``origins`` (H,W,3; None = 0) along ``directions`` (H,W,3; None = the grid's).

    Paper eq. 4 gives the normal of ``p = R(θ,φ) d(θ,φ)`` as ``R_{θ,φ} b`` with
    ``b ∝ [1, (∂R/∂φ)/(R cosθ), (∂R/∂θ)/R]`` in the local frame [d, e_φ, e_θ] — i.e. the cross
    product of the tangents ``∂p/∂φ × ∂p/∂θ``. We evaluate that cross product with finite
    differences of neighbouring points (exact on planes, unlike finite differences of R inserted
    into eq. 4, which carry an O(Δ) error). NaN where R or both neighbours along an axis are missing.

    ``method="planes"`` (default) refines that normal for a *predicted* image, whose range noise
    (a couple of cm between beams a few degrees apart) leaves finite-difference normals degrees off,
    which un-mirroring turns into decimetres on the hidden side: first the robust plane of each
    pixel's 3×9 window (:func:`holodata.geometry.planes.window_plane_normals`), then, per image, the
    normal of the plane the pixel belongs to among the image's largest planes (walls, floor,
    ceiling, box sides: :func:`holodata.geometry.planes.agreeing_planes`). Exact images keep their
    exact normals on planes. ``"difference"``: the finite-difference normal alone.
    """
    if method not in NORMAL_METHODS:
        raise ValueError(f"normal method must be one of {', '.join(NORMAL_METHODS)}, got {method!r}")
    R = np.asarray(R, dtype=np.float64)
    d = grid.directions() if directions is None else np.asarray(directions, np.float64)
    P = R[..., None] * d
    if origins is not None:
        P = P + np.asarray(origins, np.float64)
    t_th = _tangent(R, P, axis=-2, periodic=False)
    t_ph = _tangent(R, P, axis=-1, periodic=True)
    n = np.cross(t_ph, t_th)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    flip = np.sum(n * d, axis=-1, keepdims=True) > 0
    n = np.where(flip, -n, n)  # face the incoming ray
    if method == "difference":
        return n
    n = window_plane_normals(P, n)
    flat_p, flat_n = P.reshape((-1,) + P.shape[-3:]), n.reshape((-1,) + n.shape[-3:])
    for img_p, img_n in zip(flat_p, flat_n):   # views: planes are per image
        ok = np.isfinite(img_p).all(-1) & np.isfinite(img_n).all(-1)
        if ok.sum() >= 3:
            img_n[ok] = agreeing_planes(img_p[ok], img_n[ok])
    return np.where(np.sum(n * d, axis=-1, keepdims=True) > 0, -n, n)  # the fits keep n0's side; face the ray


@np.errstate(invalid="ignore", divide="ignore")
def unmirror(ranges, directions, normals=None, grid: Grid | None = None, origins=None) -> dict:
    """Un-mirror multi-return range images into real points.

    ranges: (B,H,W) metres, accumulated travel distance from the beam origin, NaN = none.
    directions: (H,W,3) unit beam directions d_1; origins: (H,W,3) beam origins (None = 0), both in
    the radar frame. normals: (B,H,W,3) true surface normals in that frame, or None to estimate
    them from ``ranges`` (then ``grid`` is required). Returns dict point (B,H,W,3)
    (NaN where R_b or any earlier bounce is missing), normal (B,H,W,3), direction (B,H,W,3) (the
    ray direction arriving at bounce b).
    """
    R = np.asarray(ranges, dtype=np.float64)
    d1 = np.asarray(directions, dtype=np.float64)
    B = R.shape[0]
    if normals is None:
        if grid is None:
            raise ValueError("unmirror needs grid to estimate normals")
        mirrored = normals_from_range(R, grid, origins, d1)
    else:
        normals = np.asarray(normals, dtype=np.float64)
        normals = normals / np.linalg.norm(normals, axis=-1, keepdims=True)
    pts = np.full(R.shape + (3,), np.nan)
    nrm = np.full(R.shape + (3,), np.nan)
    dirs = np.full(R.shape + (3,), np.nan)
    p_prev = np.zeros(d1.shape) if origins is None else np.broadcast_to(np.asarray(origins, np.float64), d1.shape)
    d = d1.copy()
    R_prev = np.zeros(R.shape[1:])
    for b in range(B):
        if b > 0:
            d = _reflect(d, nrm[b - 1])
        p = p_prev + (R[b] - R_prev)[..., None] * d
        if normals is None:
            n = mirrored[b]
            for k in range(b):  # eq. 5 through every earlier mirror, first mirror first
                n = _reflect(n, nrm[k])
        else:
            n = normals[b]
        pts[b], nrm[b], dirs[b] = p, n, d
        p_prev, R_prev = p, R[b]
    bad = np.isnan(pts).any(-1)
    pts[bad] = np.nan
    return {"point": pts, "normal": nrm, "direction": dirs}


def los_mask(points, first_range, grid: Grid, tolerance: float = 0.10, origins=None) -> np.ndarray:
    """(B,H,W) bool: True where point b of a beam is visible in the first-bounce range image
    ``first_range`` (H,W) m, i.e. the first bounce shows free space up to it.

    A point's direction, seen from the radar frame's origin, falls between four pixels of the
    grid; it is visible when any of them has R_1 missing or ≥ its distance (from that pixel's
    beam origin, ``origins`` (H,W,3), else 0) − ``tolerance`` m. All four, not the nearest one:
    a pixel's beam is the centre of a footprint ~(180°/H) wide, and a floor or wall point seen at
    grazing incidence lies well before or beyond where the nearest beam's centre meets that
    surface. Points outside the elevation field of view are visible (the first bounce says
    nothing there, as with a missing R_1); the ground truth's label is geometric visibility from
    the beam origin with no field of view (:mod:`holodata.raytrace.trace`). Bounce-1 points are
    LOS by definition; missing points are False."""
    P = np.asarray(points, dtype=np.float64)
    R1 = np.asarray(first_range, dtype=np.float64)
    r0 = np.linalg.norm(P, axis=-1)
    ok = np.isfinite(r0)
    th = np.arcsin(np.clip(P[..., 2] / np.where(r0 > 0, r0, 1), -1, 1))
    ph = np.arctan2(P[..., 1], P[..., 0])
    hi, lo = np.deg2rad(grid.elev_max_deg), np.deg2rad(grid.elev_min_deg)
    rowf = np.where(ok, (hi - th) / (hi - lo) * (grid.H - 1), 0.0)
    colf = np.where(ok, -ph / (2 * np.pi) * grid.W, 0.0)
    org = None if origins is None else np.asarray(origins, np.float64)
    vis = (rowf < -0.5) | (rowf > grid.H - 0.5)  # outside the field of view
    r0i, c0i = np.floor(rowf).astype(int), np.floor(colf).astype(int)
    for dr in (0, 1):
        row = np.clip(r0i + dr, 0, grid.H - 1)
        for dc in (0, 1):
            col = (c0i + dc) % grid.W
            r1 = R1[row, col]
            r = r0 if org is None else np.linalg.norm(P - org[row, col], axis=-1)
            vis |= ~np.isfinite(r1) | (r1 >= r - tolerance)
    vis &= ok
    vis[0] = ok[0]
    return vis
