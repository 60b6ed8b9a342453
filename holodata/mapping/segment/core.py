"""Segmentation of one organised scan, arrays in, arrays out (no I/O): foreground flood fill
from seeds (:func:`flood_fill`), erosion, destaggering, merging stacked pieces,
the person-sized checks (:func:`segment_scan`)."""
from __future__ import annotations

import numpy as np

from ...geometry.planes import fit_height_plane
from .config import NEIGHBOURS, SegmentConfig

# a beam's horizontal step shrinks with cos(elevation); floored here so that the steepest beams of a
# wide-FOV LiDAR do not get a near-zero link distance
MIN_COS_ELEVATION = 0.2
# a cluster nearer than a person's height spans only part of the vertical FOV: it needs this share
# of the height the FOV spans at its range
MIN_HEIGHT_FOV_SHARE = 0.8
# the floor: the densest FLOOR_BIN_M slice of heights, then planes through the returns within
# FLOOR_BAND_M of it, then within FLOOR_SIGMAS standard deviations but at least FLOOR_MIN_BAND_M
FLOOR_BIN_M = 0.02
FLOOR_BAND_M = 0.10
FLOOR_SIGMAS = 3.0
FLOOR_MIN_BAND_M = 0.03


# ------------------------------------------------------------------------------------------ core
def _shift(a: np.ndarray, dr: int, dc: int, fill=False) -> np.ndarray:
    """``out[i, j] = a[i + dr, (j + dc) mod W]`` (columns wrap around the scan), ``fill`` where
    ``i + dr`` is outside the rows (dr of either sign)."""
    out = np.roll(a, -dc, axis=1)
    if dr > 0:
        out = np.concatenate([out[dr:], np.full((dr,) + a.shape[1:], fill, dtype=a.dtype)], axis=0)
    elif dr < 0:
        out = np.concatenate([np.full((-dr,) + a.shape[1:], fill, dtype=a.dtype), out[:dr]], axis=0)
    return out


