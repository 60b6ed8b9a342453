"""Automatic human (moving-object) instance segmentation on the LiDAR's native range-image grid.

The method of the Ouster OS0 instance-segmentation note, on the organised scan ``lidar/range``
(T, Hl, Wl) of a scene whose scans have poses ``pose/T_world_lidar``:

1. **Background model**: every scan's returns in the world frame go into a 15 cm voxel model of the
   static scene (:class:`holodata.mapping.background.VoxelBackground`: voxels occupied in at least
   ``min_fraction`` of the scans that observed them, free-space test from the scan origins; people
   occupy a voxel only briefly), plus the **floor plane** (:func:`floor_plane`): returns within
   ``floor_margin_m`` of it are background too.
2. **Foreground**: the returns of a scan outside the background (grid mask, (Hl, Wl)).
3. **Seeds by shrinking**: binary erosion of the foreground mask (columns wrap around), which
   removes isolated pixels and the fringe of mixed/edge returns; 3×3, or 1×3 when the rows are
   more than twice as far apart in angle as the columns (:func:`shrink_structure`).
4. **Flood fill** from the seeds over grid neighbours (right, down, both diagonals, and the
   second neighbour along rows and columns to bridge single dropouts; columns wrap) that are
   foreground and within a Euclidean distance ``dist_m + dist_per_m · r + spacing_factor · s · r``
   of each other (3-D points, metres; r the nearer range, s the beam pattern's angular step between
   the two pixels — :func:`neighbour_spacing`, from the row elevations measured in the scan,
   :func:`beam_elevations`). Implemented as connected components of that neighbour graph
   (``scipy.sparse.csgraph``) keeping the components that hold a seed. Clusters standing on the
   same plan-view spot with overlapping heights are joined (:func:`merge_stacked`: a limb split
   off by a depth jump).
5. **Keep the largest cluster(s)**: components with at least ``min_points`` returns whose extent is
   person-like (vertical extent >= ``min_height_m``, horizontal extent <= ``max_width_m``, top at
   most ``max_height_m`` above the floor, not flat), largest first, at most ``max_instances``.

Beam geometry: the constants were first tuned on an OS1-like LiDAR (33.2° vertical FOV, 64 beams,
0.53° apart); on an OS0-like one (90°, 32 beams: 2.9° apart) walkers' AP50 fell to 0.15. Causes
measured (``benchmarks/segment.py``): rows of a person at 4–6 m are 20–30 cm apart, beyond the
fixed 10 cm + 2 %·r link threshold, so far people fell apart into rows; the 3×3 shrink removed a
whole 15–30 cm row top and bottom and left such a person (~6 rows) without seeds; the far floor,
hit by a coarse ring in a single scan as the robot moves, stayed out of the voxel background and
joined the feet; the near-background split (seeds only away from voxels next to the background,
then a 3-pixel regrowth) cut people within 1 m — whom a 90° LiDAR sees head to toe — into pieces
the regrowth could not rejoin; and ``min_fraction`` 0.25 kept the trail of walkers in short
recordings as background. AP50 now >= 0.9 for both LiDARs at 64×1024, 64×512 and 32×512 on every
corner kind (numbers in ``benchmarks/segment.py``).

Output per scan: an instance image (Hl, Wl) uint16, 0 = background / no return, 1 = the largest
instance, 2 = the next ... Stored as ``lidar/instance`` (T, Hl, Wl) uint16 with
``dims = [frame, beam, column]`` and the parameters in its attributes (written shard by shard with
the dataset writer: atomic shards, a rerun resumes), with ``poses_sha256``, the fingerprint of the
``pose/T_world_lidar`` it was made with (:func:`instance_state`: masks made with other poses are
made again, not resumed or reused).

Points: ``lidar/points`` holds the valid pixels of ``lidar/range`` in row-major order (see
:mod:`holodata.ingest`), in the sensor frame at each point's own time; with ``lidar/point_time_ns``
(time relative to the scan stamp) the points are de-skewed with poses interpolated between scans
(:meth:`LidarScans.deskew_points`: one transform for a scan taken at rest, one pose per column).

Runtime (400-cycle corner, 400 scans of 64×512, 366 taken at rest; background model + segmentation,
same masks as before): 20.7-22.5 s wall / 16.9-18.1 s CPU → 4.2-4.5 s on 2 shared cores at load ~4-5
(``benchmarks/pipeline.py``) — a dense voxel grid for the occupancy count and lookups
(:mod:`.background`), ``lidar/range`` read a shard at a time, the de-skew shortcuts
(:meth:`LidarScans.scan_world` for the background pass), and :func:`background_and_segment`, which
reuses the background pass's world points so that scans without foreground are not read twice.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from ..conventions import transform_points
from ..errors import DatasetError, InputError
from ..progress import track

INSTANCE_ARRAY = "lidar/instance"
# neighbour offsets (row, col): right, down, down-right, down-left, 2 right, 2 down
NEIGHBOURS = ((0, 1), (1, 0), (1, 1), (1, -1), (0, 2), (2, 0))


@dataclass(frozen=True)
class SegmentConfig:
    """Parameters of :func:`segment_scan` (metres). ``voxel`` / ``min_fraction`` / ``min_hits``:
    background model (:meth:`VoxelBackground.build`; 0.6 as slam's: 0.25 kept walkers' trails in
    short recordings); ``floor_margin_m``: returns this close to the floor plane are background (0: no
    floor model); ``tolerance_voxels`` 0: a return is background when its own voxel is, 1: when any
    voxel of its 3×3×3 neighbourhood is (the model's ``contains``);
    ``erosion``: iterations of the shrink that makes the seeds (:func:`shrink_structure`);
    ``dist_m`` + ``dist_per_m``·r + ``spacing_factor``·(beam step)·r: flood-fill distance threshold
    between grid neighbours (:func:`link_threshold`); ``merge_xy_m``: join clusters this close in plan
    view with overlapping heights (:func:`merge_stacked`; 0: off); ``max_height_m``: highest top of a
    person above the floor (and tallest merge); ``min_points``: smallest kept cluster;
    ``min_height_m`` / ``max_width_m``: person-like extent (0 / inf switch the check off);
    ``min_depth_m``: smallest robust extent along the cluster's least principal axis (rejects flat
    patches of wall that the background missed, e.g. behind a lane people walk often);
    ``max_instances``: keep at most this many clusters per scan (largest first; 0 = no limit);
    ``grow_pixels`` > 0: seeds and flood fill only away from returns within one voxel of the
    background, then the clusters regrow this many pixels (the former default 3: it split people
    within ~1 m of a wide-FOV LiDAR; 0 = off)."""

    voxel: float = 0.15
    min_fraction: float = 0.6
    min_hits: int = 2
    floor_margin_m: float = 0.07
    merge_xy_m: float = 0.15
    max_height_m: float = 2.3
    tolerance_voxels: int = 0
    erosion: int = 1
    dist_m: float = 0.10
    dist_per_m: float = 0.02
    spacing_factor: float = 2.0
    min_points: int = 15
    min_height_m: float = 0.25
    max_width_m: float = 1.5
    min_depth_m: float = 0.06
    max_instances: int = 0
    deskew: bool = True
    free_space: bool = True
    grow_pixels: int = 0

    def to_attrs(self) -> dict:
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in asdict(self).items()}


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
    c = np.maximum(np.cos(el), 0.2)
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


def grow(lab: np.ndarray, allowed: np.ndarray, points: np.ndarray, dist_m: float, dist_per_m: float,
         steps: int, elev: np.ndarray | None = None, spacing_factor: float = 0.0) -> np.ndarray:
    """Grow labels ``lab`` (H,W) int64 (-1 = none) by up to ``steps`` pixels into ``allowed`` pixels
    (8-neighbourhood, columns wrap) whose point is within the flood-fill distance of the labelled
    neighbour's point."""
    lab = lab.copy()
    rng = np.linalg.norm(points, axis=-1)
    offs = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if (dr, dc) != (0, 0)]
    for _ in range(steps):
        new = lab.copy()
        for dr, dc in offs:
            # neighbour (i+dr, j+dc) of pixel (i, j); rows past the edge are unlabelled
            nl = _shift(lab, dr, dc, fill=-1)
            npnt = _shift(points, dr, dc, fill=0.0)
            cand = (new < 0) & allowed & (nl >= 0)
            if not cand.any():
                continue
            d = np.linalg.norm(points - npnt, axis=-1)
            sp = neighbour_spacing(elev, lab.shape[1], dr, dc) if elev is not None else None
            ok = cand & (d < link_threshold(rng, rng, sp, dist_m, dist_per_m, spacing_factor))
            new[ok] = nl[ok]
        if (new == lab).all():
            break
        lab = new
    return lab


