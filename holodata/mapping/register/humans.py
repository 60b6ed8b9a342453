"""Human points and closed surfaces: clustering, RANSAC planes, picking the person
(:func:`pick_human`), body columns and closed surfaces (:func:`closed_surface`); the checks and
motion of the person's track over frames are in :mod:`.tracks`."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...geometry.planes import ransac_plane
from ...geometry.voxels import voxel_index, voxel_keys
from .config import RegisterConfig
from .extrinsic import _pcd


# ------------------------------------------------------------------------------------ humans
def cluster_points(points: np.ndarray, dist: float) -> np.ndarray:
    """Connected components of points (N,3) whose voxels (edge ``dist``) touch (26-neighbourhood):
    labels (N,) int64 0..n-1 (vectorised: packed voxel keys, sorted, neighbour lookup by searchsorted)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if len(points) == 0:
        return np.zeros(0, np.int64)
    ijk = np.floor(np.asarray(points) / dist).astype(np.int64)
    keys = voxel_keys(ijk)
    uniq, inv = np.unique(keys, return_inverse=True)
    inv = inv.reshape(-1)
    cells = ijk[np.unique(inv, return_index=True)[1]]
    rows, cols = [], []
    for o in [(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1) if (a, b, c) > (0, 0, 0)]:
        nk = voxel_keys(cells + np.array(o))
        pos = np.minimum(np.searchsorted(uniq, nk), len(uniq) - 1)
        hit = uniq[pos] == nk
        rows.append(np.flatnonzero(hit))
        cols.append(pos[hit])
    r, c = np.concatenate(rows), np.concatenate(cols)
    g = coo_matrix((np.ones(len(r), np.int8), (r, c)), shape=(len(uniq), len(uniq)))
    _, comp = connected_components(g, directed=False)
    return comp[inv]