def erode(mask: np.ndarray, iterations: int = 1, structure: np.ndarray | None = None) -> np.ndarray:
    """Binary erosion with ``structure`` (default a 3×3 square; see :func:`shrink_structure`); columns
    wrap, rows outside the image count as background."""
    from scipy import ndimage

    m = np.asarray(mask, bool)
    if iterations <= 0:
        return m.copy()
    st = np.ones((3, 3), bool) if structure is None else np.asarray(structure, bool)
    W = m.shape[1]
    pad = iterations * (st.shape[1] // 2)
    wrapped = np.concatenate([m[:, W - pad:], m, m[:, :pad]], axis=1) if pad else m
    er = ndimage.binary_erosion(wrapped, structure=st, iterations=iterations, border_value=0)
    return er[:, pad:pad + W]


def shrink_structure(elev: np.ndarray | None, W: int, max_aspect: float = 2.0) -> np.ndarray:
    """Structuring element of the seed shrink for a grid with row elevations ``elev`` (H,) rad and
    ``W`` columns: a 3×3 square when rows and columns sample angles alike, a 1×3 row (erode along
    the columns only) when the median row spacing is more than ``max_aspect`` times the column
    spacing 2π/W (3×1 in the converse case). An OS1-like 33° 64×1024 grid (0.53° × 0.35°) keeps the
    square; an OS0-like 90° 32×512 grid (2.9° × 0.70°) would lose a whole 15–30 cm row off the top
    and bottom of a person at 5 m, who is then only ~6 rows tall and often has no seed left."""
    sq = np.ones((3, 3), bool)
    if elev is None or len(elev) < 2:
        return sq
    dv = float(np.median(np.abs(np.diff(np.asarray(elev, np.float64)))))
    dh = 2 * np.pi / W
    if dv > max_aspect * dh:
        return np.ones((1, 3), bool)
    if dh > max_aspect * dv:
        return np.ones((3, 1), bool)
    return sq


def beam_elevations(points: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(H,) float64 elevation (rad) of each beam (row) of an organised scan, measured from the data:
    the median of ``atan2(z, hypot(x, y))`` over the row's returns; rows without returns are
    interpolated from the others, linearly extrapolated past the first/last row with returns (a
    scan without returns gives zeros)."""
    p = np.asarray(points, np.float64)
    v = np.asarray(valid, bool)
    H = v.shape[0]
    el = np.arctan2(p[..., 2], np.hypot(p[..., 0], p[..., 1]))
    out = np.full(H, np.nan)
    for i in range(H):
        if v[i].any():
            out[i] = np.median(el[i, v[i]])
    ok = np.isfinite(out)
    if not ok.any():
        return np.zeros(H)
    rows = np.flatnonzero(ok)
    el = np.interp(np.arange(H), rows, out[ok])
    if len(rows) >= 2:  # rows above the first / below the last row with returns: linear extrapolation
        slope = np.polyfit(rows, out[ok], 1)[0]
        lo, hi = np.arange(rows[0]), np.arange(rows[-1] + 1, H)
        el[lo] = out[rows[0]] + slope * (lo - rows[0])
        el[hi] = out[rows[-1]] + slope * (hi - rows[-1])
    return el


def neighbour_spacing(elev: np.ndarray, W: int, dr: int, dc: int) -> np.ndarray:
    """(H,1) expected distance (m per metre of range) between a pixel and its grid neighbour
    (``dr`` rows, ``dc`` columns away) on a vertical surface facing the sensor: vertical step
    ``|Δel| / cos(el)`` and horizontal step ``|dc| · 2π/W · cos(el)`` (rows past the edge: 0).
    Multiplied by the range this is the beam pattern's sampling distance there, so the flood-fill
    threshold follows the LiDAR's beam geometry (a 90° 32-beam scan samples a person every ~5 cm of
    height per metre of range, a 33° 64-beam one every ~0.9 cm)."""
    el = np.asarray(elev, np.float64)
    H = len(el)
    e2 = _shift(el[:, None], dr, 0, fill=np.nan)[:, 0]
    d_el = np.where(np.isfinite(e2), np.abs(e2 - el), 0.0)
    c = np.maximum(np.cos(el), MIN_COS_ELEVATION)
    return np.hypot(d_el / c, abs(dc) * 2 * np.pi / W * c).reshape(H, 1)


def link_threshold(rng: np.ndarray, r2: np.ndarray, spacing: np.ndarray | None, dist_m: float, dist_per_m: float,
                   spacing_factor: float) -> np.ndarray:
    """Flood-fill distance threshold (m) between two grid neighbours at ranges ``rng``/``r2`` (m):
    ``dist_m + dist_per_m · r + spacing_factor · spacing · r`` with r the nearer range and ``spacing``
    (:func:`neighbour_spacing`, or None: no geometric term)."""
    r = np.minimum(rng, r2)
    thr = dist_m + dist_per_m * r
    if spacing is not None and spacing_factor > 0:
        thr = thr + spacing_factor * spacing * r
    return thr


def flood_fill(points: np.ndarray, fg: np.ndarray, seeds: np.ndarray, dist_m: float, dist_per_m: float,
               elev: np.ndarray | None = None, spacing_factor: float = 0.0) -> tuple[np.ndarray, int]:
    """Connected components of the foreground pixels ``fg`` (H,W) bool linked to grid neighbours
    (``NEIGHBOURS``, columns wrap) whose points ``points`` (H,W,3) m are closer than
    :func:`link_threshold` (``dist_m + dist_per_m * range``, plus ``spacing_factor`` times the beam
    pattern's sampling distance at that range when the row elevations ``elev`` (H,) rad are given;
    range of the nearer point, from the sensor origin). Returns (labels (H,W) int64, -1 outside the
    kept components, n): only components holding a seed pixel are kept, numbered 0..n-1."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    H, W = fg.shape
    lab = np.full((H, W), -1, np.int64)
    n_fg = int(fg.sum())
    if n_fg == 0:
        return lab, 0
    idx = np.full((H, W), -1, np.int64)
    idx[fg] = np.arange(n_fg)
    fi, fj = np.nonzero(fg)                      # foreground pixels only (a few % of the grid)
    pf = np.asarray(points, np.float64)[fi, fj]
    rf = np.linalg.norm(pf, axis=-1)
    rows, cols = [], []
    for dr, dc in NEIGHBOURS:
        i2, j2 = fi + dr, (fj + dc) % W
        inside = (i2 >= 0) & (i2 < H)
        k2 = np.full(n_fg, -1, np.int64)
        k2[inside] = idx[i2[inside], j2[inside]]
        a = np.flatnonzero(k2 >= 0)
        if not len(a):
            continue
        b = k2[a]
        d = np.linalg.norm(pf[a] - pf[b], axis=-1)
        sp = neighbour_spacing(elev, W, dr, dc)[fi[a], 0] if elev is not None else None
        thr = link_threshold(rf[a], rf[b], sp, dist_m, dist_per_m, spacing_factor)
        e = d < thr
        rows.append(a[e])
        cols.append(b[e])
    r = np.concatenate(rows) if rows else np.zeros(0, np.int64)
    c = np.concatenate(cols) if cols else np.zeros(0, np.int64)
    g = coo_matrix((np.ones(len(r), np.int8), (r, c)), shape=(n_fg, n_fg))
    _, comp = connected_components(g, directed=False)
    seeded = np.unique(comp[seeds[fg]])
    keep = np.full(comp.max() + 1, -1, np.int64)
    keep[seeded] = np.arange(len(seeded))
    lab[fg] = keep[comp]
    return lab, len(seeded)


def row_shifts(points: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(H,) int column shifts that destagger an organised scan, measured from the data: for row i,
    the median over its returns of (point azimuth − column azimuth ``−2πj/W``) in columns. Rows are
    destaggered by ``np.roll(row, shift)``; an already destaggered grid gives zeros. Rows without
    returns get 0."""
    H, W = valid.shape
    step = 2 * np.pi / W
    enc = -step * np.arange(W)
    az = np.arctan2(points[..., 1], points[..., 0])
    d = np.angle(np.exp(1j * (az - enc[None, :])))
    out = np.zeros(H, np.int64)
    for i in range(H):
        v = valid[i]
        if v.sum() >= 8:
            out[i] = int(np.rint(np.median(d[i, v]) / step))
    return out


def destagger(a: np.ndarray, shifts: np.ndarray, inverse: bool = False) -> np.ndarray:
    """Roll row i of ``a`` (H,W,...) by ``-shifts[i]`` (``inverse``: by ``+shifts[i]``): a pixel whose
    azimuth is ``−2πj/W + shifts[i]·2π/W`` lands in column j, so columns line up across rows."""
    a = np.asarray(a)
    H, W = a.shape[:2]
    sh = np.asarray(shifts, np.int64)[:, None]
    cols = (np.arange(W)[None, :] + (-sh if inverse else sh)) % W
    return a[np.arange(H)[:, None], cols]


def segment_scan(points: np.ndarray, valid: np.ndarray, background: np.ndarray | None,
                 cfg: SegmentConfig | None = None, points_world: np.ndarray | None = None,
                 shifts: np.ndarray | None = None, floor: np.ndarray | None = None,
                 elev: np.ndarray | None = None) -> np.ndarray:
    """Instance image of one organised scan.

    ``points`` (H,W,3) sensor-frame points m (flood-fill distances); ``valid`` (H,W) bool returns;
    ``background`` (H,W) bool, True = return explained by the static background (None: none is);
    ``points_world`` (H,W,3) world points for the extent checks (default ``points``; the z axis must be
    up); ``shifts`` (H,)
    destaggering column shifts (:func:`row_shifts`; None: measured here); ``floor`` the floor plane
    (:func:`floor_plane`; clusters topping out more than ``cfg.max_height_m`` above it are dropped);
    ``elev`` (H,) beam elevations (rad; :func:`beam_elevations`, None: measured here) for the
    flood-fill threshold and the shrink structure. The grid
    is destaggered for the neighbourhood operations and the result returned in the input layout.
    Returns (H,W) uint16: 0 = background / no return, 1..n instances by decreasing size.
    """
    cfg = cfg or SegmentConfig()
    if background is not None and int((np.asarray(valid, bool) & ~np.asarray(background, bool)).sum()) < max(
            cfg.min_points, 1):   # fewer foreground returns than the smallest cluster: nothing to find
        return np.zeros(np.shape(valid), np.uint16)
    if shifts is None:
        shifts = row_shifts(np.asarray(points, np.float64), np.asarray(valid, bool))
    if np.any(shifts):
        pw = points_world if points_world is not None else points
        lab = segment_scan(destagger(np.asarray(points), shifts), destagger(np.asarray(valid, bool), shifts),
                           None if background is None else destagger(np.asarray(background, bool), shifts), cfg,
                           destagger(np.asarray(pw), shifts), np.zeros(len(shifts), np.int64), floor, elev)
        return destagger(lab, shifts, inverse=True)
    valid = np.asarray(valid, bool)
    fg = valid & (~np.asarray(background, bool) if background is not None else True)
    P = np.asarray(points, np.float64)
    lab, n, elev = _clusters(P, valid, fg, cfg, elev)
    out = np.zeros(fg.shape, np.uint16)
    if n == 0:
        return out
    pw = np.asarray(points_world if points_world is not None else points, np.float64)
    if cfg.merge_xy_m > 0 and n > 1:
        lab, n = merge_stacked(lab, n, pw, cfg.merge_xy_m, cfg.max_width_m, max_height_m=cfg.max_height_m)
    sel = lab >= 0
    ls, ps = lab[sel], pw[sel]
    ok, sizes = _extent_ok(ls, ps, P[sel], n, elev, floor, cfg)
    cand = _not_flat(np.flatnonzero(ok), lab, ls, ps, P, valid, fg, cfg)
    cand = cand[np.argsort(-sizes[cand], kind="stable")]
    if cfg.max_instances > 0:
        cand = cand[:cfg.max_instances]
    remap = np.zeros(n, np.uint16)
    remap[cand] = np.arange(1, len(cand) + 1, dtype=np.uint16)
    out[sel] = remap[ls]
    return out


def _clusters(P: np.ndarray, valid: np.ndarray, fg: np.ndarray, cfg: SegmentConfig, elev: np.ndarray | None):
    """Steps 3-4 of :func:`segment_scan` on the destaggered grid: seeds by shrinking the foreground
    ``fg`` (H,W) and the flood fill from them over ``P`` (H,W,3) sensor-frame points. Returns (labels
    (H,W) int, -1 = none; the number of clusters; the beam elevations (H,) rad the fill's threshold
    used, None when ``spacing_factor`` is 0)."""
    if elev is None:
        elev = beam_elevations(P, valid)
    seeds = erode(fg, cfg.erosion, shrink_structure(elev, fg.shape[1]))
    if cfg.spacing_factor <= 0:
        elev = None
    lab, n = flood_fill(P, fg, seeds, cfg.dist_m, cfg.dist_per_m, elev, cfg.spacing_factor)
    return lab, n, elev


def _extent_ok(ls: np.ndarray, ps: np.ndarray, p_sensor: np.ndarray, n: int, elev: np.ndarray | None, floor,
               cfg: SegmentConfig) -> tuple[np.ndarray, np.ndarray]:
    """Step 5's size and height checks of the ``n`` clusters: labels ``ls`` (N,) of the labelled
    pixels, their world points ``ps`` (N,3) and sensor-frame points ``p_sensor`` (N,3). Returns ((n,)
    bool: at least ``min_points`` returns, tall enough (:func:`min_height`) and topping out at most
    ``max_height_m`` above the ``floor`` plane when given; (n,) sizes)."""
    sizes = np.bincount(ls, minlength=n)
    zmin = np.full(n, np.inf)
    zmax = np.full(n, -np.inf)
    np.minimum.at(zmin, ls, ps[:, 2])
    np.maximum.at(zmax, ls, ps[:, 2])
    ok = sizes >= cfg.min_points
    ok &= (zmax - zmin) >= min_height(cfg.min_height_m, elev, p_sensor, ls, n)
    if floor is not None and np.isfinite(cfg.max_height_m):
        top = np.full(n, -np.inf)
        hfl = above_floor(floor, ps)
        np.maximum.at(top, ls, hfl)
        ok &= top <= cfg.max_height_m
    return ok, sizes


def _not_flat(cand: np.ndarray, lab: np.ndarray, ls: np.ndarray, ps: np.ndarray, P: np.ndarray, valid: np.ndarray,
              fg: np.ndarray, cfg: SegmentConfig) -> np.ndarray:
    """The candidate clusters ``cand`` that are person-like in plan: no wider than ``max_width_m`` and
    not a thin surface (thinner than ``min_depth_m``, or ``min_depth_sigmas`` of the scan's range noise,
    with most of it on one surface: :func:`surface_share`). ``lab`` (H,W) labels, ``ls``/``ps`` the
    labelled pixels' labels and world points, ``P`` (H,W,3) sensor-frame points, ``valid``/``fg`` the
    returns and the foreground."""
    depth_check = cfg.min_depth_m is None or cfg.min_depth_m > 0
    if not (np.isfinite(cfg.max_width_m) or depth_check):
        return cand
    good = []
    rng = sigma = None
    for c in cand:
        q = ps[ls == c]
        if _plan_extent(q[:, :2]) > cfg.max_width_m:
            continue
        if depth_check:
            if sigma is None:   # measured once per scan, only when a cluster gets this far
                rng = np.sqrt((P * P).sum(-1))
                sigma = range_noise(rng, valid & ~fg)
            thin_below = cfg.min_depth_m if cfg.min_depth_m is not None else cfg.min_depth_sigmas * sigma
            if _thickness(q) < thin_below and surface_share(
                    rng, valid, lab == c, cfg.surface_sigmas * np.sqrt(6.0) * sigma) > cfg.max_surface_share:
                continue
        good.append(c)
    return np.array(good, np.int64)


def min_height(min_height_m: float, elev: np.ndarray | None, points: np.ndarray, labels: np.ndarray, n: int
               ) -> np.ndarray:
    """(n,) smallest vertical extent (m) a cluster must have: ``min_height_m``, or 80 % of the height
    the LiDAR's vertical field of view spans at the cluster's median horizontal range when that is
    less (``elev`` (H,) beam elevations, rad; ``points`` sensor-frame points of the labelled pixels,
    ``labels`` their cluster ids 0..n-1). A person 0.4 m from a 33° LiDAR shows only a 24 cm slice."""
    need = np.full(n, float(min_height_m))
    if elev is None or not len(labels) or min_height_m <= 0:
        return need
    span = float(np.tan(np.max(elev)) - np.tan(np.min(elev)))
    rh = np.hypot(points[:, 0], points[:, 1])
    order = np.argsort(labels, kind="stable")
    bounds = np.searchsorted(labels[order], np.arange(n + 1))
    for c in range(n):
        a, b = bounds[c], bounds[c + 1]
        if b > a:
            need[c] = min(need[c], MIN_HEIGHT_FOV_SHARE * span * float(np.median(rh[order[a:b]])))
    return need


def merge_stacked(lab: np.ndarray, n: int, points_world: np.ndarray, xy_m: float, max_width_m: float,
                  min_points: int = 3, max_height_m: float = np.inf) -> tuple[np.ndarray, int]:
    """Join clusters that stand on the same plan-view spot: two clusters (each >= ``min_points``
    returns) are one when some of their points come within ``xy_m`` (m) of each other in plan view
    (x, y of ``points_world`` (H,W,3), z up), their height ranges overlap or leave a gap of at most
    2·``xy_m``, and together they stay within ``max_width_m`` across and ``max_height_m`` tall.
    A leg or arm whose link to the torso is hidden by a limb in front (a depth jump larger than the
    flood-fill threshold; common within ~1 m of a wide-FOV LiDAR that sees the whole body) is split
    off by the flood fill; this puts it back. Returns (labels renumbered 0..m-1, m)."""
    from scipy.spatial import cKDTree

    sel = lab >= 0
    ls = lab[sel]
    xy = points_world[sel][:, :2]
    z = points_world[sel][:, 2]
    sizes = np.bincount(ls, minlength=n)
    zlo = np.full(n, np.inf)
    zhi = np.full(n, -np.inf)
    np.minimum.at(zlo, ls, z)
    np.maximum.at(zhi, ls, z)
    big = np.flatnonzero(sizes >= min_points)
    if len(big) < 2:
        return lab, n
    pts = {int(c): xy[ls == c] for c in big}
    cen = {c: p.mean(0) for c, p in pts.items()}
    rad = {c: float(np.sqrt(((p - cen[c]) ** 2).sum(1).max())) for c, p in pts.items()}
    parent = np.arange(n)

    def root(c):
        while parent[c] != c:
            c = parent[c]
        return c

    trees = {}
    order = [int(c) for c in big[np.argsort(-sizes[big], kind="stable")]]
    for i, a in enumerate(order):
        for b in order[i + 1:]:
            ra, rb = root(a), root(b)
            if ra == rb or np.linalg.norm(cen[a] - cen[b]) > rad[a] + rad[b] + xy_m:
                continue
            if max(zlo[ra], zlo[rb]) - min(zhi[ra], zhi[rb]) > 2 * xy_m:
                continue
            if max(zhi[ra], zhi[rb]) - min(zlo[ra], zlo[rb]) > max_height_m:
                continue
            if a not in trees:
                trees[a] = cKDTree(pts[a])
            d, _ = trees[a].query(pts[b], k=1, distance_upper_bound=xy_m)
            if not np.isfinite(d).any():
                continue
            members = [c for c in range(n) if root(c) in (ra, rb)]
            if _plan_extent(xy[np.isin(ls, members)]) <= max_width_m:
                parent[rb] = ra
                zlo[ra], zhi[ra] = min(zlo[ra], zlo[rb]), max(zhi[ra], zhi[rb])
    roots = np.array([root(c) for c in range(n)])
    uniq, new = np.unique(roots, return_inverse=True)
    out = lab.copy()
    out[sel] = new[ls]
    return out, len(uniq)


def range_noise(rng: np.ndarray, mask: np.ndarray, min_triples: int = 100) -> float:
    """1-sigma range noise (m) of an organised scan, measured from its own returns: the robust spread
    (1.4826 × the median absolute deviation) of the second differences ``r[i, j-1] - 2 r[i, j] +
    r[i, j+1]`` along the rows (columns wrap) over triples of returns all in ``mask`` (H,W) bool (the
    background returns: static surfaces), divided by √6 (the second difference of independent
    noise has variance 6σ²: the pseudo-residuals of Gasser, Sroka & Jennen-Steinmetz 1986). A smooth
    surface's own change of slope between neighbouring columns is small next to the noise; edges
    and corners are the outliers the median ignores. ``rng`` (H,W) ranges (m). NaN with fewer
    than ``min_triples`` triples (then the flat surface check of :func:`segment_scan` keeps all)."""
    r = np.asarray(rng, np.float64)
    m = np.asarray(mask, bool)
    both = m & np.roll(m, 1, axis=1) & np.roll(m, -1, axis=1)
    if int(both.sum()) < min_triples:
        return float("nan")
    d = (np.roll(r, 1, axis=1) - 2.0 * r + np.roll(r, -1, axis=1))[both]
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(6.0))


def surface_share(rng: np.ndarray, valid: np.ndarray, mask: np.ndarray, tol_m: float) -> float:
    """Share (0..1) of a cluster's border that continues the surface around it. Over every edge
    pixel ``e`` of ``mask`` (H,W) and grid direction d (4-neighbourhood; columns wrap) with ``e + d``
    outside the cluster and ``e - d`` inside it, the border continues when the neighbour is a return
    whose range lies within ``tol_m`` of the straight-line extrapolation ``2 r[e] - r[e - d]`` (a
    second difference again: with range noise σ its spread is √6·σ). A piece of wall the
    background missed continues the wall on most of its border; something standing in front of
    the wall (a person, however flat) has a depth jump on most of it (its feet continue the floor
    only). ``rng`` (H,W) ranges (m), ``valid`` (H,W) returns; a neighbour without a return is a
    jump. 0 with no such edge."""
    r = np.asarray(rng, np.float64)
    m = np.asarray(mask, bool)
    v = np.asarray(valid, bool)
    ones = np.ones_like(m)
    cont = total = 0
    for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        edge = m & ~_shift(m, dr, dc, True) & _shift(m, -dr, -dc, False) & _shift(ones, dr, dc, False)
        if not edge.any():
            continue
        rn = _shift(r, dr, dc, np.nan)[edge]
        jump = np.where(_shift(v, dr, dc, False)[edge], rn - (2.0 * r[edge] - _shift(r, -dr, -dc, np.nan)[edge]), np.inf)
        cont += int((np.abs(jump) < tol_m).sum())
        total += int(edge.sum())
    return cont / total if total else 0.0


def _thickness(p: np.ndarray) -> float:
    """Robust smallest extent (m) of a 3-D cluster: 5-95 % spread along its least principal axis.
    A patch of wall is ~noise thin; a person's visible surface is curved and has limbs at other depths."""
    if len(p) < 4:
        return 0.0
    c = p - p.mean(0)
    _, vec = np.linalg.eigh(c.T @ c)
    q = c @ vec[:, 0]
    lo, hi = np.percentile(q, [5, 95])
    return float(hi - lo)


def _plan_extent(xy: np.ndarray) -> float:
    """Largest plan-view extent (m) of a cluster: the longer side of its principal-axes box."""
    if len(xy) < 2:
        return 0.0
    c = xy - xy.mean(0)
    _, vec = np.linalg.eigh(c.T @ c)
    proj = c @ vec
    return float((proj.max(0) - proj.min(0)).max())


def floor_plane(points_world: list, origins, below_m: float = 0.3, min_points: int = 200) -> np.ndarray | None:
    """Floor of a scene as a plane ``z = a·x + b·y + c`` (returns (3,) [a, b, c], or None when there
    is no clear floor): the densest 2 cm slice of heights among the returns more than ``below_m``
    under the lowest sensor origin, refined by least-squares planes through the returns near the
    current plane (10 cm, then 3 sigma but >= 3 cm; four rounds, so a world frame tilted by a few
    degrees is followed). World z must be (roughly) up."""
    z_max = float(np.min(np.asarray(origins)[:, 2])) - below_m if origins is not None and len(origins) else np.inf
    rng = np.random.default_rng(0)
    cap = max(2000, 800_000 // max(1, len(points_world)))   # per scan: no copy of every scan's points
    low = []
    for q in points_world:
        q = np.asarray(q).reshape(-1, 3)
        f = np.isfinite(q)
        q = q[f[:, 0] & f[:, 1] & f[:, 2] & (q[:, 2] < z_max)]   # (N,3).all(1) is slower (docs/design/performance.md)
        low.append(q[rng.choice(len(q), cap, replace=False)] if len(q) > cap else q)
    p = np.concatenate(low).astype(np.float64) if low else np.zeros((0, 3))
    if len(p) < min_points:
        return None
    if len(p) > 400_000:
        p = p[rng.choice(len(p), 400_000, replace=False)]
    lo, hi = p[:, 2].min(), p[:, 2].max()
    hist, edges = np.histogram(p[:, 2], bins=max(1, int(np.ceil((hi - lo) / FLOOR_BIN_M))),
                               range=(lo, max(hi, lo + FLOOR_BIN_M)))
    z0 = edges[int(np.argmax(hist))] + FLOOR_BIN_M / 2
    coef = np.array([0.0, 0.0, z0])
    band = FLOOR_BAND_M
    for _ in range(4):  # re-select the returns near the current plane (follows a tilted world frame), refit
        res = p[:, 2] - (p[:, :2] @ coef[:2] + coef[2])
        q = p[np.abs(res) < band]
        if len(q) < min_points:
            return None
        coef = fit_height_plane(q)
        band = max(FLOOR_SIGMAS * float((q[:, 2] - np.c_[q[:, :2], np.ones(len(q))] @ coef).std()), FLOOR_MIN_BAND_M)
    return coef


def above_floor(plane: np.ndarray | None, points_world: np.ndarray) -> np.ndarray:
    """(N,) height (m) of world points above :func:`floor_plane` ``plane`` (inf without a plane)."""
    p = np.asarray(points_world, np.float64).reshape(-1, 3)
    if plane is None:
        return np.full(len(p), np.inf)
    return p[:, 2] - (p[:, :2] @ plane[:2] + plane[2])