def segment_scan(points: np.ndarray, valid: np.ndarray, background: np.ndarray | None,
                 cfg: SegmentConfig | None = None, points_world: np.ndarray | None = None,
                 shifts: np.ndarray | None = None, background_near: np.ndarray | None = None,
                 floor: np.ndarray | None = None, elev: np.ndarray | None = None) -> np.ndarray:
    """Instance image of one organised scan.

    ``points`` (H,W,3) sensor-frame points m (flood-fill distances); ``valid`` (H,W) bool returns;
    ``background`` (H,W) bool, True = return explained by the static background (None: none is);
    ``points_world`` (H,W,3) world points for the extent checks (default ``points``; the z axis must be
    up); ``background_near`` (H,W) bool, True = return *within one voxel* of the background: when
    given, seeds and flood fill use only returns away from the background (a person touching a wall
    or a patch of wall the background missed cannot merge), and the clusters then grow by
    ``grow_pixels`` into the other foreground returns (feet, hands near walls); ``shifts`` (H,)
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
                           destagger(np.asarray(pw), shifts), np.zeros(len(shifts), np.int64),
                           None if background_near is None else destagger(np.asarray(background_near, bool), shifts),
                           floor, elev)
        return destagger(lab, shifts, inverse=True)
    valid = np.asarray(valid, bool)
    fg = valid & (~np.asarray(background, bool) if background is not None else True)
    core = fg & ~np.asarray(background_near, bool) if background_near is not None else fg
    P = np.asarray(points, np.float64)
    if elev is None:
        elev = beam_elevations(P, valid)
    seeds = erode(core, cfg.erosion, shrink_structure(elev, fg.shape[1]))
    if cfg.spacing_factor <= 0:
        elev = None
    lab, n = flood_fill(P, core, seeds, cfg.dist_m, cfg.dist_per_m, elev, cfg.spacing_factor)
    if background_near is not None and cfg.grow_pixels > 0 and n:
        lab = grow(lab, fg, P, cfg.dist_m, cfg.dist_per_m, cfg.grow_pixels, elev, cfg.spacing_factor)
    out = np.zeros(fg.shape, np.uint16)
    if n == 0:
        return out
    pw = np.asarray(points_world if points_world is not None else points, np.float64)
    if cfg.merge_xy_m > 0 and n > 1:
        lab, n = merge_stacked(lab, n, pw, cfg.merge_xy_m, cfg.max_width_m, max_height_m=cfg.max_height_m)
    sel = lab >= 0
    ls, ps = lab[sel], pw[sel]
    sizes = np.bincount(ls, minlength=n)
    zmin = np.full(n, np.inf)
    zmax = np.full(n, -np.inf)
    np.minimum.at(zmin, ls, ps[:, 2])
    np.maximum.at(zmax, ls, ps[:, 2])
    ok = sizes >= cfg.min_points
    ok &= (zmax - zmin) >= min_height(cfg.min_height_m, elev, P[sel], ls, n)
    if floor is not None and np.isfinite(cfg.max_height_m):
        top = np.full(n, -np.inf)
        hfl = above_floor(floor, ps)
        np.maximum.at(top, ls, hfl)
        ok &= top <= cfg.max_height_m
    cand = np.flatnonzero(ok)
    if np.isfinite(cfg.max_width_m) or cfg.min_depth_m > 0:
        good = []
        for c in cand:
            q = ps[ls == c]
            if _plan_extent(q[:, :2]) <= cfg.max_width_m and _thickness(q) >= cfg.min_depth_m:
                good.append(c)
        cand = np.array(good, np.int64)
    cand = cand[np.argsort(-sizes[cand], kind="stable")]
    if cfg.max_instances > 0:
        cand = cand[:cfg.max_instances]
    remap = np.zeros(n, np.uint16)
    remap[cand] = np.arange(1, len(cand) + 1, dtype=np.uint16)
    out[sel] = remap[ls]
    return out


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
            need[c] = min(need[c], 0.8 * span * float(np.median(rh[order[a:b]])))
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


# ------------------------------------------------------------------------------------------ dataset
@dataclass
class LidarScans:
    """Organised LiDAR scans of a scene: ``range`` lazy (T,H,W) array; ``stamps`` (T,) int64 ns
    (0 = no scan); ``poses`` (T,4,4) T_world_lidar; ``has_time`` whether per-point times exist."""

    scene: object
    poses: np.ndarray
    stamps: np.ndarray
    shape: tuple
    has_time: bool
    # lidar/range handle and the block of frames of the last sequential read (range_frame)
    _range: object = field(default=None, init=False, repr=False, compare=False)
    _block: tuple | None = field(default=None, init=False, repr=False, compare=False)
    _last: int = field(default=-2, init=False, repr=False, compare=False)

    @classmethod
    def open(cls, scene, url: str = "") -> "LidarScans":
        names = set(scene.arrays())
        where = f"{url}: scene {scene.id!r}"
        if "lidar/range" not in names or "lidar/points" not in names:
            raise InputError(f"{where} has no organised LiDAR scans (lidar/range + lidar/points); the grid "
                             f"segmentation needs an Ouster-like organised cloud")
        if "pose/T_world_lidar" not in names:
            raise InputError(f"{where} has no pose/T_world_lidar (run holodata slam first)")
        poses = np.asarray(scene["pose/T_world_lidar"][...], np.float64)
        rng = scene["lidar/range"]
        if "lidar/timestamp_ns" in names:
            stamps = np.asarray(scene["lidar/timestamp_ns"][...], np.int64)
        else:
            stamps = np.asarray(scene["time/timestamp_ns"][...], np.int64)
        if poses.shape != (scene.n_frames, 4, 4) or rng.shape[0] != scene.n_frames:
            raise DatasetError(f"{where}: pose/T_world_lidar {poses.shape} / lidar/range {rng.shape} do not "
                               f"match {scene.n_frames} frames")
        return cls(scene, poses, stamps, tuple(rng.shape[1:]), "lidar/point_time_ns" in names)

    def usable(self, k: int) -> bool:
        return bool(self.stamps[k] != 0 and np.isfinite(self.poses[k]).all())

    def trajectory(self):
        from ..trajectory import Trajectory

        ok = np.array([self.usable(k) for k in range(len(self.stamps))])
        ts, ps = self.stamps[ok], self.poses[ok]
        order = np.argsort(ts, kind="stable")
        ts, ps = ts[order], ps[order]
        keep = np.concatenate([[True], np.diff(ts) > 0]) if len(ts) else np.zeros(0, bool)
        return Trajectory(ts[keep], ps[keep]) if keep.any() else None

    def range_frame(self, k: int) -> np.ndarray:
        """(H,W) float32 ``lidar/range`` of frame ``k``. Sequential reads (k, k+1, ...) load the rest of
        the zarr shard at once (one decompression per shard, not per frame); others read one frame."""
        if self._range is None:
            self._range = self.scene["lidar/range"]
        blk = self._block
        sequential, self._last = k == self._last + 1, k
        if blk is not None and blk[0] <= k < blk[1]:
            return blk[2][k - blk[0]]
        if not sequential:
            return np.asarray(self._range[k], np.float32)
        step = int((getattr(self._range, "shards", None) or self._range.chunks)[0])
        end = min((k // step + 1) * step, len(self.stamps))
        self._block = blk = (k, end, np.asarray(self._range[k:end], np.float32))
        return blk[2][0]

    def _returns(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(``lidar/range`` (H,W) float32, its finite pixels (H,W) bool, ``lidar/points`` (N,3) float64:
        one point per finite pixel in row-major order, checked) of frame ``k``."""
        r = self.range_frame(k)
        fin = np.isfinite(r)
        pts = np.asarray(self.scene.ragged("lidar/points", k), np.float64)
        n_fin = int(fin.sum())
        if len(pts) != n_fin:
            raise DatasetError(f"scene {self.scene.id!r} frame {k}: lidar/points has {len(pts)} points for "
                               f"{n_fin} valid lidar/range pixels (expected the valid pixels in row-major order)")
        return r, fin, pts

    def scan(self, k: int, traj=None, deskew: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Frame ``k``: (valid (H,W) bool, sensor points (H,W,3) float64, world points (H,W,3) float64,
        NaN where not valid). World points use per-point poses interpolated from ``traj`` at
        ``stamp + point_time`` when ``deskew`` and per-point times exist, else the scan pose
        (:meth:`deskew_points`)."""
        H, W = self.shape
        r, fin, pts = self._returns(k)
        valid = fin & (r > 0)
        P = np.zeros((H, W, 3))
        P[fin] = pts
        f = np.isfinite(P)
        valid &= f[..., 0] & f[..., 1] & f[..., 2]
        if not self.usable(k):
            return np.zeros((H, W), bool), P, np.full((H, W, 3), np.nan)
        tt = None
        if deskew and self.has_time and traj is not None and len(traj) > 1:
            t = np.asarray(self.scene.ragged("lidar/point_time_ns", k), np.int64).reshape(-1)
            tt = np.zeros((H, W), np.int64)
            if len(t) == len(pts):
                tt[fin] = t
        return valid, P, self.deskew_points(k, P, valid, tt, traj)

    def scan_world(self, k: int, traj=None, deskew: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Frame ``k``: (valid (H,W) bool, world points of the valid returns (N,3) float64 in row-major
        order) — ``valid`` and ``Pw[valid]`` of :meth:`scan`, the same values; a scan taken at rest is
        transformed as its list of returns, without the (H,W,3) grids."""
        H, W = self.shape
        r, fin, pts = self._returns(k)
        f = np.isfinite(pts)
        vf = (r[fin] > 0) & f[:, 0] & f[:, 1] & f[:, 2]     # scan(): valid = finite range > 0, finite point
        valid = np.zeros((H, W), bool)
        valid[fin] = vf
        if not self.usable(k) or not vf.any():
            return np.zeros((H, W), bool) if not self.usable(k) else valid, np.zeros((0, 3))
        tt = None
        if deskew and self.has_time and traj is not None and len(traj) > 1:
            t = np.asarray(self.scene.ragged("lidar/point_time_ns", k), np.int64).reshape(-1)
            tv = t[vf] if len(t) == len(pts) else np.zeros(int(vf.sum()), np.int64)
            s = int(self.stamps[k])
            if not _constant_pose(traj, s + min(int(tv.min()), 0), s + max(int(tv.max()), 0)):
                tt = np.zeros((H, W), np.int64)
                if len(t) == len(pts):
                    tt[fin] = t
        if tt is None:
            return valid, transform_points(self.poses[k], pts[vf])
        P = np.zeros((H, W, 3))
        P[fin] = pts
        return valid, self.deskew_points(k, P, valid, tt, traj)[valid]

    def deskew_points(self, k: int, P: np.ndarray, valid: np.ndarray, tt: np.ndarray | None, traj=None) -> np.ndarray:
        """(H,W,3) world points (NaN where not ``valid``) of scan ``k``'s sensor points ``P`` (H,W,3) m
        with per-point times ``tt`` (H,W) int64 ns after the scan stamp: point i goes through
        ``poses[k] @ inv(traj(stamp)) @ traj(stamp + tt_i)`` (``traj`` interpolated, SLERP). ``tt`` or
        ``traj`` None: the scan pose for every point. Shortcuts with the same result up to rounding
        (~1e-15 m): one transform when ``traj`` holds the same pose over the whole time span of the scan
        (the robot at rest: most scans of a recording that stands), one pose per column when the
        returns of a column share one time (the Ouster layout; no per-point gather), else one pose per
        distinct time."""
        H, W = valid.shape
        if not valid.any():
            return np.full((H, W, 3), np.nan)
        s = int(self.stamps[k])
        tv = tt[valid] if tt is not None else None
        if tv is None or traj is None or len(traj) < 2 or _constant_pose(traj, s + min(int(tv.min()), 0),
                                                                          s + max(int(tv.max()), 0)):
            Pw = transform_points(self.poses[k], P)        # the whole grid: cheaper than gathering
            Pw[~valid] = np.nan
            return Pw
        Pw = np.full((H, W, 3), np.nan)
        T0 = self.poses[k] @ np.linalg.inv(traj.interpolate(np.array([s]))[0])
        tcol = np.where(valid, tt, np.iinfo(np.int64).min).max(0)
        if (tt == tcol[None, :])[valid].all():
            has = np.flatnonzero(valid.any(0))
            Ts = T0 @ traj.interpolate(tcol[has] + s)                     # (C,4,4): one pose per column
            Pw[:, has] = transform_points(Ts[None], P[:, has])
            Pw[~valid] = np.nan
            return Pw
        ut, inv = np.unique(tv + s, return_inverse=True)                # one pose per distinct time
        Ts = T0 @ traj.interpolate(ut)
        Pw[valid] = np.einsum("nij,nj->ni", Ts[inv, :3, :3], P[valid]) + Ts[inv, :3, 3]
        return Pw


def _constant_pose(traj, t0: int, t1: int) -> bool:
    """True when trajectory ``traj`` interpolates one and the same pose over [t0, t1] (ns): every
    pose from the last one at or before ``t0`` to the first one at or after ``t1`` is identical
    (clamped at the ends, as :meth:`Trajectory.interpolate` is)."""
    ts = traj.timestamp_ns
    i0 = max(int(np.searchsorted(ts, t0, "right")) - 1, 0)
    i1 = min(int(np.searchsorted(ts, t1, "left")), len(ts) - 1)
    seg = traj.poses[i0:max(i1, i0) + 1]
    return bool((seg == seg[0]).all())


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
        q = q[f[:, 0] & f[:, 1] & f[:, 2] & (q[:, 2] < z_max)]   # (N,3).all(1) is ~10x slower
        low.append(q[rng.choice(len(q), cap, replace=False)] if len(q) > cap else q)
    p = np.concatenate(low).astype(np.float64) if low else np.zeros((0, 3))
    if len(p) < min_points:
        return None
    if len(p) > 400_000:
        p = p[rng.choice(len(p), 400_000, replace=False)]
    lo, hi = p[:, 2].min(), p[:, 2].max()
    hist, edges = np.histogram(p[:, 2], bins=max(1, int(np.ceil((hi - lo) / 0.02))), range=(lo, max(hi, lo + 0.02)))
    z0 = edges[int(np.argmax(hist))] + 0.01
    coef = np.array([0.0, 0.0, z0])
    band = 0.10
    for _ in range(4):  # re-select the returns near the current plane (follows a tilted world frame), refit
        res = p[:, 2] - (p[:, :2] @ coef[:2] + coef[2])
        q = p[np.abs(res) < band]
        if len(q) < min_points:
            return None
        A = np.c_[q[:, :2], np.ones(len(q))]
        coef = np.linalg.lstsq(A, q[:, 2], rcond=None)[0]
        band = max(3.0 * float((q[:, 2] - A @ coef).std()), 0.03)
    return coef


def above_floor(plane: np.ndarray | None, points_world: np.ndarray) -> np.ndarray:
    """(N,) height (m) of world points above :func:`floor_plane` ``plane`` (inf without a plane)."""
    p = np.asarray(points_world, np.float64).reshape(-1, 3)
    if plane is None:
        return np.full(len(p), np.inf)
    return p[:, 2] - (p[:, :2] @ plane[:2] + plane[2])


def background_from_points(points_world: list, origins, cfg: SegmentConfig):
    """:class:`VoxelBackground` of world-frame scans with the segmentation's settings (free-space test
    with the scans' ``origins`` when ``cfg.free_space``)."""
    from .background import VoxelBackground

    use = cfg.free_space and origins is not None and len(origins)
    return VoxelBackground.build(points_world, voxel=cfg.voxel, min_fraction=cfg.min_fraction, min_hits=cfg.min_hits,
                                 origins=np.asarray(origins) if use else None)


def build_background(scans: LidarScans, cfg: SegmentConfig, traj=None, quiet: bool = True):
    """Voxel background model of a scene's scans (world frame). With ``cfg.free_space`` the scan
    origins go to :meth:`VoxelBackground.build` (free-space test: a voxel people walk through is seen
    through by other scans and drops out; measured AP50 0.96 vs 0.94 with the occupancy count on a
    60-frame corner with two walkers)."""
    return _background_pass(scans, cfg, traj, quiet)[0]


def _background_pass(scans: LidarScans, cfg: SegmentConfig, traj=None, quiet: bool = True, keep: bool = False):
    """(background model, kept) of :func:`build_background`; ``keep``: kept = {frame: float32 world
    points (N,3) of the valid returns in row-major order} of the usable
    scans (the lists the model is built from, no copy), for :func:`segment_scene` ``world_points``."""
    pts, origins, kept = [], [], {}
    for k in track(range(len(scans.stamps)), len(scans.stamps), "background", quiet):
        _, pw = scans.scan_world(k, traj, cfg.deskew)
        if not scans.usable(k):
            continue
        pts.append(pw.astype(np.float32))
        origins.append(scans.poses[k][:3, 3])
        if keep:
            kept[k] = pts[-1]
    origins = np.array(origins) if origins else None
    bg = background_from_points(pts, origins, cfg)
    if cfg.floor_margin_m > 0:
        bg.floor = floor_plane(pts, origins)
    return bg, kept


def background_and_segment(url: str, scene_id: str | None = None, cfg: SegmentConfig | None = None,
                           quiet: bool = True, overwrite: bool = False, segment: bool = True, scans=None, traj=None):
    """(background model, :func:`segment_scene` summary or None, world points): :func:`build_background`
    of the scene's scans and, with ``segment``, their segmentation, which reuses the background pass's
    world points: scans without foreground are not read and de-skewed a second time (366 of the 400
    scans of a 400-cycle corner are taken at rest, most of them without foreground). World points:
    {frame: float32 world points (N,3) of the valid returns in row-major order} of the usable scans,
    the lists the model was built from (``holodata register`` builds its map from them). ``scans`` /
    ``traj``: the scene's :class:`LidarScans` and trajectory when the caller has them."""
    from ..dataset import open_dataset

    cfg = cfg or SegmentConfig()
    ds = open_dataset(url)
    sid = _scene_id(ds, url, scene_id)
    if scans is None:
        scans = LidarScans.open(ds.scene(sid), url)
    if traj is None:
        traj = scans.trajectory()
    bg, kept = _background_pass(scans, cfg, traj, quiet, keep=True)
    if not segment:
        return bg, None, kept
    return bg, segment_scene(url, sid, cfg, quiet, overwrite, background=bg, world_points=kept), kept


def surely_without_foreground(bg, points_world32: np.ndarray, cfg: SegmentConfig) -> bool:
    """True when a scan whose valid returns have the float32 world points ``points_world32`` (N,3)
    has fewer than ``cfg.min_points`` foreground returns (returns outside the background model
    ``bg`` and its floor, as :func:`background_masks` decides on the float64 points), so that
    :func:`segment_scan` finds nothing in it. Returns whose float64 point might be classified
    otherwise — within 1e-6·(|x|+1) m (>15x the float32 rounding) of a voxel face or of the floor
    margin — count as foreground, so the answer is exact for the float64 points."""
    p = np.asarray(points_world32, np.float64).reshape(-1, 3)
    need = max(cfg.min_points, 1)
    if len(p) < need:
        return True
    q = np.divide(p, bg.voxel, dtype=np.float64)
    ijk = np.floor(q)                                # voxel indices, as VoxelBackground.contains computes them
    fg = ~bg._lookup(ijk, bool(cfg.tolerance_voxels))
    q -= ijk
    tol = 1e-6 * (np.abs(p) + 1.0)
    near = np.minimum(q, 1.0 - q) * bg.voxel <= tol
    amb = near[:, 0] | near[:, 1] | near[:, 2]
    floor = getattr(bg, "floor", None)
    if floor is not None and cfg.floor_margin_m > 0:
        h = above_floor(floor, p)
        fg &= ~(h < cfg.floor_margin_m)
        amb |= np.abs(h - cfg.floor_margin_m) <= tol[:, 2] + abs(floor[0]) * tol[:, 0] + abs(floor[1]) * tol[:, 1]
    return int((fg | amb).sum()) < need


def in_background(bg, points_world: np.ndarray, tolerance_voxels: int = 0) -> np.ndarray:
    """(N,) bool: world points whose voxel is a background voxel (``tolerance_voxels`` 0), or lies
    within one voxel of one (1: :meth:`VoxelBackground.contains`)."""
    if tolerance_voxels:
        return bg.contains(points_world)
    return bg.contains(points_world, 0)


def grid_geometry(scans: LidarScans, n: int = 5) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(destagger shifts (H,) int, beam elevations (H,) rad) of a scene's organised scans, measured
    once from up to ``n`` scans spread over the recording (:func:`row_shifts` — the most common value
    per row — and the median of :func:`beam_elevations`); (None, None) without usable scans (then
    :func:`segment_scan` measures them per scan)."""
    sh, el = [], []
    H = scans.shape[0]
    for k in np.unique(np.linspace(0, len(scans.stamps) - 1, min(n, len(scans.stamps))).round().astype(int)):
        valid, P, _ = scans.scan(int(k), None, False)
        if valid.sum() >= 8 * H:
            sh.append(row_shifts(P, valid))
            el.append(beam_elevations(P, valid))
    if not sh:
        return None, None
    sh = np.array(sh)
    mode = np.array([np.bincount(c - c.min()).argmax() + c.min() for c in sh.T], np.int64)
    return mode, np.median(el, axis=0)


def background_masks(bg, valid: np.ndarray, points_world: np.ndarray, cfg: SegmentConfig
                     ) -> tuple[np.ndarray, np.ndarray | None]:
    """(background (H,W) bool, near (H,W) bool or None) of one scan for :func:`segment_scan`:
    background = returns in a background voxel (:func:`in_background`, ``cfg.tolerance_voxels``) or
    within ``cfg.floor_margin_m`` of the floor plane ``bg.floor`` (when the model has one); near =
    within one voxel of the background, only with ``cfg.grow_pixels`` > 0 (else None)."""
    v = np.asarray(valid, bool)
    p = points_world[v]
    bgm = np.zeros(v.shape, bool)
    bgm[v] = in_background(bg, p, cfg.tolerance_voxels)
    floor = getattr(bg, "floor", None)
    if floor is not None and cfg.floor_margin_m > 0:
        bgm[v] |= above_floor(floor, p) < cfg.floor_margin_m
    near = None
    if cfg.grow_pixels > 0:
        near = np.zeros(v.shape, bool)
        near[v] = in_background(bg, p, 1) | bgm[v]
    return bgm, near


def segment_scene(url: str, scene_id: str | None = None, cfg: SegmentConfig | None = None, quiet: bool = True,
                  overwrite: bool = False, background=None, world_points: dict | None = None,
                  masks: "InstanceMasks | None" = None) -> dict:
    """Segment every scan of a dataset scene and write ``lidar/instance`` (T,Hl,Wl) uint16 (resumable:
    finished shards are kept). ``background``: a prebuilt model of these scans (else built here);
    ``world_points``: {frame: float32 world points of the valid returns (N,3)} from
    the pass that built ``background`` (:func:`background_and_segment`): scans that are
    :func:`surely_without_foreground` are written empty without reading them again (the same
    result). ``masks``: the :class:`InstanceMasks` of these scans and this background that another
    user already asked (``holodata register``'s map): the masks it holds are not computed again.
    Returns a summary {scene, frames, instances_per_scan, ...}."""
    import time

    from ..dataset import create_dataset, open_dataset

    cfg = cfg or SegmentConfig()
    t0 = time.perf_counter()
    ds = open_dataset(url)
    sid = _scene_id(ds, url, scene_id)
    scene = ds.scene(sid)
    scans = LidarScans.open(scene, url)
    traj = scans.trajectory()
    if background is None:
        background, world_points = _background_pass(scans, cfg, traj, quiet, keep=True)
    bg = background
    world_points = world_points or {}
    w = create_dataset(url, grid=ds.grid, range_bins=ds.range_bins)
    sw = w.scene(sid)
    poses = pose_fingerprint(scene)
    if INSTANCE_ARRAY in sw.arrays() and (overwrite or instance_state(scene) == "stale"):
        sw.remove(INSTANCE_ARRAY)
    arr = sw.frame_array(INSTANCE_ARRAY, per_frame_shape=scans.shape, dtype="uint16", dims=["frame", "beam", "column"],
                         units="1", fill_value=0,
                         attrs={"method": "voxel background + erosion seeds + Euclidean flood fill (Ouster OS0)",
                                "values": "0 = background or no return; 1..n instances by decreasing size",
                                "params": cfg.to_attrs(), "background_voxels": int(len(bg)), "poses_sha256": poses})
    counts = []
    masks = masks or InstanceMasks(scans, bg, cfg, traj, world_points)
    for s in track(range(arr.n_shards), arr.n_shards, f"segment {sid}", quiet):
        sl = arr.frames(s)
        if arr.is_done(s):
            continue
        out = np.zeros((sl.stop - sl.start,) + scans.shape, np.uint16)
        for i, k in enumerate(range(sl.start, sl.stop)):
            m = masks.mask(k)
            if m is not None:
                out[i] = m
                counts.append(int(m.max()))
        arr.write_shard(s, out)
    return {"scene": sid, "frames": scene.n_frames, "array": INSTANCE_ARRAY, "background_voxels": int(len(bg)),
            "instances_per_scan": float(np.mean(counts)) if counts else 0.0, "seconds": time.perf_counter() - t0}


def pose_fingerprint(scene) -> str | None:
    """sha256 of the scene's ``pose/T_world_lidar`` (float64, C order); None without poses. Stored
    with ``lidar/instance`` as ``poses_sha256``: the poses its scans were segmented with."""
    import hashlib

    if "pose/T_world_lidar" not in set(scene.arrays()):
        return None
    P = np.ascontiguousarray(scene["pose/T_world_lidar"][...], np.float64)
    return hashlib.sha256(P.tobytes()).hexdigest()


def instance_state(scene) -> str:
    """What the scene's ``lidar/instance`` is worth now: "current" (every shard written, segmented
    with the poses the scene holds), "partial" (same poses, shards missing: :func:`segment_scene`
    resumes it), "stale" (segmented with other poses, or with unknown ones: ``holodata slam`` ran
    again, or the poses were replaced) or "absent"."""
    nodes = scene.nodes()
    if INSTANCE_ARRAY not in nodes:
        return "absent"
    attrs = nodes[INSTANCE_ARRAY][1].get("attributes") or {}
    fp = attrs.get("poses_sha256")
    if fp is None or fp != pose_fingerprint(scene):
        return "stale"
    n = int((attrs.get("holodata") or {}).get("n_shards") or 0)
    done = n > 0 and all(scene.is_done(INSTANCE_ARRAY, k) for k in range(n))
    return "current" if done else "partial"


class InstanceMasks:
    """Per-scan instance masks of :func:`segment_scene`, computed on demand: ``masks[k]`` (H,W)
    uint16 (0 = background / no return, 1..n instances). ``world_points`` {frame: float32 world points
    of the valid returns} from the background pass: scans that are :func:`surely_without_foreground`
    are answered from them without reading the scan again. A mask asked by index (``masks[k]``) is
    kept until :meth:`mask` hands it out (to :func:`segment_scene`), so it is computed once."""

    def __init__(self, scans: LidarScans, bg, cfg: SegmentConfig, traj=None, world_points: dict | None = None):
        self.scans, self.bg, self.cfg, self.traj = scans, bg, cfg, traj
        self.world_points = world_points or {}
        self.shifts, self.elev = grid_geometry(scans)
        self._kept: dict = {}

    def mask(self, k: int) -> np.ndarray | None:
        """Scan ``k``'s mask, or None for a scan without returns (counted by nobody)."""
        if k in self._kept:
            return self._kept.pop(k)
        wp = self.world_points.get(k)
        if wp is not None and surely_without_foreground(self.bg, wp, self.cfg):
            return np.zeros(self.scans.shape, np.uint16) if len(wp) else None
        valid, P, Pw = self.scans.scan(k, self.traj, self.cfg.deskew)
        if not valid.any():
            return None
        bgm, near = background_masks(self.bg, valid, Pw, self.cfg)
        return segment_scan(P, valid, bgm, self.cfg, points_world=np.where(valid[..., None], Pw, 0.0),
                            background_near=near, floor=getattr(self.bg, "floor", None), shifts=self.shifts,
                            elev=self.elev)

    def __getitem__(self, k: int) -> np.ndarray:
        m = self._kept[k] = self.mask(k)
        return np.zeros(self.scans.shape, np.uint16) if m is None else m


def _scene_id(ds, url: str, scene_id: str | None) -> str:
    if scene_id is None:
        if len(ds.scenes) != 1:
            raise InputError(f"{url}: holds {len(ds.scenes)} scenes ({', '.join(ds.scenes) or 'none'}); pick one with --scene")
        return ds.scenes[0]
    if scene_id not in ds.scenes:
        raise InputError(f"{url}: no scene {scene_id!r} (have: {', '.join(ds.scenes) or 'none'})")
    return scene_id


__all__ = ["SegmentConfig", "segment_scan", "flood_fill", "erode", "LidarScans", "build_background", "segment_scene",
           "InstanceMasks",
           "background_and_segment", "surely_without_foreground", "INSTANCE_ARRAY", "instance_state",
           "pose_fingerprint"]