def pixel_links(rows: np.ndarray, cols: np.ndarray, depth: np.ndarray, sigma: np.ndarray, gap: int,
                n_sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (i (L,), j (L,)) of returns on nearby pixels whose depths agree within the depth noise:
    ``rows``, ``cols`` (N,) int pixels at most ``gap`` pixels apart in row and column (a single stereo
    hole bridged with 2), ``depth`` (N,) optical depths (m), ``sigma`` (N,) their noise σ (m), linked
    when |Δdepth| <= ``n_sigma`` · sqrt(σi² + σj²). A camera's returns are sharp across the view (a
    pixel's footprint) but noisy along it (stereo σ grows as depth²): at 9 m a 160-column cloud's σ
    is 0.3 m, three pixel footprints, so neighbours on one body lie farther apart in space than any
    isotropic linking distance that keeps people apart from each other."""
    r = np.asarray(rows, np.int64)
    c = np.asarray(cols, np.int64)
    z = np.asarray(depth, np.float64)
    s2 = np.asarray(sigma, np.float64) ** 2
    if len(r) < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    r0, c0 = r.min(), c.min()
    idx = np.full((int(r.max() - r0) + 1 + gap, int(c.max() - c0) + 1 + 2 * gap), -1, np.int64)
    idx[r - r0, c - c0 + gap] = np.arange(len(r))    # (a later return on the same pixel wins; none in a frame)
    ii, jj = [], []
    for dr in range(gap + 1):
        for dc in range(-gap, gap + 1):
            if dr == 0 and dc <= 0:
                continue                              # each unordered pair once
            j = idx[r - r0 + dr, c - c0 + gap + dc]
            ok = j >= 0
            i = np.flatnonzero(ok)
            j = j[ok]
            near = np.abs(z[i] - z[j]) <= n_sigma * np.sqrt(s2[i] + s2[j])
            ii.append(i[near])
            jj.append(j[near])
    return np.concatenate(ii), np.concatenate(jj)


def cluster_returns(points: np.ndarray, dist: float, pixels: tuple | None = None, gap: int = 2,
                    n_sigma: float = RegisterConfig.link_sigma) -> np.ndarray:
    """Labels (N,) int64 of the connected components of ``points`` (N,3) linked by :func:`cluster_points`
    (voxels of edge ``dist`` touching) or, with ``pixels`` = (rows, cols, depth, sigma) (N,) each, by
    :func:`pixel_links` (``gap``, ``n_sigma``) as well."""
    lab = cluster_points(points, dist)
    if pixels is None or len(lab) < 2:
        return lab
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    i, j = pixel_links(*pixels, gap=gap, n_sigma=n_sigma)
    first = np.unique(lab, return_index=True)[1]          # each voxel component: its first return
    n = len(lab)
    a = np.concatenate([i, np.arange(n)])
    b = np.concatenate([j, first[lab]])
    g = coo_matrix((np.ones(len(a), np.int8), (a, b)), shape=(n, n))
    return connected_components(g, directed=False)[1].astype(np.int64)


# a connected part of a RANSAC plane of the static camera cloud is structure (floor, wall, ceiling)
# only when a standing person could not be it: longer than this in the plane, or wider than
# max_width_m across its longer side (static_residual)
PERSON_MAX_HEIGHT_M = 2.2


def _plane_extents(points: np.ndarray, normal: np.ndarray) -> tuple[float, float]:
    """(longer, shorter) extent (m) of ``points`` (N,3) in the plane with unit ``normal`` (3,), along
    their principal axes in it."""
    a = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    uv = points @ np.c_[a, np.cross(normal, a)]
    if len(uv) < 3:
        return 0.0, 0.0
    uv = uv - uv.mean(0)
    ext = np.ptp(uv @ np.linalg.eigh(uv.T @ uv)[1], axis=0)
    return float(ext.max()), float(ext.min())


def static_residual(points: np.ndarray, cfg: RegisterConfig, seed: int = 0) -> np.ndarray:
    """(N,) bool: points of the static camera cloud (N,3, any frame) that are on none of the large
    planes (floor, ceiling, walls: RANSAC planes, :func:`ransac_plane`, each holding at least
    ``plane_min_fraction`` of the points, up to ``max_planes``). Catches a person who stands still
    (and is therefore part of the temporal background).

    A plane's inliers count as structure only in its connected parts (voxels within 2 ``cam_voxel``)
    that no standing person could be: longer than :data:`PERSON_MAX_HEIGHT_M` or wider than
    ``max_width_m`` (:func:`_plane_extents`). A person facing the camera is nearly flat (torso,
    arms and legs' fronts within ``plane_dist_m`` of one plane), and near the camera holds the
    share of a plane: on the synthetic L / T corners of seed 0 (6 frames, a person standing 3.1 m
    away) their front made the fifth plane, the torso was taken for a wall and the centroid sat on
    the arms and legs (benchmarks/results/register_defaults.md, "A person standing still")."""
    pts = np.asarray(points, np.float64)
    keep = np.ones(len(pts), bool)
    if len(pts) < 100:
        return keep
    rng = np.random.default_rng(seed)
    _, first, inv = np.unique(voxel_keys(voxel_index(pts, cfg.cam_voxel)), return_index=True, return_inverse=True)
    inv = inv.reshape(-1)
    sub = pts[first]
    alive = np.ones(len(sub), bool)        # not yet on a plane (RANSAC looks among these)
    structure = np.zeros(len(sub), bool)   # on a plane, in a part larger than a person
    for _ in range(cfg.max_planes):
        idx = np.flatnonzero(alive)
        if len(idx) < 100:
            break
        normal, offset, n_in = ransac_plane(sub[idx], cfg.plane_dist_m, 400, rng)
        if n_in < cfg.plane_min_fraction * len(sub):
            break
        on = idx[np.abs(sub[idx] @ normal + offset) < cfg.plane_dist_m]
        alive[on] = False
        part = cluster_points(sub[on], 2 * cfg.cam_voxel)
        # (a part whose bounding box has a diagonal within max_width_m fits a person either way)
        lo = np.full((part.max() + 1, 3), np.inf)
        hi = np.full((part.max() + 1, 3), -np.inf)
        np.minimum.at(lo, part, sub[on])
        np.maximum.at(hi, part, sub[on])
        for lab in np.flatnonzero(np.linalg.norm(hi - lo, axis=1) > cfg.max_width_m):
            m = on[part == lab]
            longer, shorter = _plane_extents(sub[m], normal)
            if longer > PERSON_MAX_HEIGHT_M or shorter > cfg.max_width_m:
                structure[m] = True
    return ~structure[inv]


# the 2nd-98th percentile spread of a normal distribution, in sigmas (2 x 2.054)
NOISE_SPREAD_SIGMAS = 4.108


def _robust_plan_extent(xy: np.ndarray, along: np.ndarray | None = None, sigma: float = 0.0) -> float:
    """Plan extent (m) of ``xy`` (N,2), 2-98 % spread (stereo noise sprays a few points far behind a
    person): along the principal axes; with ``along`` (2,) the unit plan direction of the view, along it
    and across it, the spread along it less that of the depth noise ``sigma`` (m) in quadrature (a far
    person's returns spread ± 2σ along the view: 1.2 m at σ 0.3 m, though the body is 0.3 m deep)."""
    if len(xy) < 4:
        return 0.0
    c = xy - xy.mean(0)
    if along is None:
        _, vec = np.linalg.eigh(c.T @ c)
    else:
        u = np.asarray(along, np.float64) / max(float(np.linalg.norm(along)), 1e-12)
        vec = np.array([[u[0], -u[1]], [u[1], u[0]]])
    q = c @ vec
    lo, hi = np.percentile(q, [2, 98], axis=0)
    ext = hi - lo
    if along is not None:
        ext[0] = np.sqrt(max(ext[0] ** 2 - (NOISE_SPREAD_SIGMAS * sigma) ** 2, 0.0))
    return float(ext.max())


def pick_human(points_world: np.ndarray, cfg: RegisterConfig, centre: np.ndarray | None = None,
               footprint: np.ndarray | None = None, pixels: tuple | None = None,
               eye: np.ndarray | None = None) -> np.ndarray:
    """Boolean mask of the largest person-like cluster of ``points_world`` (N,3) (z up); with
    ``centre`` (3,) only clusters whose centroid is within ``track_radius_m`` (plan) of it count.

    ``footprint`` (N,): each return's pixel footprint in metres (optical depth / focal length in
    pixels). The camera's resolution then sets two things a fixed number cannot: clusters link points
    at least ``cluster_px`` footprints (at the candidates' median depth) apart, not only ``cluster_m``
    (a 160-column camera's pixels are 8 cm apart at 7 m: a person there is dust at 8 cm), and a
    cluster is evidence enough with ``min_points`` returns *or* ``min_area_m2`` of surface (each
    return covering footprint²: a sixth of a person's front), whichever the camera can give at that
    depth. Without it: ``cluster_m`` and ``min_points`` alone.

    ``pixels`` = (rows, cols, depth, sigma) (N,) each: the returns' pixels, optical depths (m) and depth
    noise σ (m); returns on pixels at most ``surface_gap_px`` apart whose depths differ by at most
    ``link_sigma`` sigmas of their difference (:func:`pixel_links`) are linked as well: on
    the held-out 120×160 cloud (σ 0.1 m at 5.5 m, 0.3 m at 9 m) a person fell apart along the view
    into an upper and a lower piece, each person-like, and the larger half was taken (centroid p90
    41-51 cm, ``docs/design/register.md``). With ``pixels`` and the camera centre ``eye`` (3,) the
    width is judged across the view and, along it, less the depth noise's spread
    (:func:`_robust_plan_extent`): the linked person is as deep along the view as the noise makes it."""
    out = np.zeros(len(points_world), bool)
    fp2 = None if footprint is None else np.asarray(footprint, np.float64) ** 2
    if len(points_world) < cfg.min_points and (fp2 is None or fp2.sum() < cfg.min_area_m2):
        return out
    dist = cfg.cluster_m if fp2 is None else max(cfg.cluster_m, cfg.cluster_px * float(np.sqrt(np.median(fp2))))
    lab = cluster_returns(points_world, dist, pixels, cfg.surface_gap_px, cfg.link_sigma)
    sizes = np.bincount(lab)
    enough = sizes >= cfg.min_points
    if fp2 is not None:
        enough |= np.bincount(lab, weights=fp2, minlength=len(sizes)) >= cfg.min_area_m2
    for c in np.argsort(-sizes):
        if not enough[c]:
            continue
        m = lab == c
        p = points_world[m]
        if centre is not None and np.linalg.norm(p[:, :2].mean(0) - centre[:2]) > cfg.track_radius_m:
            continue
        if pixels is not None and eye is not None:
            along, sig = p[:, :2].mean(0) - np.asarray(eye, float)[:2], float(np.median(np.asarray(pixels[3])[m]))
        else:
            along, sig = None, 0.0
        if np.ptp(p[:, 2]) >= cfg.min_height_m and _robust_plan_extent(p[:, :2], along, sig) <= cfg.max_width_m:
            # stereo noise sprays single points behind/in front of the body: statistical outlier removal
            _, keep = _pcd(p).remove_statistical_outlier(nb_neighbors=20, std_ratio=2.0)
            idx = np.flatnonzero(m)
            m[:] = False
            m[idx[np.asarray(keep, np.int64)]] = True
            return m
    return out


def pixel_runs(rows: np.ndarray, cols: np.ndarray, gap: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal runs of pixels (``rows``, ``cols`` (N,) int): ``order`` (N,) the row-major sort of the
    pixels and ``run`` (N,) the run id of each sorted pixel (0..R-1). A run continues across fewer than
    ``gap`` missing pixels (``gap`` 1: strictly adjacent; 2 bridges the single stereo holes that split a
    torso into two narrow runs)."""
    order = np.lexsort((cols, rows))
    r, c = rows[order], cols[order]
    new = np.ones(len(r), bool)
    new[1:] = (r[1:] != r[:-1]) | (c[1:] - c[:-1] > gap)
    return order, np.cumsum(new) - 1


@dataclass(frozen=True)
class ColumnShape:
    """How :func:`body_columns` shapes the solid behind a person's front: a cross-section's depth D is
    its width clipped to [``lo``, ``hi``] m; a horizontal run of pixels continues across fewer than
    ``gap`` missing pixels (:func:`pixel_runs`); the lowest pixel of an image column within
    ``floor_reach_m`` m above the floor reaches down to it; ``back_frac`` / ``side_frac``: the share of
    D every column's far end / the far end of a run alone in its image row goes further back (a person
    walking along / across the view). :func:`body_columns` says why each is there."""

    lo: float
    hi: float
    gap: int = 2
    floor_reach_m: float = 0.35
    back_frac: float = 0.0
    side_frac: float = 0.0


def body_columns(points_world: np.ndarray, rows: np.ndarray, cols: np.ndarray, depth: np.ndarray, eye: np.ndarray,
                 fx: float, shape: ColumnShape, floor_z: float | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The solid behind a person's visible front, one horizontal column per human pixel, shaped as
    ``shape`` says (:class:`ColumnShape`: ``lo``, ``hi``, ``gap``, ``floor_reach_m``, ``back_frac``,
    ``side_frac`` below are its fields).

    ``points_world`` (N,3) the pixels' points (map frame), ``rows``/``cols`` (N,) their pixels,
    ``depth`` (N,) their optical depths (m), ``eye`` (3,) the camera centre, ``fx`` px. Each horizontal
    run of pixels (:func:`pixel_runs`, bridging ``gap``) is a cross-section of width w (run length ·
    mean depth / fx) and depth D = clip(w, ``lo``, ``hi``) m (limbs about as deep as wide, the torso
    capped), modelled as an ellipse with axes w and D: the pixel at lateral position s in (-1, 1) of its
    run spans ± h = D/2 · sqrt(1 - s²) around the run's centre range c, and c is the mean over the run of
    each pixel's estimate (its measured plan range + h; values more than ``hi`` from the run's median are
    left out). The measured front only places the centre: stereo noise no longer scatters the surface,
    the back is the front mirrored through the centre, and a round limb is an ellipse of area π w D / 4
    rather than a w × D box pushed a whole D back (measurements: ``docs/design/register.md``).

    Returns ``span`` (N,2): the column's near and far ends as offsets (m) along the horizontal viewing
    direction from the pixel's point (negative: toward the camera), ``pixel_m`` (N,) the pixel's footprint
    edge (depth / fx, m) and ``down_to`` (N,) heights (m) the column reaches down to, NaN for none: with
    ``floor_z`` given, the lowest human pixel of each image column lying within ``floor_reach_m`` above
    it reaches the floor (the foreground test loses the feet, whose background — the floor just
    behind them — is too near: body volume missing, the centroid too high; and a walking
    person's far foot, hidden behind the near one in stride). ``back_frac``:
    every column's far end goes ``back_frac`` · D further back (the front stays): a person walking along
    the view hides the far leg and arm behind the near ones (register: ``walk_back_frac`` scaled by
    :func:`.tracks.radial_speed`). ``side_frac``: the far end of the columns of a run that is alone in its image
    row goes ``side_frac`` · D further back (a person walking across the view, :func:`.tracks.side_back`: the
    far arm, shoulder and leg hidden behind the near ones); where a row shows several runs (legs apart
    in stride, an arm beside the torso) each is a limb seen whole, as deep as wide."""
    lo, hi, gap, floor_reach_m = shape.lo, shape.hi, shape.gap, shape.floor_reach_m
    back_frac, side_frac = shape.back_frac, shape.side_frac
    p = np.asarray(points_world, np.float64).reshape(-1, 3)
    n = len(p)
    z = np.asarray(depth, np.float64)
    if n == 0:
        return np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    rows, cols = np.asarray(rows, np.int64), np.asarray(cols, np.int64)
    order, rid = pixel_runs(rows, cols, gap)
    nr = int(rid[-1]) + 1
    c, zs = cols[order], z[order]
    cmin = np.full(nr, np.iinfo(np.int64).max)
    np.minimum.at(cmin, rid, c)
    cmax = np.full(nr, -1, np.int64)
    np.maximum.at(cmax, rid, c)
    npx = cmax - cmin + 1
    cnt = np.bincount(rid, minlength=nr)
    w = npx * (np.bincount(rid, zs, minlength=nr) / cnt) / fx
    D = np.clip(w, lo, hi)[rid]
    s = (c - cmin[rid] + 0.5) / npx[rid] * 2.0 - 1.0
    h = 0.5 * D * np.sqrt(np.clip(1.0 - s * s, 0.0, 1.0))
    d = p[order] - np.asarray(eye, float)
    rho = np.linalg.norm(d[:, :2], axis=1)
    est = rho + h
    o = np.lexsort((est, rid))                       # per-run median, then the mean of the values near it
    start = np.cumsum(cnt) - cnt
    srt = est[o]
    med = 0.5 * (srt[start + (cnt - 1) // 2] + srt[start + cnt // 2])
    near = np.abs(est - med[rid]) <= hi
    n_near = np.bincount(rid, near, minlength=nr)
    # (an even run whose two middle values lie more than ``hi`` apart has none near its median: the median)
    centre = np.where(n_near > 0, np.bincount(rid, est * near, minlength=nr) / np.maximum(n_near, 1), med)
    off = centre[rid] - rho
    run_row = rows[order][start]                      # each run's image row
    alone = (np.bincount(run_row - run_row.min(), minlength=1)[run_row - run_row.min()] == 1)[rid]
    span = np.empty((n, 2))
    span[order] = np.stack([off - h, off + h + (back_frac + side_frac * alone) * D], 1)
    down = np.full(n, np.nan)
    if floor_z is not None and np.isfinite(floor_z):
        oc = np.lexsort((-rows, cols))              # per image column, the lowest pixel (largest row) first
        low = oc[np.r_[True, cols[oc][1:] != cols[oc][:-1]]]
        low = low[p[low, 2] < floor_z + floor_reach_m]
        down[low] = floor_z
    return span, z / fx, down


def _repeat_index(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Item i repeated ``counts[i]`` times: (owner (sum,) item index, (sum,) index within its repeats)."""
    owner = np.repeat(np.arange(len(counts)), counts)
    return owner, np.arange(len(owner)) - np.repeat(np.cumsum(counts) - counts, counts)


def closed_surface(points_world: np.ndarray, eye: np.ndarray, thickness, voxel: float,
                   horizontal: bool = True, pixel_m=None, down_to=None) -> tuple[np.ndarray, np.ndarray]:
    """Closed triangle surface around the volume swept by the points (N,3) along their viewing rays
    from ``eye`` (3,) (their horizontal part when ``horizontal``: a body's depth is horizontal),
    voxelised at ``voxel`` m: vertices (V,3) float64, faces (F,3) int32, outward (counter-clockwise seen
    from outside).

    ``thickness``: scalar or (N,) m — each point extruded away from the camera over it; or (N,2) — the
    column from the first to the second offset (m, negative toward the camera; :func:`body_columns`).
    ``pixel_m`` (scalar or (N,), m): each point stands for a square pixel footprint of that edge; then a
    voxel is occupied when the columns fill at least half of it (their volume, sampled every voxel/2
    along the column, summed per voxel): an unbiased voxelisation. Without it every voxel a column
    touches is occupied (each dimension grows by about a voxel: a leg becomes a voxel too wide).
    A footprint wider than the voxel is split into m × m sub-pixels (m = ceil(edge / voxel)) so that
    its volume spreads over the voxels it covers. ``down_to`` (N,) m, NaN for none: the point's column
    also fills the vertical strip below its footprint down to that height (feet reaching the floor)."""
    p = np.asarray(points_world, np.float64).reshape(-1, 3)
    if len(p) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int32)
    d = p - np.asarray(eye, float)
    if horizontal:  # a body's depth is horizontal: extrude along the ray's plan direction
        d[:, 2] = 0.0
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
    th = np.asarray(thickness, float)
    if th.ndim == 2:
        a, b = th[:, 0], th[:, 1]
    else:
        a, b = np.zeros(len(p)), np.broadcast_to(th, (len(p),)).astype(float)
    if pixel_m is None:
        L = b - a
        frac = np.linspace(0.0, 1.0, max(2, int(np.ceil(max(L.max(), 0.0) / (voxel / 2))) + 1))
        t = a[:, None, None] + frac[None, :, None] * L[:, None, None]
        sw = (p[:, None, :] + t * d[:, None, :]).reshape(-1, 3)
        return voxel_boundary(np.floor(sw / voxel).astype(np.int64), voxel)     # repeated voxels are fine
    px = np.broadcast_to(np.asarray(pixel_m, float), (len(p),))
    m_sub = np.maximum(1, np.ceil(px / voxel - 1e-9).astype(np.int64))
    if (m_sub > 1).any():
        # a footprint wider than a voxel (a coarse camera, a far person) is split into m × m sub-pixels
        # across it (lateral × vertical), else its whole volume lands in the voxels along one line
        j, k = _repeat_index(m_sub ** 2)
        mj = m_sub[j]
        u = ((k % mj) + 0.5) / mj - 0.5
        v = ((k // mj) + 0.5) / mj - 0.5
        lat = np.stack([-d[j, 1], d[j, 0], np.zeros(len(j))], 1)
        lat /= np.maximum(np.linalg.norm(lat, axis=1, keepdims=True), 1e-9)
        p = p[j] + (u * px[j])[:, None] * lat + np.outer(v * px[j], [0.0, 0.0, 1.0])
        d, a, b, px = d[j], a[j], b[j], px[j] / mj
        if down_to is not None:
            down_to = np.asarray(down_to, float)[j]
    step = voxel / 2
    L = np.maximum(b - a, 0.0)
    ns = np.maximum(1, np.ceil(L / step).astype(np.int64))
    idx, k = _repeat_index(ns)
    t = a[idx] + (k + 0.5) / ns[idx] * L[idx]
    q = p[idx] + t[:, None] * d[idx]
    wgt = px[idx] ** 2 * (L / ns)[idx]
    if down_to is not None:
        dz = np.asarray(down_to, float)
        sel = np.isfinite(dz[idx])
        if sel.any():                                # strips below the footprint, down to ``down_to``
            qs, ws, j0 = q[sel], wgt[sel], idx[sel]
            ext = np.maximum(qs[:, 2] - px[j0] / 2 - dz[j0], 0.0)
            m = np.maximum(1, np.ceil(ext / step).astype(np.int64))
            j, kk = _repeat_index(m)
            qq = qs[j].copy()
            qq[:, 2] -= px[j0][j] / 2 + (kk + 0.5) / m[j] * ext[j]
            q = np.concatenate([q, qq])
            wgt = np.concatenate([wgt, ws[j] / px[j0][j] * ext[j] / m[j]])
    ijk = np.floor(q / voxel).astype(np.int64)
    lo = ijk.min(0)
    ijk -= lo
    dims = ijk.max(0) + 1
    key = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    full = np.flatnonzero(np.bincount(key, wgt, minlength=int(np.prod(dims))) >= 0.5 * voxel ** 3)
    if not len(full):
        return np.zeros((0, 3)), np.zeros((0, 3), np.int32)
    occ = np.stack(np.unravel_index(full, tuple(dims)), 1) + lo
    return voxel_boundary(occ, voxel)


def voxel_boundary(occ: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """Boundary surface of a set of occupied voxels ``occ`` (N,3) int (repeats allowed): two triangles
    per voxel face not shared with another occupied voxel; shared vertices (a closed mesh), outward
    orientation; vertices in lexicographic lattice order."""
    occ = np.asarray(occ, np.int64).reshape(-1, 3)
    if len(occ) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int32)
    lo = occ.min(0) - 1
    o = occ - lo
    dims = o.max(0) + 2
    grid = np.zeros(dims, bool)
    grid[o[:, 0], o[:, 1], o[:, 2]] = True
    quads = []
    # for each axis and direction: faces where occupied voxel meets empty neighbour
    for ax in range(3):
        for sgn in (1, -1):
            nb = np.roll(grid, -sgn, axis=ax)
            face = grid & ~nb
            idx = np.argwhere(face)
            if not len(idx):
                continue
            # face plane at coordinate idx[ax] + (1 if sgn > 0 else 0); the other two axes span it
            a1, a2 = [a for a in range(3) if a != ax]
            base = idx.copy()
            base[:, ax] += 1 if sgn > 0 else 0
            c = np.zeros((len(idx), 4, 3), np.int64)
            for q, (da, db) in enumerate(((0, 0), (1, 0), (1, 1), (0, 1))):
                c[:, q] = base
                c[:, q, a1] += da
                c[:, q, a2] += db
            # orientation: (a1, a2, ax) right-handed for ax = 0 -> (1,2), 1 -> (2,0), 2 -> (0,1)
            right = (a1, a2) in ((1, 2), (2, 0), (0, 1))
            if right != (sgn > 0):
                c = c[:, ::-1]
            quads.append(c)
    q = np.concatenate(quads)                      # (Q,4,3) corner lattice coordinates, in 0..dims
    # vertex ids on a dense lattice of the box (C order: lexicographic, as a sort would number them)
    flat = np.ravel_multi_index((q[..., 0], q[..., 1], q[..., 2]), tuple(dims + 1))
    used = np.zeros(int(np.prod(dims + 1)), bool)
    used[flat] = True
    cells = np.flatnonzero(used)
    ids = np.zeros(len(used), np.int64)
    ids[cells] = np.arange(len(cells))
    inv = ids[flat]
    faces = np.concatenate([inv[:, [0, 1, 2]], inv[:, [0, 2, 3]]]).astype(np.int32)
    corners = np.stack(np.unravel_index(cells, tuple(dims + 1)), 1)
    verts = (corners + lo).astype(np.float64) * voxel
    return verts, faces


def column_centroid(points_world: np.ndarray, eye: np.ndarray, span: np.ndarray, pixel_m: np.ndarray,
                    down_to: np.ndarray | None = None) -> np.ndarray:
    """Centre of mass (3,) of the body columns (:func:`body_columns`: ``span`` (N,2) m along the plan
    viewing direction from ``eye`` (3,), footprint ``pixel_m`` (N,) m, strips down to ``down_to`` (N,)
    m, NaN none) of the points (N,3): each column weighs its volume. The solid :func:`closed_surface`
    voxelises has this centre up to its voxels; NaN (3,) for no points."""
    p = np.asarray(points_world, np.float64).reshape(-1, 3)
    if len(p) == 0:
        return np.full(3, np.nan)
    d = p - np.asarray(eye, float)
    d[:, 2] = 0.0
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
    a, b = np.asarray(span, float)[:, 0], np.asarray(span, float)[:, 1]
    px = np.broadcast_to(np.asarray(pixel_m, float), (len(p),))
    L = np.maximum(b - a, 0.0)
    mid = p + d * (0.5 * (a + b))[:, None]
    vol = px ** 2 * L
    pos, w = [mid], [vol]
    if down_to is not None:
        dz = np.asarray(down_to, float)
        ext = np.where(np.isfinite(dz), np.maximum(p[:, 2] - px / 2 - np.nan_to_num(dz), 0.0), 0.0)
        strip = mid.copy()
        strip[:, 2] = p[:, 2] - px / 2 - ext / 2
        pos.append(strip)
        w.append(px * L * ext)
    P, W = np.concatenate(pos), np.concatenate(w)
    return P.T @ W / W.sum() if W.sum() > 0 else p.mean(0)


def silhouette_cut(rows: np.ndarray, cols: np.ndarray, depth: np.ndarray, static_depth: np.ndarray,
                   reach_px: int, margin_m) -> float:
    """Share (0-1) of a person's image rows whose silhouette ends against a nearer static surface or the
    image's side: the person is partly hidden there (behind a corner, a pillar) or leaves the view.

    ``rows``/``cols`` (N,) the person's pixels, ``depth`` (N,) their depths (m), ``static_depth`` (H,W)
    the camera's static depth (m, NaN none). A row's run ends at its leftmost and rightmost pixel; it is
    cut on a side when, within ``reach_px`` pixels beyond that end, the static depth is nearer than the
    end's depth by more than ``margin_m`` (m, scalar or (N,) per pixel: the end's depth noise; the
    occluder in front of the person), or the image ends.
    The visible part of a cut person is not the person: its centre lies toward the visible side and
    the body model (:func:`body_columns`) cannot say how much is missing
    (docs/design/register.md, "A person half behind a corner"). 0 for no pixels."""
    r = np.asarray(rows, np.int64)
    if len(r) == 0:
        return 0.0
    c, d = np.asarray(cols, np.int64), np.asarray(depth, float)
    W = static_depth.shape[1]
    order = np.lexsort((c, r))
    r, c = r[order], c[order]
    d = (d - np.broadcast_to(np.asarray(margin_m, float), d.shape))[order]   # nearer than this: in front
    starts = np.flatnonzero(np.r_[True, r[1:] != r[:-1]])
    ends = np.r_[starts[1:], len(r)] - 1
    cut = np.zeros(len(starts), bool)
    for idx, step in ((starts, -1), (ends, 1)):
        rr, cc, dd = r[idx], c[idx], d[idx]
        for k in range(1, reach_px + 1):
            ck = cc + step * k
            inside = (ck >= 0) & (ck < W)
            cut |= ~inside & (k == 1)
            sd = np.full(len(ck), np.nan)
            sd[inside] = static_depth[rr[inside], ck[inside]]
            with np.errstate(invalid="ignore"):
                cut |= sd < dd
    return float(cut.mean())
